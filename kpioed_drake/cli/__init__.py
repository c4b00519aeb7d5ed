"""The ``kpioed`` command line: a thin layer over :mod:`kpioed_drake.api` and the library.

Each subcommand lives in its own module with ``register(subparsers)``; ``run(args) -> int``.
Bad input raises :class:`~kpioed_drake.errors.InputError`: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from kpioed_drake.errors import InputError

COMMANDS = ("info", "evaluate", "design", "simulate", "calibrate", "diagnose", "study")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors: one line, exit 2
        self.exit(2, f"kpioed: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="kpioed", description="KPI-based optimum experimental design for robot calibration")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f"kpioed_drake.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"kpioed_drake.cli.{name}":
                raise
            continue
        mod.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"kpioed: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("kpioed: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
