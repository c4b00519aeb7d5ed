"""The ``kpioed`` command line: a thin layer over :mod:`kpioed_drake.api`.

Each subcommand lives in its own module with ``register(subparsers)``; ``run(args) -> int``:
:mod:`.info`, :mod:`.evaluate`, :mod:`.design`, :mod:`.simulate`, :mod:`.calibrate`, :mod:`.next`,
:mod:`.diagnose`, :mod:`.study`, :mod:`.validate`, :mod:`.compensate`.
Exit statuses (:mod:`kpioed_drake.errors`): 0 success; 2 bad input (one line naming the file, row
or field); 3 solver failure or infeasible result; 130 interrupted; 1 an internal error (one line;
``kpioed --debug COMMAND ...`` shows the traceback).

The library's messages name the API's parameters; the command line shows each as the running
command's option (:func:`option_names`): ``sigma_mm`` as ``--sigma-mm``.

The package also holds the arguments the commands share (``add_robot``, ``add_data_outputs``, ...)
and JSON on stdout (:func:`print_json`); their values are checked by the command functions of
:mod:`kpioed_drake.api` (with :mod:`kpioed_drake.arguments`: one place for the CLI and Python users).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import json
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any

from kpioed_drake.errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_SOLVER,
    InputError,
    SolverError,
    catch_interrupts,
    exit_on_interrupt,
    interrupted,
    name_fields,
    param_names,
)

COMMANDS = (
    "info",
    "evaluate",
    "design",
    "simulate",
    "calibrate",
    "next",
    "diagnose",
    "study",
    "validate",
    "compensate",
)


# The arguments the commands share.

API_NAMES = {
    "q_work_deg": "q_work",
    "target_var_mm2": "target_var",
    "json_path": "json",
    "plots_dir": "plots",
    "data_format": "format",
    "effects": "effect",
}
"""API parameter -> option dest where they differ, alike in every command (those whose dest a command
has apply to it; the messages name API parameters, :func:`option_names` turns them into options)."""


def command(
    sub: argparse._SubParsersAction,
    name: str,
    *,
    help: str,
    description: str | None = None,
    data: str | None = None,
    data_help: str | None = None,
    api_names: dict[str, str] | None = None,
) -> argparse.ArgumentParser:
    """The parser of command ``name`` with ``--robot`` and, by ``data``, its measurement file:
    ``"required"``, ``"optional"`` (optional beside the contact files ``--planes``/``--distances``,
    which it adds) or None (no data argument). ``api_names``: the command's own API parameter -> dest
    pairs beside :data:`API_NAMES`."""
    p = sub.add_parser(name, help=help, description=description)
    p.set_defaults(api_names=api_names or {})
    add_robot(p)
    if data is not None:
        add_data(p, help=data_help or DATA_HELP, optional=data == "optional")
    if data == "optional":
        add_contacts(p)
    return p


def add_model_out(p: argparse.ArgumentParser, *, help: str) -> None:
    """``--out``: the model file a command writes (YAML, or a URDF with its sidecar)."""
    add_optional(p, "--out", metavar=MODEL_OUT_METAVAR, help=help)


def add_robot(p: argparse.ArgumentParser, *, required: bool = True) -> None:
    p.add_argument(
        "--robot",
        required=required,
        help="model name (kr16, kr300, kr500, ur5, lift7, notional-850-800) or a YAML or URDF path",
    )


def add_sigma(p: argparse.ArgumentParser, default: float | None = None) -> None:
    """``--sigma-mm``: the measurement noise per coordinate; ``default`` None where the command finds it."""
    shown = "" if default is None else f" ({default:g})"
    p.add_argument(
        "--sigma-mm", type=float, default=default, help=f"noise std. dev. per coordinate [mm]{shown}"
    )


def add_sigma_deg(p: argparse.ArgumentParser, *, default: float | None, use: str) -> None:
    """``--sigma-deg``: a 6-DoF probe's orientation noise; ``use`` says when and what for."""
    help = f"a 6-DoF probe's orientation noise about each tracker axis [deg], {use}"
    p.add_argument("--sigma-deg", type=float, default=default, metavar="S", help=help)


def add_kpi_orientation(p: argparse.ArgumentParser, *, default: float | None, use: str) -> None:
    """``--kpi-orientation-mm L``: the TCP's orientation in the KPI; ``use`` says with which data."""
    help = (
        f"{use}: the TCP's orientation counts in the KPI as the displacement L x angle at L mm from the "
        "TCP: tr(Cs)/3 = position variance + L^2 x orientation variance [rad^2] (default 0: the position "
        "alone)"
    )
    p.add_argument("--kpi-orientation-mm", type=float, default=default, metavar="L", help=help)


def add_seed(p: argparse.ArgumentParser, *, of: str) -> None:
    """``--seed`` (default 0): the seed of the command's random draws, ``of`` naming them."""
    p.add_argument("--seed", type=int, default=0, help=f"seed of {of} (0)")


def add_force(p: argparse.ArgumentParser) -> None:
    """``--force``: go on with data that fails the plausibility checks."""
    p.add_argument(
        "--force", action="store_true", help="go on with data that fails the plausibility checks (warned)"
    )


def add_optional(
    p: argparse.ArgumentParser,
    option: str,
    *,
    metavar: str,
    help: str,
    type: type[int] | type[float] | type[str] = str,
) -> None:
    """An optional ``option``: a file path, or a number of ``type`` (int or float); None when not
    given (``help`` says what that means)."""
    p.add_argument(option, type=type, default=None, metavar=metavar, help=help)


JOINT_COLUMNS = "one column per joint (q1_deg, q2_deg, ...; a prismatic joint's qK_mm)"
"""The joint columns of the files, whatever the robot's joint count (docs/data-formats.md)."""
DATA_HELP = (
    f"measurement CSV: {JOINT_COLUMNS}, x_mm, y_mm, z_mm (the reflector in the tracker frame) "
    "[, temperature_C, time_s, payload_kg, target] (docs/data-formats.md), or see --format"
)
"""The help of a command's measurement file argument."""


def add_data(p: argparse.ArgumentParser, *, help: str = DATA_HELP, optional: bool = False) -> None:
    """The positional measurement file ``DATA.csv`` (``optional``: may be left out)."""
    if optional:
        p.add_argument(
            "data", metavar="DATA.csv", nargs="?", default=None, help=help + " (optional with contacts)"
        )
    else:
        p.add_argument("data", metavar="DATA.csv", help=help)


def add_contacts(p: argparse.ArgumentParser) -> None:
    """``--planes`` and ``--distances``: contact files (docs/contacts.md)."""
    planes = "plane-contact CSV (joint columns, plane 1..P, optional target, distance_mm, sigma_mm)"
    add_optional(p, "--planes", metavar="PLANES.csv", help=planes)
    add_optional(
        p,
        "--distances",
        metavar="DIST.csv",
        help="distance CSV (a_q1_deg.. and b_q1_deg.., or q1_deg.. and pivot; length_mm, optional bar, "
        "target, sigma_mm)",
    )


DESIGN_HELP = f"design CSV: {JOINT_COLUMNS}"
"""The help of a design file argument."""
MODEL_OUT_METAVAR = "MODEL.yaml|NAME.urdf"
"""A calibrated model file: YAML, or for a URDF robot a URDF with its sidecar."""


def add_q_work(p: argparse.ArgumentParser, *, several: bool = False) -> None:
    """``--q-work``: the working pose overriding the model's; with ``several`` repeatable (several KPIs)."""
    more = "; repeat it for several KPIs (working poses, or a working path sampled at K points)"
    p.add_argument(
        "--q-work",
        action="append" if several else "store",
        default=None,
        metavar="q1,...,qN",
        help="working pose, one value per joint [deg; a prismatic joint's mm], overrides the model's"
        + (more if several else ""),
    )


def add_extend(p: argparse.ArgumentParser) -> None:
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


def add_json_out(p: argparse.ArgumentParser) -> None:
    """``--json [FILE]``: the report as JSON to FILE, or to stdout without a FILE (``"-"``)."""
    p.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="FILE",
        help="write the report as JSON to FILE (or stdout)",
    )


def add_html(p: argparse.ArgumentParser) -> None:
    """``--html FILE``: a self-contained 3-D page (Drake Meshcat) of the result."""
    add_optional(p, "--html", metavar="FILE.html", help="write a 3-D page (Meshcat) of the result")


def add_format(p: argparse.ArgumentParser) -> None:
    """``--format F.yaml``: the format file of a measurement file of another layout."""
    help = "format file of a measurement file of another layout (docs/data-formats.md)"
    add_optional(p, "--format", metavar="F.yaml", help=help)


def add_data_outputs(p: argparse.ArgumentParser, *, plots_help: str) -> None:
    """The outputs of a command on measured data: ``--json``, ``--plots``, ``--html``, and its
    ``--force`` and ``--format`` options."""
    add_json_out(p)
    add_optional(p, "--plots", metavar="DIR", help=plots_help)
    add_html(p)
    add_force(p)
    add_format(p)


def data_outputs(args: argparse.Namespace) -> dict:
    """The keyword arguments of :func:`add_data_outputs`' options for the API."""
    return {
        "json_path": json_file(args.json),
        "plots_dir": args.plots,
        "html": args.html,
        "force": args.force,
        "data_format": args.format,
    }


def passed(args: argparse.Namespace, *names: str) -> dict:
    """``{name: args.name}``: the parsed options whose dest is the API parameter's name."""
    return {name: getattr(args, name) for name in names}


def json_file(target: str | None) -> str | None:
    """The ``--json`` file to write (None for none or for stdout)."""
    return None if target in (None, "-") else target


def print_json(data: Any) -> None:
    """Write ``data`` as indented JSON to stdout (``--json`` without a file; files are the API's)."""
    json.dump(data, sys.stdout, indent=2)
    sys.stdout.write("\n")


def print_result(
    args: argparse.Namespace,
    record: Callable[[], Any],
    summary: Callable[[], str],
    written: tuple[tuple[str | None, str], ...] = (),
) -> int:
    """A command's result on stdout: ``record()`` as JSON for ``--json -``, else ``summary()`` and a
    line per file ``(path, what)`` written (those given); the exit status 0."""
    if args.json == "-":
        print_json(record())
        return 0
    print(summary())
    for path, what in written:
        if path:
            print(f"  {what}: {path}")
    return 0


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors: one line, exit 2
        self.exit(EXIT_INPUT, f"kpioed: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``kpioed`` parser with every subcommand registered."""
    parser = _Parser(prog="kpioed", description="KPI-based optimum experimental design for robot calibration")
    parser.add_argument("--debug", action="store_true", help="show the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"kpioed_drake.cli.{name}").register(sub)
    for command in sub.choices.values():
        command.set_defaults(option_names=option_names(command))
    return parser


def _long_option(option_strings: list[str]) -> str:
    """``--sigma-mm`` of its option strings (``--certify`` of ``--certify``/``--no-certify``)."""
    # not the builtin next(): importing the command module kpioed_drake.cli.next binds ``next`` here
    longs = [o for o in option_strings if o.startswith("--")]
    return longs[0] if longs else option_strings[0]


def option_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """API parameter -> option string of a command's parser (``{"sigma_mm": "--sigma-mm"}``): each
    option's dest, and :func:`api_names` (API parameter -> dest where they differ, e.g.
    ``{"target_var_mm2": "target_var"}``)."""
    names = {a.dest: _long_option(a.option_strings) for a in parser._actions if a.option_strings}
    return names | {api: names[dest] for api, dest in api_names(parser).items()}


def api_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """API parameter -> dest of a command's parser where they differ: :data:`API_NAMES` for the dests
    it has, and its own (``command(..., api_names=)``)."""
    dests = {a.dest for a in parser._actions}
    pairs = API_NAMES | (parser.get_default("api_names") or {})
    return {api: dest for api, dest in pairs.items() if dest in dests}


def _os_error_text(exc: OSError) -> str:
    what = exc.strerror or type(exc).__name__
    if exc.errno == errno.ENOSPC:
        what = "no space left on the device (nothing was written)"
    elif exc.errno == errno.EROFS:
        what = "read-only file system"
    name = exc.filename if exc.filename is not None else "file"
    return f"{name}: {what}"


def _empty_options(args, parser: argparse.ArgumentParser) -> None:
    """Refuse an option given as an empty string (``--out ''``): no command takes one, and a
    command that tests its option for truth would silently do without it."""
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for action in sub.choices[args.command]._actions:
        value = getattr(args, action.dest, None) if action.option_strings else None
        values = value if isinstance(value, list) else [value]
        if any(isinstance(v, str) and not v.strip() for v in values):
            raise InputError(f"{_long_option(action.option_strings)}: expected a value, got an empty string")


def main(argv: list[str] | None = None) -> int:
    """Run ``kpioed`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    The interrupt handler is installed first, before the commands' imports (Drake, numpy) take
    their seconds: a Ctrl-C at any point ends with one line and status 130, never a traceback
    (during the imports at once, :func:`~kpioed_drake.errors.exit_on_interrupt`). Without
    ``argv`` (the ``kpioed`` process itself), a Ctrl-C after the command ended is ignored: the
    process is exiting with the command's status.
    """
    if argv is None and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # what catch_interrupts restores at the end
    with catch_interrupts():
        with exit_on_interrupt("kpioed: interrupted"):
            parser = build_parser()
            args = parser.parse_args(argv)
        return _run(args, parser)


def _run(args, parser: argparse.ArgumentParser) -> int:
    """The parsed command, its errors as one line and an exit status."""
    try:
        with param_names(args.option_names):
            _empty_options(args, parser)
            return int(args.func(args) or EXIT_OK)
    except InputError as exc:
        print(f"kpioed: error: {name_fields(str(exc), exc.fields, args.option_names)}", file=sys.stderr)
        return EXIT_INPUT
    except SolverError as exc:
        print(f"kpioed: failed: {name_fields(str(exc), exc.fields, args.option_names)}", file=sys.stderr)
        return EXIT_SOLVER
    except BrokenPipeError:  # output piped into e.g. `head`
        sys.stderr.close()
        return EXIT_OK
    except KeyboardInterrupt:
        print("kpioed: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:  # unreadable input, unwritable output, full disk
        if args.debug:
            traceback.print_exc()
        print(f"kpioed: error: {_os_error_text(exc)}", file=sys.stderr)
        return EXIT_INPUT
    except Exception as exc:  # a bug: one line unless --debug
        if interrupted():  # a Ctrl-C that a solver wrapped into its own exception
            print("kpioed: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        if args.debug:
            traceback.print_exc()
        print(
            f"kpioed: internal error: {type(exc).__name__}: {exc} (run `kpioed --debug {args.command} ...` "
            "for the traceback)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
