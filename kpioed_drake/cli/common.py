"""Argument helpers shared by the subcommands."""

from __future__ import annotations

import json
import sys

from kpioed_drake.designio import atomic_write_json


def add_robot(p, *, required: bool = True) -> None:
    p.add_argument(
        "--robot", required=required, help="model name (kr16, kr300, kr500, notional-850-800) or YAML path"
    )


def add_sigma(p, default=None) -> None:
    p.add_argument("--sigma-mm", type=float, default=default, help="noise std. dev. per coordinate [mm]")


def add_q_work(p) -> None:
    p.add_argument(
        "--q-work", default=None, metavar="q1,...,q6", help="working pose [deg], overrides the model's"
    )


def add_extend(p) -> None:
    """``--extend EFFECT`` (repeatable): a model extension estimated with the geometry."""
    p.add_argument(
        "--extend",
        action="append",
        default=[],
        metavar="EFFECT",
        help="extend the model, e.g. joint_elasticity:2 or gear_cyclic:4:2 (repeatable)",
    )


def add_json_out(p) -> None:
    """``--json [FILE]``: the report as JSON to FILE, or to stdout without a FILE."""
    p.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="FILE",
        help="write the report as JSON to FILE (or stdout)",
    )


def emit_json(data, target) -> None:
    """Write ``data`` as JSON to a file (atomically) or to stdout when ``target`` is True/'-'."""
    if target in (True, "-"):
        json.dump(data, sys.stdout, indent=2)
        sys.stdout.write("\n")
    elif target:
        atomic_write_json(target, data)
