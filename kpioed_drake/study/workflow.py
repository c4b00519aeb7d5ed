"""``kpioed study``: run (or resume) the paper's study and write its tables, report and figures
(:func:`run_study`), or rebuild the tables of a finished study with the bounds
(:func:`regenerate_tables`)."""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from kpioed_drake.arguments import check_count, check_seed, require
from kpioed_drake.errors import InputError, SolverError
from kpioed_drake.outputs import atomic_write_text, check_output_paths
from kpioed_drake.robot.models import list_robots, load_robot
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.study.bounds import add_efficiency, bound_tasks_of, bounds_frame, rows_from_results
from kpioed_drake.study.plots import make_figures
from kpioed_drake.study.report import StudyReport, make_report
from kpioed_drake.study.runner import run_tasks
from kpioed_drake.study.tables import make_tables, results_frame
from kpioed_drake.study.tasks import BoundTask, make_bound_tasks, make_tasks, study_robots
from kpioed_drake.study.variants import DEFAULT, get_variant

if TYPE_CHECKING:  # an optional dependency (extra "dask")
    from distributed import Client


def write_outputs(
    out_dir: Path,
    rows: list[dict],
    *,
    wall_s: float | None = None,
    figures: bool = True,
    title: str = "Study",
    bound_rows: list[dict] = (),
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame, pd.DataFrame, str, list[Path]]:
    """Write ``results.csv``, ``per_robot.csv``, ``table6/7/8.csv``, ``report.md``, (``figures``)
    the figures and (with ``bound_rows``) ``bounds.csv`` into ``out_dir``, each atomically.

    Args:
        rows: the design rows (:func:`run_task`); bound_rows: the rows of the :class:`BoundTask`
            (joined as each design's ``bound_mm2`` and ``efficiency``, :mod:`.bounds`).

    Returns:
        the results frame, Tables 6, 7, 8, the report and the figure paths.
    """
    out_dir = Path(out_dir)
    df = results_frame(add_efficiency(rows, list(bound_rows)))
    if bound_rows:
        atomic_write_text(
            out_dir / "bounds.csv", bounds_frame(list(bound_rows)).to_csv(index=False, float_format="%.6g")
        )
    t6, t7, t8, pr = make_tables(df)
    atomic_write_text(out_dir / "results.csv", df.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out_dir / "per_robot.csv", pr.to_csv(float_format="%.6g"))
    atomic_write_text(out_dir / "table6.csv", t6.to_csv(float_format="%.6g"))
    atomic_write_text(out_dir / "table7.csv", t7.to_csv(float_format="%.6g"))
    atomic_write_text(out_dir / "table8.csv", t8.to_csv(float_format="%.6g"))
    report = make_report(df, t6, t7, t8, pr, wall_s=wall_s, title=title)
    figs = make_figures(out_dir, df, pr) if figures else []
    if figs:
        report += "\n## Figures\n\n" + "\n".join(f"![{p.stem}]({p.name})" for p in figs) + "\n"
    atomic_write_text(out_dir / "report.md", report)
    return df, t6, t7, t8, report, figs


def run_study(
    out_dir: str | Path,
    *,
    quick: bool = False,
    jobs: int | None = None,
    scheduler: str | Client | None = None,
    progress: bool = True,
    robots: Iterable[str] | None = None,
    n: int = 60,
    heuristic_draws: int | None = None,
    seed: int = 0,
    figures: bool = True,
    design_api: str | object | None = None,
    variant: str = DEFAULT,
    bounds: bool = True,
) -> StudyReport:
    """Run (or resume) the paper's study (``kpioed study``) and write ``results.csv``,
    ``table6/7/8.csv``, ``report.md`` and the figures into ``out_dir``.

    Args:
        out_dir: study folder (created; existing task files are reused).
        quick: KUKA robots + six notional robots, 3 heuristic draws (unless given).
        jobs: local worker processes (default: the number of CPUs); 1 runs inline.
        scheduler: Dask scheduler address (or a ``distributed.Client``): the tasks go there instead.
        progress: show a progress bar.
        robots: the robots to study (default: KUKA + all 90 notional, or the quick set).
        n: poses per design.
        heuristic_draws: seeded heuristic designs per robot (default 10; quick 3).
        seed: first seed.
        figures: draw Figures 7 and 8.
        design_api: stand-in for :mod:`kpioed_drake.design` (tests).
        variant: the problem variant (:data:`VARIANTS`); its name is in the task ids, the design
            file names and the report's title unless ``default``.
        bounds: also compute each robot's lower bound (:class:`BoundTask`, 4-13 s per robot) and
            the designs' efficiencies (not with a ``design_api`` stand-in without
            ``certified_design``).

    Raises:
        InputError: ``n`` below a robot's fewest poses, ``jobs`` below 1, an unknown robot or variant.
        SolverError: every task failed (nothing to tabulate; the task files keep the errors).
    """
    t0 = time.perf_counter()
    check_output_paths(folders=[out_dir])  # an empty name would be the current folder
    out_dir = Path(out_dir)
    robots = list(robots) if robots is not None else study_robots(quick)
    _check(out_dir, robots, n=n, seed=seed, heuristic_draws=heuristic_draws, jobs=jobs)
    var = get_variant(variant)
    draws = heuristic_draws if heuristic_draws is not None else (3 if quick else 10)
    tasks = make_tasks(robots, n=n, heuristic_draws=draws, seed=seed, variant=var.name)
    if bounds and (
        design_api is None or isinstance(design_api, str) or hasattr(design_api, "certified_design")
    ):
        tasks += make_bound_tasks(robots, n=n, variant=var.name)
    all_rows, n_run, n_skip = run_tasks(
        tasks, out_dir, jobs=jobs, scheduler=scheduler, progress=progress, design_api=design_api
    )
    rows = [r for t, r in zip(tasks, all_rows, strict=True) if not isinstance(t, BoundTask)]
    bound_rows = [r for t, r in zip(tasks, all_rows, strict=True) if isinstance(t, BoundTask)]
    failed = [r for r in rows if r.get("error")]
    if rows and len(failed) == len(rows):
        raise SolverError(
            f"{out_dir}: all {len(rows)} study tasks failed (first: {failed[0]['task_id']}: "
            f"{failed[0]['error']}); each task file under tasks/ records its error; a new run retries them"
        )
    wall = time.perf_counter() - t0
    title = "Quick study" if quick else "Study"
    if var.name != DEFAULT:
        title += f", variant `{var.name}` ({var.description})"
    outputs = write_outputs(out_dir, rows, wall_s=wall, figures=figures, title=title, bound_rows=bound_rows)
    n_errors = int(outputs[0]["error"].notna().sum()) + sum(1 for b in bound_rows if b.get("error"))
    return _study_report(out_dir, outputs, (len(tasks), n_run, n_skip, n_errors), time.perf_counter() - t0)


def _check(out_dir: Path, robots: list[str], *, n, seed, heuristic_draws, jobs) -> None:
    """Refuse a bad study request before any task runs (InputError naming the argument)."""
    check_seed(seed)
    check_count("n", n)
    check_count("heuristic_draws", heuristic_draws, allow_none=True)
    check_count("jobs", jobs, allow_none=True)
    require(len(robots) > 0, "robots: expected at least one robot name", fields=("robots",))
    known = set(list_robots())
    unknown = [r for r in robots if r not in known]
    if unknown:
        raise InputError(f"unknown robot(s): {', '.join(unknown)}")
    for r in robots:
        need = parameter_layout(load_robot(r)).n_free // 3 + 1
        if n < need:
            raise InputError(
                f"n {n}: {r} needs designs of at least {need} poses (one more than its parameters / 3)",
                fields=("n",),
            )


def _study_report(out_dir: Path, outputs: tuple, counts: tuple, wall_s: float) -> StudyReport:
    """The :class:`StudyReport` of :func:`write_outputs`' ``outputs`` and the counts (tasks, run,
    skipped, errors)."""
    df, t6, t7, t8, report, figs = outputs
    n_tasks, n_run, n_skip, n_errors = counts
    return StudyReport(
        out_dir=out_dir,
        results=df,
        table6=t6,
        table7=t7,
        table8=t8,
        report=report,
        figures=figs,
        n_tasks=n_tasks,
        n_run=n_run,
        n_skipped=n_skip,
        n_errors=n_errors,
        wall_s=wall_s,
    )


_WALL = re.compile(r"^Wall time of this run: (\d+(?:\.\d*)?) s\.$", re.MULTILINE)


def regenerate_tables(
    out_dir: str | Path,
    *,
    jobs: int | None = None,
    progress: bool = True,
    figures: bool = True,
    design_api: str | object | None = None,
) -> StudyReport:
    """Rebuild the tables, report and figures of a finished study in ``out_dir`` with the bounds and
    efficiencies, without making the designs again (``kpioed study --tables-only``).

    The design rows come from ``results.csv`` and ``designs/`` (:func:`.bounds.rows_from_results`);
    the bounds (one :class:`BoundTask` per robot, variant and n) are computed where ``tasks/`` has no
    result file yet (resumable like the designs). The report keeps the title and the wall time of the
    run that made the designs.

    Raises:
        InputError: no ``results.csv`` or a missing design file. SolverError: every bound failed.
    """
    out_dir = Path(out_dir)
    rows = rows_from_results(out_dir)
    tasks = bound_tasks_of(rows)
    bound_rows, n_run, n_skip = run_tasks(tasks, out_dir, jobs=jobs, progress=progress, design_api=design_api)
    if bound_rows and all(b.get("error") for b in bound_rows):
        raise SolverError(f"{out_dir}: every bound failed (first: {bound_rows[0]['error']})")
    old = out_dir / "report.md"
    text = old.read_text(encoding="utf-8") if old.is_file() else ""
    wall = _WALL.search(text)
    title = (
        text.splitlines()[0].removeprefix("# ").rsplit(": KPI-based OED", 1)[0]
        if text.startswith("# ")
        else "Study"
    )
    wall_s = float(wall.group(1)) if wall else None
    outputs = write_outputs(out_dir, rows, wall_s=wall_s, figures=figures, title=title, bound_rows=bound_rows)
    n_errors = sum(1 for b in bound_rows if b.get("error"))
    return _study_report(out_dir, outputs, (len(tasks), n_run, n_skip, n_errors), wall_s or math.nan)
