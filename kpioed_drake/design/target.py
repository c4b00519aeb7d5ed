"""Fewest poses for a target precision (paper, Conclusion): the smallest N reaching tr(Cs)/3 <= V.

The paper notes that a design with a lower TCP variance for the same number of poses also needs
fewer poses for a given precision, and so a shorter re-identification. :func:`design_for_target`
finds the smallest number N of poses whose optimised design (paper eq. 24, any design method of
:func:`~kpioed_drake.design.optimize.optimize_design`) reaches ``kpi_avg_var_mm2 <= V`` (tr(Cs)/3,
or the KPI of several working poses), optionally given poses already measured (then N counts the
new poses).

The search is warm-started:

- doubling from the fewest poses (:func:`~kpioed_drake.design.optimize.min_new_poses`) until a
  design reaches V, each solve started from the previous design plus heuristic poses;
- bisection between the largest N that failed and the smallest that reached V, each solve started
  from the smallest design that reached V with the poses removed that raise its KPI least
  (:func:`~kpioed_drake.design.polish.remove_poses`, greedy).

Each step is one call, :func:`~kpioed_drake.design.optimize.target_attempt` (its start and its
solve), so the search leaves this module once per design tried.

A design "reaches" V if its solve succeeded, it passes the independent check and its KPI is at most
V. The optimum of a local solver is not exactly monotone in N, so N is the smallest of the search:
N reaches V and N - 1 (as solved in the search) does not. Heuristic designs are nested in N (the
first N feasible draws), so for them the search is exact.

The lower bound for N poses is :func:`~kpioed_drake.design.approximate.certificate.certify`'s ``bound_mm2``
(no design of N poses among those it searched has a smaller tr(Cs)/3).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from kpioed_drake.design.approximate.certificate import certify
from kpioed_drake.design.optimize import first_target_n, target_attempt
from kpioed_drake.design.report import DesignError, DesignReport
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem

MAX_TARGET_POSES = 600
"""Most poses the search tries by default (doubling stops here)."""


def design_for_target(
    problem: Problem,
    target_var_mm2: float,
    *,
    criterion: str = "kpi",
    collision: bool = True,
    solver: str = "snopt",
    seed: int = 0,
    given: np.ndarray | None = None,
    max_poses: int = MAX_TARGET_POSES,
    bound: bool = True,
    **options: Any,
) -> DesignReport:
    """The design of the fewest poses whose KPI reaches ``target_var_mm2`` (warm-started search).

    Args:
        problem: robot, cell, model, working pose(s) and noise.
        target_var_mm2: the target V of tr(Cs)/3 (the KPI of several working poses) [mm^2].
        criterion, collision, solver, seed: see
            :func:`~kpioed_drake.design.optimize.optimize_design` (every solve of the search).
        given: (m, 6) [rad] poses already measured, held fixed; N then counts the new poses.
        max_poses: most poses tried.
        bound: compute the lower bound for N poses (:func:`certify`; not with ``given``).
        **options: further arguments of ``optimize_design`` (``starts``, ``active_rows``, ...).

    Returns:
        :class:`DesignReport` of the N poses found, with ``target``: ``target_var_mm2``,
        ``n_poses`` (N), ``kpi_avg_var_mm2`` (its KPI) [mm^2], ``bound_mm2`` (lower bound on
        tr(Cs)/3 of N poses [mm^2], None if not computed), ``bound_note``, ``search_s`` (wall time
        [s]) and ``trail``: every design tried (``n_poses``, ``kpi_avg_var_mm2``, ``reached``,
        ``success``, ``feasible``, ``solve_s``), in order.

    Raises:
        InputError: bad target or arguments; the given poses alone already reach the target.
        DesignError: no design of up to ``max_poses`` poses reached the target.
    """
    t0 = time.perf_counter()
    V = float(target_var_mm2)
    if not np.isfinite(V) or V <= 0:
        raise InputError(
            f"target_var_mm2 must be a positive variance [mm^2], got {target_var_mm2!r}",
            fields=("target_var_mm2",),
        )
    n_min = first_target_n(problem, V, given, max_poses)
    settings = dict(
        criterion=criterion, collision=collision, solver=solver, seed=seed, given=given, **options
    )
    # one solve per step: doubling from n_min until a design reaches V (each grown from the last
    # design), then bisection between the largest N that failed and the smallest that reached V
    # (each shrunk from the smallest design that reached V)
    trail: list[dict] = []
    lo, hi, n, best, last = n_min - 1, None, n_min, None, None
    while hi is None or hi - lo > 1:
        res, row = target_attempt(
            problem, n, V, last if hi is None else best, shrink=hi is not None, settings=settings
        )
        trail.append(row)
        if row["reached"]:
            hi, best = n, res
        elif hi is None and n >= max_poses:
            raise DesignError(
                f"{problem.robot.name}: no design of up to {max_poses} poses reached tr(Cs)/3 <= {V:.4g} "
                f"mm^2 (the last: {row['kpi_avg_var_mm2']:.4g} mm^2)",
                res,
            )
        else:
            lo = n
        last = res
        n = min(2 * n, max_poses) if hi is None else (lo + hi) // 2
    bound_mm2, note = _bound(problem, best.q, bound=bound, given=given, collision=collision, seed=seed)
    best.target = {
        "target_var_mm2": V,
        "n_poses": hi,
        "kpi_avg_var_mm2": best.kpi_avg_var_mm2,
        "bound_mm2": bound_mm2,
        "bound_note": note,
        "search_s": time.perf_counter() - t0,
        "trail": trail,
    }
    return best


def _bound(
    problem: Problem, q, *, bound: bool, given, collision: bool, seed: int
) -> tuple[float | None, str]:
    """Lower bound on tr(Cs)/3 of ``len(q)`` poses (:func:`certify`) and a note on it."""
    if not bound:
        return None, "not computed (bound=False)"
    if given is not None:
        return None, "not available with given poses (the certificate bounds designs of N poses alone)"
    try:
        cert = certify(problem, q, collision=collision, seed=seed)
    except Exception as exc:  # the certificate is optional: report why it is missing
        return None, f"certify failed: {exc}"
    note = f"certify: efficiency {cert['efficiency']:.3f}, {cert['method']}"
    if problem.worst_case:
        note += "; a bound on the weighted mean, hence also on the worst working pose"
    return float(cert["bound_mm2"]), note
