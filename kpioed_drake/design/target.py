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
  (:func:`remove_poses`, greedy).

A design "reaches" V if its solve succeeded, it passes the independent check and its KPI is at most
V. The optimum of a local solver is not exactly monotone in N, so N is the smallest of the search:
N reaches V and N - 1 (as solved in the search) does not. Heuristic designs are nested in N (the
first N feasible draws), so for them the search is exact.

The lower bound for N poses is :func:`~kpioed_drake.design.approximate.certificate.certify`'s ``bound_mm2``
(no design of N poses among those it searched has a smaller tr(Cs)/3).
"""

from __future__ import annotations

import time

import numpy as np

from kpioed_drake.design.approximate.certificate import certify
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.optimize import min_new_poses, optimize_design
from kpioed_drake.design.report import DesignError, DesignReport
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem

MAX_TARGET_POSES = 600
"""Most poses the search tries by default (doubling stops here)."""


def remove_poses(problem: Problem, q: np.ndarray, m: int, *, given: np.ndarray | None = None) -> np.ndarray:
    """Greedily remove poses of ``q`` (n, 6) [rad] down to ``m``, each time the one whose removal
    raises the KPI (``problem.criteria``'s ``kpi_avg_var_mm2``; with ``given`` poses held fixed)
    least.

    Returns:
        (m, 6) the kept poses [rad], in their original order.
    """
    n_par = problem.n_params
    F = problem.F1(q).reshape(len(q), -1, n_par)
    M0 = np.zeros((n_par, n_par))
    if given is not None:
        Fg = problem.F1(given)
        M0 = Fg.T @ Fg
    Js_each = problem.Js_each()
    K = len(Js_each)
    Js = Js_each.reshape(3 * K, n_par)
    keep = np.arange(len(q))
    while len(keep) > m:
        Fk = F[keep]
        M_i = (np.einsum("iak,ial->kl", Fk, Fk) + M0)[None] - np.einsum("iak,ial->ikl", Fk, Fk)
        sign, _ = np.linalg.slogdet(M_i)
        ok = sign > 0
        kpi = np.full(len(keep), np.inf)
        if ok.any():
            X = np.linalg.solve(M_i[ok], np.broadcast_to(Js.T, (int(ok.sum()), n_par, 3 * K)))
            v = np.einsum("rk,ikr->ir", Js, X).reshape(-1, K, 3).sum(axis=2) / 3.0  # (n_ok, K)
            kpi[ok] = v.max(axis=1) if problem.worst_case else v @ problem.weights
        keep = np.delete(keep, int(np.argmin(kpi)))
    return q[keep]


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
    **options,
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
    n_given = 0 if given is None else len(np.atleast_2d(given))
    n_min = min_new_poses(problem, n_given)
    if given is not None:
        try:
            alone = problem.criteria(given)["kpi_avg_var_mm2"]
        except InputError:
            alone = np.inf
        if alone <= V:
            raise InputError(
                f"the {n_given} given poses already reach tr(Cs)/3 = {alone:.4g} <= {V:.4g} mm^2: "
                "no new poses are needed"
            )
    if max_poses < n_min:
        raise InputError(f"max_poses {max_poses} is below the fewest poses {n_min}")
    trail: list[dict] = []
    settings = dict(
        criterion=criterion, collision=collision, solver=solver, seed=seed, given=given, **options
    )

    def attempt(n: int, q0: np.ndarray | None) -> tuple[DesignReport, bool]:
        res = optimize_design(problem, n=n, q0=q0, allow_infeasible=True, **settings)
        ok = bool(res.success and res.feasible and res.kpi_avg_var_mm2 <= V)
        trail.append(
            {
                "n_poses": n,
                "kpi_avg_var_mm2": res.kpi_avg_var_mm2,
                "reached": ok,
                "success": res.success,
                "feasible": res.feasible,
                "solve_s": res.solve_s,
            }
        )
        return res, ok

    # doubling: grow the last design with heuristic poses until it reaches V
    lo, n, q0 = n_min - 1, n_min, None
    while True:
        res, ok = attempt(n, q0)
        if ok:
            hi, best = n, res
            break
        if n >= max_poses:
            raise DesignError(
                f"{problem.robot.name}: no design of up to {max_poses} poses reached tr(Cs)/3 <= {V:.4g} "
                f"mm^2 (the last: {res.kpi_avg_var_mm2:.4g} mm^2)",
                res,
            )
        lo, n_next = n, min(2 * n, max_poses)
        more = heuristic_design(problem, n=n_next - n, seed=seed + n_next, collision=collision)
        q0 = np.concatenate([res.q, more]) if res.feasible else None
        n = n_next
    # bisection: shrink the smallest design that reached V
    while hi - lo > 1:
        mid = (lo + hi) // 2
        res, ok = attempt(mid, remove_poses(problem, best.q, mid, given=given))
        if ok:
            hi, best = mid, res
        else:
            lo = mid
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
