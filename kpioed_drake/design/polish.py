"""A final exchange on the exact KPI criterion after the optimiser (paper eq. 24a, 24c).

The optimiser ends at a local minimum of tr(Cs)/3 near its start. Its poses and the candidates of
the approximate design (the poses the column generation found, each feasible) form one pool; an
exchange over that pool (:func:`~kpioed_drake.design.approximate.design.exchange_counts`: add the
candidate that lowers ``Phi = tr(K^T M^-1 K)`` most, remove the copy whose removal raises it
least, rank-3 updates of ``M``) swaps poses the local solve could not move out of their basin,
and the optimiser is run again from the exchanged design. A round is kept only if the new solve
succeeds, passes the independent check and lowers the criterion; rounds stop when the exchange
changes nothing or a round does not help.

:func:`remove_poses` is the greedy removal the other way round (the fewest-poses search of
:mod:`~kpioed_drake.design.target` shrinks a design with it).

Units: millimetres and radians; ``Phi`` in mm^2 (``n`` times tr(Cs)/3 at the design's noise).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.design.approximate.design import exchange_counts, kpi_factor, replicate_poses
from kpioed_drake.design.approximate.search import pose_rows
from kpioed_drake.design.exact.check import DesignCheck
from kpioed_drake.design.exact.solve import SolveOutcome, SolveSetup, solve_checked
from kpioed_drake.estimation.problem import Problem

POLISH_ROUNDS = 2
"""Most exchange-and-solve rounds after the optimiser (the first usually gives the gain)."""
POLISH_RTOL = 1e-4
"""A round is kept if it lowers tr(Cs)/3 by more than this fraction."""
POLISH_MAX_VARIABLES = 420
"""Designs with more joint variables (poses times joints) are not polished: each round is a full
solve, which for large designs costs more than the gain is worth."""


@dataclasses.dataclass
class Polished:
    """The result of :func:`polish_design`.

    Attributes:
        sol: the solve kept (the optimiser's own if no round helped).
        check: its independent check.
        rounds: rounds kept.
        value_before: tr(Cs)/3 [mm^2] of the optimiser's result before the exchange.
        solve_s: wall time of the extra solves [s]; n_evals: their criterion evaluations.
    """

    sol: SolveOutcome
    check: DesignCheck
    rounds: int
    value_before: float
    solve_s: float
    n_evals: int


def exchanged(
    problem: Problem, q: np.ndarray, pool_q: np.ndarray, pool_F: np.ndarray, *, M0: np.ndarray | None = None
) -> np.ndarray | None:
    """The design ``q`` (n, nj) [rad] after an exchange over ``q`` and ``pool_q`` (m, nj) [rad] with
    rows ``pool_F`` (m, 3, k), or None if the exchange keeps every pose. ``M0``: (k, k) information
    held fixed (given poses)."""
    F = np.concatenate([pose_rows(problem, q), pool_F])
    counts = np.concatenate([np.ones(len(q), dtype=int), np.zeros(len(pool_q), dtype=int)])
    try:
        new = exchange_counts(F, kpi_factor(problem), counts, M0=M0)
    except np.linalg.LinAlgError:
        return None
    if np.array_equal(new, counts):
        return None
    return replicate_poses(problem, np.concatenate([q, pool_q]), new)


def polish_design(
    setup: SolveSetup,
    sol: SolveOutcome,
    check: DesignCheck,
    *,
    pool_q: np.ndarray,
    pool_F: np.ndarray | None = None,
    rounds: int = POLISH_ROUNDS,
    fixed_information: np.ndarray | None = None,
) -> Polished:
    """Exchange rounds on the exact KPI criterion after the optimiser (the module's docstring).

    Args:
        setup: the solve setup of the design (criterion ``kpi``).
        sol, check: the optimiser's result and its check (kept if no round helps).
        pool_q: (m, nj) [rad] feasible candidate poses (the approximate design's).
        pool_F: (m, 3, k) their rows (computed once if None).
        rounds: most rounds.
        fixed_information: (k, k) information held fixed (given poses), or None.
    """
    out = Polished(sol=sol, check=check, rounds=0, value_before=sol.value, solve_s=0.0, n_evals=0)
    n_vars = sol.q.size
    if not len(pool_q) or n_vars > POLISH_MAX_VARIABLES or not (sol.success and check.n_infeasible == 0):
        return out
    if pool_F is None:
        pool_F = pose_rows(setup.problem, pool_q)
    for _ in range(rounds):
        q_start = exchanged(setup.problem, out.sol.q, pool_q, pool_F, M0=fixed_information)
        if q_start is None:
            break
        new, new_check = solve_checked(setup, q_start, fixed_information=fixed_information)
        out.solve_s += new.solve_s
        out.n_evals += new.n_evals
        good = new.success and new_check.n_infeasible == 0
        if not (good and new.value < out.sol.value * (1.0 - POLISH_RTOL)):
            break
        out.sol, out.check, out.rounds = new, new_check, out.rounds + 1
    return out


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
    K, r = Js_each.shape[:2]  # r: 3 KPI rows per working pose, 6 with the orientation
    Js = Js_each.reshape(r * K, n_par)
    keep = np.arange(len(q))
    while len(keep) > m:
        Fk = F[keep]
        M_i = (np.einsum("iak,ial->kl", Fk, Fk) + M0)[None] - np.einsum("iak,ial->ikl", Fk, Fk)
        sign, _ = np.linalg.slogdet(M_i)
        ok = sign > 0
        kpi = np.full(len(keep), np.inf)
        if ok.any():
            X = np.linalg.solve(M_i[ok], np.broadcast_to(Js.T, (int(ok.sum()), n_par, r * K)))
            v = np.einsum("rk,ikr->ir", Js, X).reshape(-1, K, r).sum(axis=2) / 3.0  # (n_ok, K)
            kpi[ok] = v.max(axis=1) if problem.worst_case else v @ problem.weights
        keep = np.delete(keep, int(np.argmin(kpi)))
    return q[keep]
