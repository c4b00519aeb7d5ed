"""Approximate (continuous-weight) KPI design by column generation, and its rounding to n poses.

An approximate design puts weights ``w`` (sum 1) on candidate poses ``x_i``; its information is
``M(w) = sum_i w_i F_i^T F_i`` (``F_i``: the pose's rows of F1, eq. 24d: 3, 3 T with T targets, 6
with a probe's pose). Its KPI criterion (eq. 24a, 24c; Appendix: ``Cs = Js M^-1 Js^T``): the L-criterion

    Phi(w) = tr(A M(w)^-1),   A = K K^T,   K = Js^T / sqrt(3)   (Js: paper eq. 24e),

and an exact design of n poses has tr(Cs)/3 = Phi(its uniform weights) / n.

Over finitely many candidates the optimum is a second-order-cone program (Sagnol 2011); its dual

    sqrt(Phi*) = max_Y tr(K^T Y)   s.t.  ||F_i Y||_F <= 1  for every candidate i

is solved by :func:`.pool.solve_pool`; the cones' multipliers ``lambda_i`` give the weights
``w = lambda / sum(lambda)``. At the optimum ``Y`` is proportional to ``M(w)^-1 K``, so
``g(x) = ||F_x Y||_F^2`` is proportional to ``d(x, w) = tr(A M^-1 M_x M^-1)`` (equivalence theorem).

Candidates from the continuous feasible set (paper eq. 24b) come by column generation: random
feasible poses (the paper's heuristic, zero margin) and variants with joints at their limits, then
rounds of (1) the cone program over the working candidates, (2) pricing: ``g`` on every candidate
and local maxima of ``g`` over the feasible poses (:mod:`.search`), (3) maxima with ``g > 1`` join the
candidates, until nothing searched has ``g > 1 + tol``. The local maximisation is a search, not a
proof that no feasible pose has a larger ``g`` (:mod:`.certificate`: what is rigorous).

:func:`efficient_rounding` (Pukelsheim and Rieder 1992) and :func:`approximate_start`: n poses.

Units: millimetres and radians; ``Phi`` in mm^2 (a variance times a number of poses).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from kpioed_drake import progress
from kpioed_drake.design.approximate import search
from kpioed_drake.design.approximate.pool import CONE_TOL, solve_pool
from kpioed_drake.design.approximate.search import corner_poses, dual_values, maximize_dual, pose_rows
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.estimation.problem import Problem

POOL_POSES = 2000
"""Random feasible poses the column generation starts from."""
ROUNDS = 6
"""Column-generation rounds of :func:`approximate_design` by default."""
START_POOL = 1000
"""Random feasible poses of the cheaper column generation behind the optimiser's start
(:func:`approximate_start`; the start needs no converged bound)."""
START_ROUNDS = 4
"""Its column-generation rounds."""
START_SEARCHES = 12
"""Its local maximisations of ``g`` per round, :data:`START_RANDOM` of them from random candidates.
With :data:`START_POOL` and :data:`START_ROUNDS`, the start's column generation costs about half of
one with :data:`POOL_POSES`, :data:`ROUNDS` and 24 searches; less work gives a poorer
start, from which SNOPT ends higher and often takes longer (docs/certificate.md, design notes)."""
START_RANDOM = 4
EXCHANGE_ITER = 200
"""Most exchange steps (:func:`exchange_counts`) after the rounding of the optimiser's start."""
EXCHANGE_RTOL = 1e-9
"""An exchange is kept if it lowers ``Phi`` by more than this fraction."""
DET_FLOOR = 1e-9
"""A removal whose ``det(I - F M^-1 F^T)`` is below this would make ``M`` (nearly) singular."""
ROUND_TOL = 1e-3
"""Column generation stops when nothing searched has ``g > 1 + ROUND_TOL``."""
FIRST_WORKING = 600
"""Pool poses in the first cone program; then the support and the ``WORKING_POSES`` of largest ``g``."""
WORKING_POSES = 200
SUPPORT_WEIGHT = 1e-5
"""Weights below this count as zero (interior-point round-off) in support and rounding."""
SAME_POSE_TOL = 1e-6
"""A new pose with rows within this (relative) of a candidate's is not added."""
START_CONE_TOL = 1e-8
"""The cone programs' gap in the optimiser's start (it needs no certificate): a little faster than
:data:`~.pool.CONE_TOL` for a start of the same value to a few 1e-4 (docs/certificate.md, design
notes)."""


def kpi_factor(problem: Problem) -> np.ndarray:
    """``K = Js^T / sqrt(3)`` (k, 3): tr(Cs)/3 = tr(K^T M^-1 K); several working poses: (k, 3K)
    from the weighted stack :meth:`Problem.Js` (their weighted mean; every ``Y`` below is then
    (k, 3K))."""
    return problem.Js().T / math.sqrt(3.0)


@dataclasses.dataclass
class ApproximateDesign:
    """An approximate KPI design over the feasible poses and the lower bound found with it.

    Attributes:
        q: (m, 6) candidate poses [rad], each feasible (incidence and clearance rows >= 0).
        F: (m, 3, k) their weighted identification rows.
        w: (m,) optimum weights over the candidates (sum 1).
        phi: ``Phi(w)`` [mm^2]: an upper bound on the optimum ``Phi*`` (``w`` is a design).
        Y: (k, 3) dual matrix of the last cone program.
        dual: ``tr(K^T Y)^2`` [mm^2].
        g_max: largest ``g = ||F_x Y||_F^2`` over every pose searched with ``Y`` (>= 1).
        rounds: column-generation rounds run (with those of a warm start).
        converged: the last round found nothing with ``g > 1 + tol``.
        n_searched: local maximisations of ``g`` run.
        collision: whether the clearance constraints were imposed.
        solve_s: wall time [s] (with a warm start's).
        n_checked: poses besides the candidates at which ``g`` was evaluated with ``Y``
            (:func:`kpioed_drake.design.approximate.certificate.verify_search`).
    """

    q: np.ndarray
    F: np.ndarray
    w: np.ndarray
    phi: float
    Y: np.ndarray
    dual: float
    g_max: float
    rounds: int
    converged: bool
    n_searched: int
    collision: bool
    solve_s: float
    n_checked: int = 0

    @property
    def bound(self) -> float:
        """``dual / g_max`` [mm^2]: a lower bound on ``Phi*`` over the poses searched."""
        return self.dual / self.g_max

    @property
    def support(self) -> np.ndarray:
        """Indices of the candidates with weight above :data:`SUPPORT_WEIGHT`."""
        return np.flatnonzero(self.w > SUPPORT_WEIGHT)


def distinct_rows(F_old: np.ndarray, F_new: np.ndarray) -> np.ndarray:
    """(s,) bool: rows ``F_new`` (s, 3, k) unlike every old one and every earlier kept new one."""
    flat, ref = F_new.reshape(len(F_new), -1), F_old.reshape(len(F_old), -1)
    keep = np.zeros(len(flat), dtype=bool)
    for i, f in enumerate(flat):
        others = np.concatenate([ref, flat[:i][keep[:i]]])
        keep[i] = np.min(np.linalg.norm(others - f, axis=1)) > SAME_POSE_TOL * np.linalg.norm(f)
    return keep


def _first_pool(
    problem: Problem,
    warm: ApproximateDesign | None,
    *,
    collision: bool,
    seed: int,
    pool: int,
    first_working: int,
    working: int,
) -> tuple[np.ndarray, np.ndarray, int, int, float, np.ndarray]:
    """Where :func:`approximate_design` starts: the candidates ``q`` and their rows ``F``, the
    rounds, local searches and seconds already spent (``warm``'s, else 0) and the first working set."""
    if warm is None:
        q = heuristic_design(  # as many draws as the certificate's pool: two hands facing the
            problem, n=pool, seed=seed, collision=collision, margin_mm=0.0, max_draws=10**7
        )  # tracker are a few feasible poses in a thousand
        q = np.concatenate([q, corner_poses(problem, q, seed=seed, collision=collision)])
        return q, pose_rows(problem, q), 0, 0, 0.0, np.arange(min(len(q), first_working))
    work = np.union1d(warm.support, np.argsort(-dual_values(warm.F, warm.Y))[:working])
    return warm.q, warm.F, warm.rounds, warm.n_searched, warm.solve_s, work


def _with_found(
    problem: Problem, q: np.ndarray, F: np.ndarray, w: np.ndarray, q_new: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidates ``q``, their rows ``F`` and weights ``w`` with the poses ``q_new`` whose rows
    are not already among ``F`` (weight 0)."""
    F_new = pose_rows(problem, q_new)
    keep = distinct_rows(F, F_new)
    q, F = np.concatenate([q, q_new[keep]]), np.concatenate([F, F_new[keep]])
    return q, F, np.concatenate([w, np.zeros(int(keep.sum()))])


def approximate_design(
    problem: Problem,
    *,
    collision: bool = True,
    seed: int = 0,
    max_rounds: int = ROUNDS,
    pool: int = POOL_POSES,
    starts: int | None = None,
    random_starts: int | None = None,
    tol: float = ROUND_TOL,
    warm: ApproximateDesign | None = None,
    first_working: int = FIRST_WORKING,
    working: int = WORKING_POSES,
    cone_tol: float = CONE_TOL,
) -> ApproximateDesign:
    """The approximate KPI design over the feasible poses, by column generation (module docstring).

    Args:
        problem: robot, cell, model, ``q_work`` and noise.
        collision: impose the clearance constraints (as the design does).
        seed: seed of the random pool and random starts.
        max_rounds: most rounds (in all, with those of ``warm``).
        pool: random feasible poses to start from (:func:`heuristic_design`, zero margin); their
            feasible variants with joints at limits (:func:`corner_poses`) join them.
        starts: local maximisations per round, ``random_starts`` of them from random candidates
            (None: :func:`.search.round_starts` of the robot).
        tol: stop when nothing searched has ``g > 1 + tol``.
        warm: continue from this design's candidates (same problem and ``collision``).
        first_working: pool poses in the first cone program; working: candidates of largest ``g``
            in each later one (besides the support).
        cone_tol: Clarabel's tolerances (:func:`solve_pool`).

    Returns:
        :class:`ApproximateDesign`.
    """
    t0 = time.perf_counter()
    s0, r0 = search.round_starts(problem.robot.n_joints)
    starts, random_starts = s0 if starts is None else starts, r0 if random_starts is None else random_starts
    rng = np.random.default_rng(seed)
    K = kpi_factor(problem)
    q, F, done, n_searched, before_s, work = _first_pool(
        problem, warm, collision=collision, seed=seed, pool=pool, first_working=first_working, working=working
    )
    rounds = done
    while rounds < max(max_rounds, done + 1):
        rounds += 1
        sol = solve_pool(F[work], K, tol=cone_tol)
        w = np.zeros(len(q))
        w[work] = sol.w
        g_max, q, F, w = _price(problem, q, F, w, sol.Y, rng, starts, random_starts, collision=collision)
        n_searched += starts
        progress.step(g_max=g_max)
        converged = g_max <= 1.0 + tol
        if converged:
            break
        work = np.union1d(np.flatnonzero(w > SUPPORT_WEIGHT), np.argsort(-dual_values(F, sol.Y))[:working])
    return ApproximateDesign(
        q=q,
        F=F,
        w=w,
        phi=sol.phi,
        Y=sol.Y,
        dual=sol.dual,
        g_max=g_max,
        rounds=rounds,
        converged=converged,
        n_searched=n_searched,
        collision=collision,
        solve_s=before_s + time.perf_counter() - t0,
        n_checked=0 if warm is None else warm.n_checked,
    )


def _price(
    problem: Problem,
    q: np.ndarray,
    F: np.ndarray,
    w: np.ndarray,
    Y: np.ndarray,
    rng: np.random.Generator,
    starts: int,
    random_starts: int,
    *,
    collision: bool,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """The pricing of a round: ``g`` under ``Y`` on every candidate and at the local maxima from the
    ``starts - random_starts`` candidates of largest ``g`` and ``random_starts`` random ones; the
    largest ``g`` and the candidates ``q``, rows ``F`` and weights ``w`` with the maxima of
    ``g > 1`` added (weight 0)."""
    g = dual_values(F, Y)
    first = np.concatenate(
        [np.argsort(-g)[: starts - random_starts], rng.choice(len(q), size=random_starts, replace=False)]
    )
    q_max, g_found, ok = maximize_dual(problem, q[first], Y, collision=collision)
    new = ok & (g_found > 1.0)
    if new.any():
        q, F, w = _with_found(problem, q, F, w, q_max[new])
    return max(float(g.max()), float(g_found[ok].max(initial=0.0))), q, F, w


def efficient_rounding(w: np.ndarray, n: int) -> np.ndarray:
    """Counts (m,) summing to ``n`` from weights ``w`` (m,) (Pukelsheim and Rieder 1992).

    ``c_i = ceil((n - l/2) w_i)`` on the ``l`` support points (``w_i > SUPPORT_WEIGHT``); then the
    count with the smallest ``c_i / w_i`` is raised, or the one with the largest ``(c_i - 1) / w_i``
    lowered, until the counts sum to ``n``.
    """
    w = np.asarray(w, dtype=float)
    sup = w > SUPPORT_WEIGHT
    ws = np.where(sup, w, 1.0)
    c = np.where(sup, np.ceil((n - sup.sum() / 2.0) * ws), 0).astype(int)
    while c.sum() < n:
        c[np.argmin(np.where(sup, c / ws, np.inf))] += 1
    while c.sum() > n:
        c[np.argmax(np.where(c > 0, (c - 1) / ws, -np.inf))] -= 1
    return c


def rank3_changes(F: np.ndarray, M: np.ndarray, K: np.ndarray, sign: float) -> np.ndarray:
    """(m,) change magnitudes of ``Phi = tr(K^T M^-1 K)`` when one copy of each candidate's rows
    ``F`` (m, 3, k) ((m, 3 T, k) with T targets) is added (``sign`` +1: the decrease
    ``tr((F X)^T (I + F M^-1 F^T)^-1 F X)``, ``X = M^-1 K``) or removed (``sign`` -1: the increase,
    with ``I - F M^-1 F^T``)."""
    Minv = np.linalg.inv(M)
    FM = F @ Minv  # (m, 3, k)
    S = np.eye(F.shape[1]) + sign * (FM @ F.transpose(0, 2, 1))
    FX = FM @ K  # (m, 3, 3)
    if F.shape[1] != 3:  # several targets: 3 T rows per pose, batched solves instead of 3 x 3 adjugates
        det = np.linalg.det(S)
        ok = det > DET_FLOOR
        change = np.full(len(F), np.inf if sign < 0 else -np.inf)
        change[ok] = np.einsum("iac,iac->i", FX[ok], np.linalg.solve(S[ok], FX[ok]))
        return change
    r0, r1, r2 = S[:, 0], S[:, 1], S[:, 2]
    adj = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=2)  # det * S^-1
    det = np.einsum("ia,ia->i", r0, adj[:, :, 0])
    change = np.einsum("iac,iab,ibc->i", FX, adj, FX)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(det > DET_FLOOR, change / det, np.inf if sign < 0 else -np.inf)


def exchange_counts(
    F: np.ndarray,
    K: np.ndarray,
    counts: np.ndarray,
    *,
    max_iter: int = EXCHANGE_ITER,
    M0: np.ndarray | None = None,
) -> np.ndarray:
    """Improve an exact design over candidates by exchanges (Mitchell's DETMAX for the L-criterion).

    Each step adds a copy of the candidate whose addition lowers ``Phi`` most, then removes the
    copy whose removal raises it least; it is kept if ``Phi`` of the n poses went down, else the
    exchange stops. Rank-3 updates of ``M`` (Sherman-Morrison-Woodbury), all candidates at once.

    Args:
        F: (m, 3, k) candidate rows; K: (k, 3) the KPI factor; counts: (m,) copies per candidate
            (their information, with ``M0``, must be regular).
        max_iter: most exchange steps.
        M0: (k, k) information held fixed beside the candidates' (measured poses), or None.

    Returns:
        counts (m,) with the same sum, ``Phi`` (of the candidates and ``M0``) no larger than the
        given counts'.
    """
    c = np.asarray(counts, dtype=int).copy()
    G = F.transpose(0, 2, 1) @ F  # (m, k, k)
    M = np.einsum("i,ikl->kl", c, G) + (0.0 if M0 is None else M0)
    phi = float(np.sum(K * np.linalg.solve(M, K)))
    for _ in range(max_iter):
        j = int(np.argmax(rank3_changes(F, M, K, 1.0)))
        c[j] += 1
        r = int(np.argmin(np.where(c > 0, rank3_changes(F, M + G[j], K, -1.0), np.inf)))
        c[r] -= 1
        if r == j:
            break
        M_new = M + G[j] - G[r]
        phi_new = float(np.sum(K * np.linalg.solve(M_new, K)))
        if not phi_new < phi * (1.0 - EXCHANGE_RTOL):
            c[j], c[r] = c[j] - 1, c[r] + 1
            break
        M, phi = M_new, phi_new
    return c


def replicate_poses(problem: Problem, q: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Poses ``q`` (m, 6) [rad] repeated ``counts`` (m,) times: (sum(counts), 6) [rad].

    Copies of a pose are, where the joint limits allow, the same configuration with joint 4 and/or
    joint 6 turned by a full turn (same geometry and information, other angles); further copies
    are identical.
    """
    nj = problem.robot.n_joints
    wrist = (3, 5) if problem.robot.chain is None else np.flatnonzero(~problem.robot.prismatic)[-3:]
    if problem.robot.joint_map is not None:  # a coupled joint's full turn would break the coupling
        N, _ = problem.robot.joint_map.coupling_equations()
        wrist = [j for j in wrist if not np.any(np.abs(N[:, j]) > 1e-12)]
    turns = [np.zeros(nj)] + [s * 2 * math.pi * np.eye(nj)[j] for j in wrist for s in (1, -1)]
    lo, up = problem.robot.lower, problem.robot.upper
    out = []
    counts = np.asarray(counts, dtype=int)
    if counts.shape != (len(q),):
        raise ValueError(f"counts {counts.shape} do not match the {len(q)} poses")
    for i in np.flatnonzero(counts):  # the candidates used (most have no copy)
        qi = q[i]
        variants = [qi + t for t in turns if np.all(qi + t >= lo) and np.all(qi + t <= up)]
        out += [variants[r % len(variants)] for r in range(int(counts[i]))]
    return np.array(out, dtype=float).reshape(-1, nj)


def start_approximation(problem: Problem, *, collision: bool = True, seed: int = 0) -> ApproximateDesign:
    """The cheaper approximate design behind the optimiser's start: :data:`START_POOL` poses,
    :data:`START_ROUNDS` rounds and :data:`START_SEARCHES` local searches per round."""
    return approximate_design(
        problem,
        collision=collision,
        seed=seed,
        max_rounds=START_ROUNDS,
        pool=START_POOL,
        starts=START_SEARCHES,
        random_starts=START_RANDOM,
        cone_tol=START_CONE_TOL,
    )


def approximate_start(
    problem: Problem,
    *,
    n: int,
    collision: bool = True,
    seed: int = 0,
    approx: ApproximateDesign | None = None,
) -> np.ndarray:
    """The optimiser's start: the approximate design rounded to ``n`` poses.

    Args:
        problem: robot, cell, model, ``q_work`` and noise; n: number of poses.
        collision, seed: those of :func:`approximate_design`.
        approx: an approximate design of the same problem and ``collision``; None:
            :func:`start_approximation`.

    Returns:
        q0: (n, 6) [rad], every pose a candidate (feasible); not an n-pose optimum (rounding loses).
    """
    if approx is None:
        approx = start_approximation(problem, collision=collision, seed=seed)
    counts = efficient_rounding(approx.w, n)
    try:
        counts = exchange_counts(approx.F, kpi_factor(problem), counts)
    except np.linalg.LinAlgError:  # the rounded design does not determine the parameters: keep it
        pass
    return replicate_poses(problem, approx.q, counts)
