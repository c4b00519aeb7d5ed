"""Independent feasibility check of a design (paper eq. 24b) with Drake geometry queries.

Every design the optimiser returns (and every block result of a sweep) is checked by
:class:`~kpioed_drake.tracker.feasibility.FeasibilityChecker` (Drake signed distances), never by the
optimiser's own constraint functions. One checker per robot and cell is kept per thread (a checker
holds a Drake context).
"""

from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from kpioed_drake.estimation.problem import Problem
from kpioed_drake.tracker.feasibility import FeasibilityChecker, PoseReport

_LOCAL = threading.local()  # checkers hold a Drake context: one cache per thread


class DesignCheck(NamedTuple):
    """The independent check of a design (unpacks as ``reports, n_infeasible, n_colliding``)."""

    reports: list[PoseReport]
    """Per pose, the full check (joint limits, incidence, collisions, beam)."""
    n_infeasible: int
    """Poses failing a constraint that was imposed (joint limit, incidence; with collision
    avoidance also collision and beam)."""
    n_colliding: int
    """Poses with a collision or beam failure, whether or not collision avoidance was imposed."""


def _checker(problem: Problem) -> FeasibilityChecker:
    cache = _LOCAL.__dict__.setdefault("checkers", {})
    key = (id(problem.robot), id(problem.cell))
    ch = cache.get(key)
    if ch is None or ch.robot is not problem.robot or ch.cell is not problem.cell:
        ch = FeasibilityChecker(problem.robot, problem.cell)
        if len(cache) > 16:
            cache.clear()
        cache[key] = ch
    return ch


def check_design(problem: Problem, q: np.ndarray, *, collision: bool = True) -> DesignCheck:
    """Independent feasibility check of a design (Drake geometry queries, all checks).

    Args:
        problem: robot and cell.
        q: (n, 6) [rad].
        collision: whether collision avoidance was imposed; without it, only joint-limit and
            incidence failures make a pose infeasible (collisions are still counted).

    Returns:
        :class:`DesignCheck`: the reports of the full check, the number of infeasible poses (w.r.t.
        the imposed constraints) and the number of poses with a collision or beam failure.
    """
    reports = _checker(problem).check(q, collision=True)
    imposed = {"joint_limit", "incidence"} | ({"collision", "beam"} if collision else set())
    n_bad = sum(any(f["check"] in imposed for f in r.failures) for r in reports)
    n_col = sum(any(f["check"] in ("collision", "beam") for f in r.failures) for r in reports)
    return DesignCheck(reports, n_bad, n_col)
