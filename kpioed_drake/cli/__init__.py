"""The ``kpioed`` command line: a thin layer over :mod:`kpioed_drake.api`.

Each subcommand lives in its own module with ``register(subparsers)``; ``run(args) -> int``.
Exit statuses (:mod:`kpioed_drake.errors`): 0 success; 2 bad input (one line naming the file, row
or field); 3 solver failure or infeasible result; 130 interrupted; 1 an internal error (one line;
``kpioed --debug COMMAND ...`` shows the traceback).

The library's messages name the API's parameters; the command line shows each as the running
command's option (:func:`option_names`): ``sigma_mm`` as ``--sigma-mm``.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import signal
import sys
import threading
import traceback

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
    "diagnose",
    "study",
    "validate",
    "compensate",
)


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
    return next((o for o in option_strings if o.startswith("--")), option_strings[0])


def option_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """API parameter -> option string of a command's parser (``{"sigma_mm": "--sigma-mm"}``): each
    option's dest, and the command's ``api_names`` default (API parameter -> dest where they differ,
    e.g. ``{"target_var_mm2": "target_var"}``)."""
    names = {a.dest: _long_option(a.option_strings) for a in parser._actions if a.option_strings}
    api_names = parser.get_default("api_names") or {}
    return names | {api: names[dest] for api, dest in api_names.items()}


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
