"""The KPI design of plane touches and its certificate: column generation that stays on the planes.

The approximate design (paper eq. 24 with weights on poses; :mod:`kpioed_drake.design.approximate`)
over a candidate set ``X`` of feasible touches (:mod:`kpioed_drake.design.contact.poses`): the cone
program :func:`~kpioed_drake.design.approximate.design.solve_pool` over the candidates gives weights
``w`` and the dual ``Y`` (k, 3) with ``max g = 1`` over them, ``g(x) = ||F_x Y||^2``; a local search
for larger ``g`` (:func:`maximize_on_planes`) adds the touches it finds and the program is solved
again, until no search finds ``g > 1 + tol`` or :data:`ROUNDS` rounds are done.

The search stays in the feasible set: each step moves the joints along the gradient of ``g``
projected on the tangent of the pose's plane constraint (``dg/dq`` minus its component along
``dr/dq``, both closed form: ``dg/dq_j = 2 (F_x Y) . (dF_x/dq_j Y)``), then back onto the plane
(:func:`~kpioed_drake.design.contact.poses.project_to_planes`); a step is taken only if the new pose
is a feasible touch and ``g`` went up (else it is halved). It keeps each pose's plane.

The design: the weights rounded to ``n`` poses (efficient rounding) and improved by exchanges over
the candidates (:func:`~kpioed_drake.design.approximate.design.exchange_counts`), then polished on
the exact criterion with every pose kept on its plane (:func:`polish_on_planes`). Polished poses may
have a larger ``g`` than the search found: they then join the candidates and the column generation
continues (:data:`REFINEMENTS`), and the bound uses the largest ``g`` of the design's poses too.
The certificate (the bound of
:mod:`~kpioed_drake.design.approximate.certificate`, which holds for one row per pose): any ``n``
touches in the set searched have tr(Cs)/3 >= ``tr(K^T Y)^2 / (n g_max)``, ``g_max`` the largest
``g`` over the candidates, :data:`VERIFY_POOL` fresh feasible touches (another seed) and the local
maxima reached from the best of them. As with tracker designs this bounds every feasible design
only if the search missed no pose of larger ``g`` (a search, not a proof). The bound of every round's
``Y`` is valid over the set it searched once the candidates added later and the design's poses are
evaluated with it: the best round's is taken if larger than the last's (the column generation's bound
is not monotone). There is no exact
optimisation of the poses with the on-plane equality in the exact design's program (not built).

Units: millimetres and radians; variances in mm^2.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.design.approximate.design import (
    distinct_rows,
    efficient_rounding,
    exchange_counts,
    kpi_factor,
    replicate_poses,
    solve_pool,
)
from kpioed_drake.design.approximate.search import dual_values, pose_rows
from kpioed_drake.design.contact.poses import (
    on_plane_feasible,
    plane_clearance,
    plane_poses,
    plane_rows,
    project_to_planes,
)
from kpioed_drake.design.contact.problem import PlaneProblem

ROUNDS = 12
"""Most column-generation rounds."""
SEARCH_STEPS = 40
"""Projected-gradient steps of one local search."""
FIRST_STEP_RAD = 0.05
"""First step length of the search, the norm of the joint step [rad]."""
A_WEIGHT = 1e-3
"""Share of the normalised A-criterion in the rounding's exchanges (:func:`_rounded`)."""
LIVE_SHARE = 1e-9
"""A parameter whose weighted information is below this share of the largest belongs to a plane the
approximate design does not touch (no A-criterion term for it)."""
REFINEMENTS = 3
"""Most times the polished design's poses, beyond the search, join the candidates and the column
generation continues (for :data:`REFINE_ROUNDS` more rounds at most)."""
REFINE_ROUNDS = 10
POLISH_STEPS = 200
"""Most steps of :func:`polish_on_planes`."""
VERIFY_POOL = 2000
"""Fresh feasible touches on which ``g`` is evaluated after the column generation."""


@dataclasses.dataclass(frozen=True)
class PlaneDesign:
    """A plane-touch design and its certificate.

    Attributes:
        q: (n, nj) the design's poses [rad]; plane: (n,) the plane each touches (0-based).
        value: its tr(Cs)/3 [mm^2].
        bound: lower bound on tr(Cs)/3 of any n touches in the set searched [mm^2].
        efficiency: ``bound / value`` (<= 1).
        phi: the approximate design's ``Phi(w)`` [mm^2] (n times it: tr(Cs)/3 of n poses at those weights).
        g_max: the largest ``g`` found (>= 1; the candidates' maximum is 1).
        design_beyond_search: the design's largest ``g`` over ``g_max`` (> 1: the polish found
            touches beyond the search; the bound then uses the design's ``g``).
        rounds: column-generation rounds; converged: the last found no ``g > 1 + tol``.
        n_candidates: touches in the cone program at the end; n_searched: local searches run.
    """

    q: np.ndarray
    plane: np.ndarray
    value: float
    bound: float
    efficiency: float
    phi: float
    g_max: float
    design_beyond_search: float
    rounds: int
    converged: bool
    n_candidates: int
    n_searched: int


def _g_and_grad(problem: PlaneProblem, q: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``g`` (s,) of poses ``q`` (s, nj) and ``dg/dq`` (s, nj) [per rad]."""
    F, dF = problem.F1(q, with_dq=True)
    FY = F @ Y  # (s, 3)
    dFY = np.einsum("sjk,kc->sjc", dF[:, :, 0], Y)  # (s, nj, 3)
    return np.sum(FY * FY, axis=1), 2.0 * np.einsum("sc,sjc->sj", FY, dFY)


def maximize_on_planes(
    problem: PlaneProblem, q: np.ndarray, plane: np.ndarray, Y: np.ndarray, *, collision: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of ``g`` from feasible touches ``q`` (s, nj) of planes ``plane`` (s,) (module
    docstring): (the poses reached (s, nj), their ``g`` (s,)); every pose stays a feasible touch."""
    robot, N, d = problem.robot, problem.normals, problem.offsets
    cm = plane_clearance(problem, collision)
    q = np.array(q, dtype=float)
    g, grad = _g_and_grad(problem, q, Y)
    step = np.full(len(q), FIRST_STEP_RAD)
    for _ in range(SEARCH_STEPS):
        _, c, _ = plane_rows(problem, q, plane, N, d)
        t = grad - (np.sum(grad * c, axis=1) / np.sum(c * c, axis=1))[:, None] * c
        norm = np.linalg.norm(t, axis=1)
        live = (norm > 1e-12) & (step > 1e-6)
        if not live.any():
            break
        trial = np.clip(q + (step / np.where(live, norm, 1.0))[:, None] * t, robot.lower, robot.upper)
        trial = project_to_planes(problem, trial, plane, N, d)
        ok = live & on_plane_feasible(problem, trial, plane, N, d, clearance=cm, margin_mm=0.0)
        g_t, grad_t = _g_and_grad(problem, trial, Y)
        better = ok & (g_t > g)
        q[better], g[better], grad[better] = trial[better], g_t[better], grad_t[better]
        step = np.where(better, 1.5 * step, 0.5 * step)
    return q, g


def _phi_and_grad(
    problem: PlaneProblem, q: np.ndarray, K: np.ndarray, use: np.ndarray
) -> tuple[float, np.ndarray]:
    """tr(Cs)/3 = ``tr(K^T M^-1 K)`` [mm^2] of the design ``q`` (n, nj) over the columns ``use`` and
    its gradient (n, nj) [mm^2/rad]: ``-2 (F_i X) . (dF_i/dq_j X)``, ``X = M^-1 K`` (inf if singular)."""
    F, dF = problem.F1(q, with_dq=True)
    F, dF = F[:, use], dF[:, :, 0][..., use]
    try:
        X = np.linalg.solve(F.T @ F, K[use])
    except np.linalg.LinAlgError:
        return np.inf, np.zeros(q.shape)
    FX, dFX = F @ X, np.einsum("njk,kc->njc", dF, X)
    return float(np.sum(K[use] * X)), -2.0 * np.einsum("nc,njc->nj", FX, dFX)


def polish_on_planes(
    problem: PlaneProblem, q: np.ndarray, plane: np.ndarray, *, collision: bool, steps: int = POLISH_STEPS
) -> np.ndarray:
    """The design ``q`` (n, nj) [rad] improved on the exact criterion tr(Cs)/3, every pose kept a
    feasible touch of its plane ``plane`` (n,): steps of all poses at once along the criterion's
    gradient projected on each pose's plane tangent, projected back onto the planes (a pose whose
    step is infeasible stays), taken if the criterion went down (else the step is halved)."""
    N, d, K = problem.normals, problem.offsets, kpi_factor(problem)
    cm = plane_clearance(problem, collision)
    use = problem.used_columns(q)
    q = np.array(q, dtype=float)
    phi, grad = _phi_and_grad(problem, q, K, use)
    step = FIRST_STEP_RAD
    for _ in range(steps):
        _, c, _ = plane_rows(problem, q, plane, N, d)
        t = -(grad - (np.sum(grad * c, axis=1) / np.sum(c * c, axis=1))[:, None] * c)
        norm = float(np.linalg.norm(t, axis=1).max())
        if norm <= 0 or step < 1e-6:
            break
        trial = np.clip(q + (step / norm) * t, problem.robot.lower, problem.robot.upper)
        trial = project_to_planes(problem, trial, plane, N, d)
        ok = on_plane_feasible(problem, trial, plane, N, d, clearance=cm, margin_mm=0.0)
        trial[~ok] = q[~ok]
        phi_t, grad_t = _phi_and_grad(problem, trial, K, use)
        if phi_t < phi:
            q, phi, grad, step = trial, phi_t, grad_t, 1.5 * step
        else:
            step *= 0.5
    return q


def _starts(g: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Half the ``n`` starts the largest ``g``, half random others."""
    top = np.argsort(-g)[: n - n // 2]
    rest = np.setdiff1d(np.arange(len(g)), top)
    return np.concatenate([top, rng.choice(rest, size=min(n // 2, rest.size), replace=False)])


def _rounded(
    F: np.ndarray, K: np.ndarray, w: np.ndarray, n: int, phi: float, plane: np.ndarray
) -> np.ndarray:
    """Counts (m,) of an ``n``-pose design from weights ``w``: efficient rounding, then exchanges on
    ``[K, delta D]`` (``D``: the parameters' scales ``diag(M_w)^-1/2``, ``delta^2 = A_WEIGHT phi / k``:
    the normalised A-criterion, a small share, keeps the design regular, which rounding alone often
    does not with one row per pose), then exchanges on ``K`` alone; the first of these that is
    regular, else with the touches of a plane touched once or twice moved (``plane``: (m,) the
    candidates' planes)."""
    G = F.transpose(0, 2, 1) @ F
    diag = np.einsum("i,ikk->k", w, G)
    live = diag > LIVE_SHARE * diag.max()  # not the parameters of a plane the weights leave out
    D = np.diag(np.where(live, 1.0 / np.sqrt(np.where(live, diag, 1.0)), 0.0))
    K_aug = np.concatenate([K, np.sqrt(A_WEIGHT * phi / K.shape[0]) * D], axis=1)
    ridge = np.diag(np.where(live, 1e-12 * diag, 1e-12 * diag.max()))
    counts = exchange_counts(F, K_aug, efficient_rounding(w, n), M0=ridge)
    try:
        tries = [exchange_counts(F, K, counts, M0=ridge), counts]
    except np.linalg.LinAlgError:
        tries = [counts]
    tries += [_without_lone_planes(c, plane) for c in tries]
    return next((c for c in tries if _regular(np.einsum("i,ikl->kl", c, G))), tries[-1])


def _without_lone_planes(counts: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """``counts`` with the touches of a plane touched once or twice (its three parameters undetermined)
    moved to the most repeated candidates of the other planes, one each in turn."""
    c = counts.copy()
    lone = [k for k in np.unique(plane) if 0 < c[plane == k].sum() < 3]
    if not lone:
        return c
    moved = int(c[np.isin(plane, lone)].sum())
    c[np.isin(plane, lone)] = 0
    order = np.argsort(-c, kind="stable")
    for i in range(moved):
        c[order[i % max(int(np.sum(c > 0)), 1)]] += 1
    return c


def _regular(M: np.ndarray) -> bool:
    """The information ``M`` (k, k) determines every parameter whose column it has (a plane left out
    has none): the normalised matrix of those is positive definite (smallest eigenvalue > 1e-12)."""
    d = np.diag(M)
    on = d > 0
    s = 1.0 / np.sqrt(d[on])
    return bool(np.linalg.eigvalsh(M[np.ix_(on, on)] * s[:, None] * s[None, :])[0] > 1e-12)


def plane_design(
    problem: PlaneProblem,
    n: int,
    *,
    seed: int = 0,
    collision: bool = True,
    pool: int = 1000,
    starts: int = 24,
    rounds: int = ROUNDS,
    tol: float = 1e-3,
    verify: int = VERIFY_POOL,
) -> PlaneDesign:
    """The ``n``-touch KPI design on ``problem``'s planes and its certificate (module docstring).

    Args:
        seed: seed of the candidate pool (the verification pool: ``seed + 1``) and random starts.
        collision: touches avoid collisions (robot, obstacles; not the planes).
        pool: feasible touches to start from; starts: local searches per round.
        tol: stop when no search finds ``g > 1 + tol``.
        verify: fresh touches on which ``g`` is evaluated at the end (0: none).

    Raises:
        InputError: too few feasible touches, a cone program that fails or candidates that do not
            determine the parameters.
    """
    rng = np.random.default_rng(seed)
    N, d, K = problem.normals, problem.offsets, kpi_factor(problem)
    q, plane = plane_poses(problem, N, d, n=pool, seed=seed, collision=collision)
    F = pose_rows(problem, q)
    if verify:
        q_v, k_v = plane_poses(problem, N, d, n=verify, seed=seed + 1, collision=collision)
        F_v = pose_rows(problem, q_v)
    n_searched, done, limit, refined = 0, 0, rounds, 0
    best: tuple | None = None
    while True:
        done += 1
        sol = solve_pool(F, K)
        first = _starts(dual_values(F, sol.Y), starts, rng)
        q_new, g_new = maximize_on_planes(problem, q[first], plane[first], sol.Y, collision=collision)
        k_new, n_searched = plane[first], n_searched + len(first)
        searched = float(g_new.max()) <= 1.0 + tol
        if searched and verify:  # the fresh touches and the local maxima from the best of them
            g_v = dual_values(F_v, sol.Y)
            fv = _starts(g_v, starts, rng)
            q_l, g_l = maximize_on_planes(problem, q_v[fv], k_v[fv], sol.Y, collision=collision)
            n_searched += len(fv)
            q_new, k_new = np.concatenate([q_new, q_v, q_l]), np.concatenate([k_new, k_v, k_v[fv]])
            g_new = np.concatenate([g_new, g_v, g_l])
        g_max = max(1.0, float(g_new.max()))
        converged = g_max <= 1.0 + tol
        if best is None or sol.dual / g_max > best[0] / best[2]:
            best = (sol.dual, sol.Y, g_max)  # the round of the best bound over what it searched
        if converged or done >= limit:
            q_design = replicate_poses(problem, q, _rounded(F, K, sol.w, n, sol.phi, plane))
            k_design = problem.plane_of(q_design)
            q_design = polish_on_planes(problem, q_design, k_design, collision=collision)
            g_d = dual_values(pose_rows(problem, q_design), sol.Y)  # polished: may leave the set
            if float(g_d.max()) <= g_max * (1.0 + tol) or refined >= REFINEMENTS:
                break
            refined, limit = refined + 1, done + REFINE_ROUNDS  # its poses join the candidates
            q_new, k_new = np.concatenate([q_new, q_design]), np.concatenate([k_new, k_design])
            g_new = np.concatenate([g_new, g_d])
        F_new = pose_rows(problem, q_new)
        keep = (g_new > 1.0) & distinct_rows(F, F_new)
        q, plane, F = (
            np.concatenate([q, q_new[keep]]),
            np.concatenate([plane, k_new[keep]]),
            np.concatenate([F, F_new[keep]]),
        )
    g_design = float(g_d.max())
    value = float(problem.criteria(q_design)["kpi_avg_var_mm2"])
    bound = sol.dual / (max(g_max, g_design) * n)
    dual, Y, g_best = best  # valid too once the later candidates and the design are evaluated with its Y
    g_best = max(
        g_best, float(dual_values(F, Y).max()), float(dual_values(pose_rows(problem, q_design), Y).max())
    )
    bound = max(bound, dual / (g_best * n))
    return PlaneDesign(
        q=q_design,
        plane=problem.plane_of(q_design),
        value=value,
        bound=bound,
        efficiency=bound / value,
        phi=sol.phi,
        g_max=g_max,
        design_beyond_search=g_design / g_max,
        rounds=done,
        converged=converged,
        n_candidates=len(q),
        n_searched=n_searched,
    )
