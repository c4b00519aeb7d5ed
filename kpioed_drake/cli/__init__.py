"""The ``kpioed`` command line: a thin layer over :mod:`kpioed_drake.api`.

Each subcommand lives in its own module with ``register(subparsers)``; ``run(args) -> int``.
Exit statuses (:mod:`kpioed_drake.errors`): 0 success; 2 bad input (one line naming the file, row
or field); 3 solver failure or infeasible result; 130 interrupted; 1 an internal error (one line;
``kpioed --debug COMMAND ...`` shows the traceback).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import sys
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
    interrupted,
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
    return parser


def _os_error_text(exc: OSError) -> str:
    what = exc.strerror or type(exc).__name__
    if exc.errno == errno.ENOSPC:
        what = "no space left on the device (nothing was written)"
    elif exc.errno == errno.EROFS:
        what = "read-only file system"
    name = exc.filename if exc.filename is not None else "file"
    return f"{name}: {what}"


def main(argv: list[str] | None = None) -> int:
    """Run ``kpioed`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with catch_interrupts():
            return int(args.func(args) or EXIT_OK)
    except InputError as exc:
        print(f"kpioed: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except SolverError as exc:
        print(f"kpioed: failed: {exc}", file=sys.stderr)
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
