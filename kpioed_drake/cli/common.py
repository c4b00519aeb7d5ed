"""Argument helpers shared by the subcommands, and JSON on stdout.

The values are checked by the command functions of :mod:`kpioed_drake.api` (with
:mod:`kpioed_drake.arguments`: one place for the CLI and Python users).
"""

from __future__ import annotations

import json
import sys


def add_robot(p, *, required: bool = True) -> None:
    p.add_argument(
        "--robot",
        required=required,
        help="model name (kr16, kr300, kr500, ur5, lift7, notional-850-800) or a YAML or URDF path",
    )


def add_sigma(p, default=None) -> None:
    p.add_argument("--sigma-mm", type=float, default=default, help="noise std. dev. per coordinate [mm]")


def add_optional_number(p, option: str, *, type, metavar: str, help: str) -> None:
    """An optional number ``option`` of ``type`` (int or float), None when not given (``help`` says
    what that means)."""
    p.add_argument(option, type=type, default=None, metavar=metavar, help=help)


JOINT_COLUMNS = "one column per joint (q1_deg, q2_deg, ...; a prismatic joint's qK_mm)"
"""The joint columns of the files, whatever the robot's joint count (docs/data-formats.md)."""
DATA_HELP = (
    f"measurement CSV: {JOINT_COLUMNS}, x_mm, y_mm, z_mm (the reflector in the tracker frame) "
    "[, temperature_C, time_s, payload_kg, target] (docs/data-formats.md), or see --format"
)
"""The help of a command's measurement file argument."""
DESIGN_HELP = f"design CSV: {JOINT_COLUMNS}"
"""The help of a design file argument."""
MODEL_OUT_METAVAR = "MODEL.yaml|NAME.urdf"
"""A calibrated model file: YAML, or for a URDF robot a URDF with its sidecar."""


def add_q_work(p) -> None:
    p.add_argument(
        "--q-work",
        default=None,
        metavar="q1,...,qN",
        help="working pose, one value per joint [deg; a prismatic joint's mm], overrides the model's",
    )


def add_extend(p) -> None:
    """``--extend EFFECT`` (repeatable): a model extension estimated with the geometry."""
    p.add_argument(
        "--extend",
        action="append",
        default=[],
        metavar="EFFECT",
        help="extend the model, e.g. joint_elasticity:2, gear_cyclic:4:2, joint_scale:2, joint_coupling:5:4, "
        "backlash:3, tracker_scale, column_compliance:1 (a lift), base_compliance, lateral_compliance:2 "
        "(repeatable)",
    )


def add_json_out(p) -> None:
    """``--json [FILE]``: the report as JSON to FILE, or to stdout without a FILE (``"-"``)."""
    p.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="FILE",
        help="write the report as JSON to FILE (or stdout)",
    )


def add_html(p) -> None:
    """``--html FILE``: a self-contained 3-D page (Drake Meshcat) of the result."""
    p.add_argument(
        "--html", default=None, metavar="FILE.html", help="write a 3-D page (Meshcat) of the result"
    )


def add_format(p) -> None:
    """``--format F.yaml``: the format file of a measurement file of another layout."""
    p.add_argument(
        "--format",
        default=None,
        metavar="F.yaml",
        help="format file of a measurement file of another layout (docs/data-formats.md)",
    )


def add_data_outputs(p, *, plots_help: str) -> None:
    """The outputs of a command on measured data: ``--json``, ``--plots``, ``--html``, and its
    ``--force`` and ``--format`` options."""
    add_json_out(p)
    p.add_argument("--plots", default=None, metavar="DIR", help=plots_help)
    add_html(p)
    p.add_argument(
        "--force", action="store_true", help="go on with data that fails the plausibility checks (warned)"
    )
    add_format(p)


def data_outputs(args) -> dict:
    """The keyword arguments of :func:`add_data_outputs`' options for the API."""
    return {
        "json_path": json_file(args.json),
        "plots_dir": args.plots,
        "html": args.html,
        "force": args.force,
        "data_format": args.format,
    }


def passed(args, *names: str) -> dict:
    """``{name: args.name}``: the parsed options whose dest is the API parameter's name."""
    return {name: getattr(args, name) for name in names}


def json_file(target) -> str | None:
    """The ``--json`` file to write (None for none or for stdout)."""
    return None if target in (None, "-") else target


def print_json(data) -> None:
    """Write ``data`` as indented JSON to stdout (``--json`` without a file; files are the API's)."""
    json.dump(data, sys.stdout, indent=2)
    sys.stdout.write("\n")
