"""``kpioed study``: regenerate the paper's Tables 6-8 and Figures 7-8 (resumable, parallel)."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli
from kpioed_drake.errors import EXIT_SOLVER
from kpioed_drake.study import DEFAULT, VARIANTS, regenerate_tables


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="run (or resume) the paper's study: Tables 6-8, Figures 7-8")
    p.add_argument(
        "--out", required=True, metavar="DIR", help="output folder (results.csv, tables, report.md)"
    )
    p.add_argument("--quick", action="store_true", help="KUKA robots + 6 notional robots, 3 heuristic draws")
    p.add_argument("--jobs", type=int, default=None, help="local worker processes (default: number of CPUs)")
    p.add_argument(
        "--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler address (tcp://host:port)"
    )
    p.add_argument("--n", type=int, default=60, help="poses per design (default 60)")
    p.add_argument(
        "--heuristic-draws", type=int, default=None, help="seeded heuristic draws (default 10, quick 3)"
    )
    cli.add_seed(p, of="the first run")
    p.add_argument("--robots", default=None, help="comma-separated robot names (default: the study's)")
    p.add_argument(
        "--variant",
        default=DEFAULT,
        help=f"problem variant (docs/studies.md): {', '.join(VARIANTS)}, or a+b of two (default {DEFAULT})",
    )
    p.add_argument(
        "--tables-only",
        action="store_true",
        help="rebuild the tables, report and figures of the finished study in --out from its results.csv "
        "and designs/ with each robot's lower bound and the designs' efficiencies (computes the missing "
        "bounds, about 4-13 s per robot; makes no design)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run, api_names={"out_dir": "out"})


def run(args: argparse.Namespace) -> int:
    if args.tables_only:
        res = regenerate_tables(args.out, jobs=args.jobs, progress=not args.no_progress)
        print(f"{res.n_tasks} bounds ({res.n_run} computed, {res.n_skipped} resumed, {res.n_errors} failed); "
              f"report: {res.out_dir / 'report.md'}")  # fmt: skip
        return EXIT_SOLVER if res.n_errors else 0
    robots = None if args.robots is None else [r.strip() for r in args.robots.split(",") if r.strip()]
    res = api.study(
        args.out,
        quick=args.quick,
        jobs=args.jobs,
        scheduler=args.scheduler,
        progress=not args.no_progress,
        robots=robots,
        n=args.n,
        heuristic_draws=args.heuristic_draws,
        seed=args.seed,
        variant=args.variant,
    )
    print(
        f"{res.n_tasks} tasks ({res.n_run} run, {res.n_skipped} resumed, {res.n_errors} failed) "
        f"in {res.wall_s:.0f} s; report: {res.out_dir / 'report.md'}"
    )
    return EXIT_SOLVER if res.n_errors else 0
