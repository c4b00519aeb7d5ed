"""The study's lower bounds joined into its rows: each design's efficiency.

A :class:`~kpioed_drake.study.tasks.BoundTask` gives, per robot (and variant, n), the dual matrix
``Y`` (k, 3) of the approximate KPI design over the poses its search evaluated, ``tr(K^T Y)^2``
and ``g_max`` = the largest ``||F_x Y||_F^2`` found (:mod:`kpioed_drake.design.approximate.certificate`).
For a design of n poses ``x_1..x_n`` with collision avoidance,

    bound = tr(K^T Y)^2 / (n max(g_max, max_i ||F_{x_i} Y||_F^2))

is a lower bound on tr(Cs)/3 of every n-pose design from the poses searched and the design's own
(so bound <= the design's value, efficiency = bound / value <= 1); over all feasible poses it is as
good as the search (docs/certificate.md). Unlike ``kpioed design``'s certificate no local search is
started from the design's poses, so a design beyond the search only lowers its own bound.

Designs without collision avoidance (``noca``) get no bound: their feasible set is larger.

:func:`rows_from_results` reads a study folder's ``results.csv`` and ``designs/`` back into rows, so
the tables can be regenerated with the bounds without making the designs again.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake.design.approximate.search import dual_values, pose_rows
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.files.designs import read_design
from kpioed_drake.study.tasks import BoundTask, Task, _problem_and_checker

BOUND_COLUMNS = [
    "robot",
    "variant",
    "n",
    "seed",
    "bound_mm2",
    "approximate_mm2",
    "dual_gap",
    "rounds",
    "converged",
    "n_candidates",
    "n_local_searches",
    "solve_s",
    "error",
]
"""Columns of ``bounds.csv``: one row per robot (``bound_mm2``: the search's bound on tr(Cs)/3 of
any n-pose design with collision avoidance [mm^2]; ``approximate_mm2``: the approximate design's
``Phi / n``; ``solve_s``: the search's wall time [s], 0 when read from the disk cache)."""


def _key(robot: str, variant: str, n: int) -> tuple[str, str, int]:
    return str(robot), str(variant), int(n)


def design_bound(bound_row: dict, problem: Problem, q: np.ndarray) -> float:
    """The bound on tr(Cs)/3 of any design of ``len(q)`` poses that also covers the design ``q``
    (n, 6) [rad] (module docstring) [mm^2]."""
    Y = np.asarray(bound_row["Y"], dtype=float)
    g_design = float(dual_values(pose_rows(problem, q), Y).max())
    return bound_row["dual_mm2"] / (len(q) * max(bound_row["g_max"], g_design))


def add_efficiency(rows: list[dict], bound_rows: list[dict]) -> list[dict]:
    """The design rows with ``bound_mm2`` (:func:`design_bound`) and ``efficiency`` = bound /
    ``kpi_avg_var_mm2``; NaN for designs without collision avoidance, failed tasks, rows without
    poses (``q_deg``) and robots without a bound."""
    bounds = {_key(b["robot"], b["variant"], b["n"]): b for b in bound_rows if not b.get("error")}
    out = []
    for r in rows:
        r = dict(r)
        b = bounds.get(_key(r["robot"], r.get("variant") or "default", r["n"]))
        bound = math.nan
        if b is not None and r.get("collision_avoidance") and not r.get("error") and r.get("q_deg"):
            problem, _ = _problem_and_checker(r["robot"], b["variant"])
            bound = design_bound(b, problem, np.deg2rad(np.asarray(r["q_deg"], dtype=float)))
        r["bound_mm2"] = bound
        r["efficiency"] = bound / r["kpi_avg_var_mm2"] if np.isfinite(bound) else math.nan
        out.append(r)
    return out


def bounds_frame(bound_rows: list[dict]) -> pd.DataFrame:
    """``bounds.csv``: one row per bound task, :data:`BOUND_COLUMNS`."""
    df = pd.DataFrame([{k: b.get(k) for k in BOUND_COLUMNS} for b in bound_rows], columns=BOUND_COLUMNS)
    return df


def bound_tasks_of(rows: list[dict]) -> list[BoundTask]:
    """One :class:`BoundTask` per (robot, variant, n) of the design rows, in their order."""
    seen: dict = {}
    for r in rows:
        seen.setdefault(_key(r["robot"], r.get("variant") or "default", r["n"]), None)
    return [BoundTask(robot, n, variant) for robot, variant, n in seen]


def rows_from_results(out_dir: str | Path) -> list[dict]:
    """The design rows of a finished study from ``out_dir/results.csv`` and the design files of
    ``out_dir/designs`` (``q_deg``), as :func:`~kpioed_drake.study.tasks.run_task` returned them.

    Raises:
        InputError: no ``results.csv``, or a design file missing for a row without error.
    """
    out_dir = Path(out_dir)
    path = out_dir / "results.csv"
    if not path.is_file():
        raise InputError(f"{path}: not found; expected the results of a finished study")
    df = pd.read_csv(path, keep_default_na=True)
    rows = []
    for _, s in df.iterrows():
        r = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in s.items()}
        if isinstance(r.get("error"), float) and math.isnan(r["error"]):
            r["error"] = None
        if not isinstance(r.get("variant"), str) or not r["variant"]:
            r["variant"] = "default"
        task = Task.from_row(r)
        r["task_id"] = task.task_id
        if r.get("error") is None:
            design = out_dir / "designs" / task.design_name
            if not design.is_file():
                raise InputError(f"{design}: not found; expected the design of {path} row {task.task_id}")
            problem, _ = _problem_and_checker(task.robot, task.variant)
            r["q_deg"] = np.rad2deg(read_design(design, problem.robot)).tolist()
        rows.append(r)
    return rows
