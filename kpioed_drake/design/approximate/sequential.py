"""Poses added to measured ones: the approximate design's candidates chosen with the measured
information held fixed (paper section 3.1, sequential re-identification).

With measured poses of information ``M0`` the KPI criterion of ``n`` new poses from candidates
``x_i`` (rows ``F_i``, :mod:`.design`) is ``tr(K^T (M0 + sum_i c_i F_i^T F_i)^-1 K)`` = tr(Cs)/3 of
the combined design. :func:`given_counts` chooses the counts ``c`` greedily (the candidate that
lowers it most, one pose at a time: rank-3 updates of ``M``) and improves them by the
approximate start's exchanges with ``M0`` held fixed;
:func:`given_start` turns them into the optimiser's start (the measured poses' information makes
the approximate design of the new poses a different one than without them: the poses the measured
ones lack). :func:`fewest_new_poses` is the greedy count that reaches a target, the horizon an
online step plans over, and :func:`most_useful` the poses of a plan to measure first.

Units: millimetres and radians; the criterion in mm^2.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.design.approximate.design import (
    EXCHANGE_ITER,
    ApproximateDesign,
    exchange_counts,
    kpi_factor,
    rank3_changes,
    replicate_poses,
)
from kpioed_drake.design.approximate.search import pose_rows
from kpioed_drake.estimation.problem import Problem

REGULARIZATION = 1e-9
"""``M0`` plus this times its mean diagonal in the greedy steps: a few measured poses need not
determine every parameter (the first new poses do)."""


def _criterion(K: np.ndarray, M: np.ndarray) -> float:
    return float(np.sum(K * np.linalg.solve(M, K)))


def _regular(M0: np.ndarray) -> np.ndarray:
    scale = max(float(np.trace(M0)) / M0.shape[0], 1e-300)
    return M0 + REGULARIZATION * scale * np.eye(M0.shape[0])


def given_information(problem: Problem, given: np.ndarray | None) -> np.ndarray:
    """``M0 = F0^T F0`` (k, k) of the measured poses ``given`` (m, n_joints) [rad] (zeros if None)."""
    if given is None or len(given) == 0:
        return np.zeros((problem.n_params, problem.n_params))
    F0 = pose_rows(problem, given).reshape(-1, problem.n_params)
    return F0.T @ F0


def greedy_order(
    F: np.ndarray, K: np.ndarray, M0: np.ndarray, n: int, *, avail: np.ndarray | None = None
) -> list[int]:
    """Indices of ``n`` rows of ``F`` (m, 3, k), each the one that lowers the criterion most with
    ``M0`` and those before; ``avail`` (m,) bool: each row used at most once (else with repeats)."""
    G = F.transpose(0, 2, 1) @ F
    M, out = _regular(M0), []
    free = None if avail is None else np.asarray(avail, dtype=bool).copy()
    for _ in range(n):
        change = rank3_changes(F, M, K, 1.0)
        j = int(np.argmax(change if free is None else np.where(free, change, -np.inf)))
        out.append(j)
        M = M + G[j]
        if free is not None:
            free[j] = False
    return out


def given_counts(
    F: np.ndarray, K: np.ndarray, M0: np.ndarray, n: int, *, max_iter: int = EXCHANGE_ITER
) -> tuple[np.ndarray, float]:
    """Counts (m,) of ``n`` new poses among candidate rows ``F`` (m, 3, k) for measured information
    ``M0`` (k, k): greedy additions (:func:`greedy_order`), then the exchanges of
    :func:`~.design.exchange_counts` with ``M0`` held fixed.

    Returns:
        (counts (m,) summing to ``n``, tr(K^T M^-1 K) of the combined design [mm^2]).
    """
    c = np.bincount(greedy_order(F, K, M0, n), minlength=len(F))
    M0 = _regular(M0)
    c = exchange_counts(F, K, c, max_iter=max_iter, M0=M0)
    return c, _criterion(K, M0 + np.einsum("i,iak,ial->kl", c, F, F))


def given_start(problem: Problem, approx: ApproximateDesign, *, n: int, given: np.ndarray) -> np.ndarray:
    """(n, n_joints) [rad] the optimiser's start for ``n`` poses added to ``given``: the candidates
    of ``approx`` (an :class:`ApproximateDesign` of ``problem`` or a
    :class:`~.given.GivenDesign`: candidates ``q`` and rows ``F``, the noise included, every
    candidate feasible) chosen by :func:`given_counts` with the measured information."""
    counts, _ = given_counts(approx.F, kpi_factor(problem), given_information(problem, given), n)
    return replicate_poses(problem, approx.q, counts)


def fewest_new_poses(
    problem: Problem, approx: ApproximateDesign, *, given: np.ndarray, target: float, n_max: int
) -> int:
    """The fewest poses added greedily to ``given`` from ``approx``'s candidates (as in
    :func:`given_start`) whose combined tr(Cs)/3 is at most ``target`` [mm^2]; ``n_max`` if none up
    to it reaches it."""
    F, K = approx.F, kpi_factor(problem)
    G = F.transpose(0, 2, 1) @ F
    M = _regular(given_information(problem, given))
    for h in range(1, n_max + 1):
        M = M + G[int(np.argmax(rank3_changes(F, M, K, 1.0)))]
        if _criterion(K, M) <= target:
            return h
    return n_max


def most_useful(problem: Problem, q_plan: np.ndarray, *, given: np.ndarray, n: int) -> np.ndarray:
    """Indices (n,) of the poses of a plan ``q_plan`` (H, n_joints) [rad] to measure first: one at a
    time, the one that lowers tr(Cs)/3 of the measured and the chosen poses most."""
    F = pose_rows(problem, q_plan)
    avail = np.ones(len(q_plan), dtype=bool)
    return np.array(greedy_order(F, kpi_factor(problem), given_information(problem, given), n, avail=avail))
