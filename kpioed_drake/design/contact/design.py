"""The KPI design of a contact system and its certificate: column generation that stays on its surfaces.

The contact systems (:mod:`.surfaces`): touches of planes, or a pivot ballbar's tool ball on the
sphere about its pivot. The approximate design (paper eq. 24 with weights on poses;
:mod:`kpioed_drake.design.approximate`) over a candidate set ``X`` of feasible poses on the surfaces
(:mod:`kpioed_drake.design.contact.poses`): the cone program
:func:`~kpioed_drake.design.approximate.pool.solve_pool` over the candidates gives weights ``w``
and the dual ``Y`` (k, 3) with ``max g = 1`` over them, ``g(x) = ||F_x Y||^2``; a local search for
larger ``g`` (:func:`maximize_on_surfaces`) adds the poses it finds and the program is solved again,
until no search finds ``g > 1 + tol`` or :data:`ROUNDS` rounds are done.

The search stays in the feasible set: each step moves the joints along the gradient of ``g``
projected on the tangent of the pose's surface constraint (``dg/dq`` minus its component along
``dr/dq``, both closed form: ``dg/dq_j = 2 (F_x Y) . (dF_x/dq_j Y)``), then back onto the surface
(:func:`~kpioed_drake.design.contact.poses.project_to_surfaces`); a step is taken only if the new
pose is feasible and ``g`` went up (else it is halved). It keeps each pose's surface.

The design: the weights rounded to ``n`` poses (efficient rounding) and improved by exchanges over
the candidates (:func:`~kpioed_drake.design.approximate.design.exchange_counts`), then polished on
the exact criterion with every pose kept on its surface (:func:`polish_on_surfaces`). Polished poses
may have a larger ``g`` than the search found: they then join the candidates and the column
generation continues (:data:`REFINEMENTS`), and the bound uses the largest ``g`` of the design's
poses too. The certificate (the bound of :mod:`~kpioed_drake.design.approximate.certificate`, which
holds for one row per pose): any ``n`` poses in the set searched have tr(Cs)/3 >=
``tr(K^T Y)^2 / (n g_max)``, ``g_max`` the largest ``g`` over the candidates, :data:`VERIFY_POOL`
fresh feasible poses (another seed) and the local maxima reached from the best of them. As with
tracker designs this bounds every feasible design only if the search missed no pose of larger ``g``
(a search, not a proof). The bound of every round's ``Y`` is valid over the set it searched once the
candidates added later and the design's poses are evaluated with it: the best round's is taken if
larger than the last's (the column generation's bound is not monotone). There is no exact
optimisation of the poses with the on-surface equality in the exact design's program (not built).

Units: millimetres and radians; variances in mm^2.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from kpioed_drake.design.approximate.design import (
    distinct_rows,
    efficient_rounding,
    exchange_counts,
    kpi_factor,
    replicate_poses,
)
from kpioed_drake.design.approximate.pool import PoolSolution, solve_pool
from kpioed_drake.design.approximate.search import dual_values, pose_rows
from kpioed_drake.design.contact.poses import (
    contact_clearance,
    contact_poses,
    on_surface_feasible,
    project_to_surfaces,
    surface_rows,
)
from kpioed_drake.design.contact.problem import ContactProblem
from kpioed_drake.errors import InputError

ROUNDS = 12
"""Most column-generation rounds."""
SEARCH_STEPS = 40
"""Projected-gradient steps of one local search."""
FIRST_STEP_RAD = 0.05
"""First step length of the search, the norm of the joint step [rad]."""
A_WEIGHT = 1e-3
"""Share of the normalised A-criterion in the rounding's exchanges (:func:`_rounded`)."""
LIVE_SHARE = 1e-9
"""A parameter whose weighted information is below this share of the largest belongs to a surface
the approximate design does not use (no A-criterion term for it)."""
REFINEMENTS = 3
"""Most times the polished design's poses, beyond the search, join the candidates and the column
generation continues (for :data:`REFINE_ROUNDS` more rounds at most)."""
REFINE_ROUNDS = 10
"""Most column-generation rounds after each refinement."""
POLISH_STEPS = 200
"""Most steps of :func:`polish_on_surfaces`."""
VERIFY_POOL = 2000
"""Fresh feasible poses on which ``g`` is evaluated after the column generation."""
MIN_PER_SURFACE = 3
"""Fewest poses on a surface the design uses (a plane's or a pivot's three parameters)."""


@dataclasses.dataclass(frozen=True)
class ContactDesign:
    """A contact design and its certificate.

    Attributes:
        q: (n, nj) the design's poses [rad]; surface: (n,) the plane or pivot of each (0-based).
        value: its tr(Cs)/3 [mm^2].
        bound: lower bound on tr(Cs)/3 of any n poses in the set searched [mm^2].
        efficiency: ``bound / value`` (<= 1).
        phi: the approximate design's ``Phi(w)`` [mm^2] (n times it: tr(Cs)/3 of n poses at those weights).
        g_max: the largest ``g`` found (>= 1; the candidates' maximum is 1).
        design_beyond_search: the design's largest ``g`` over ``g_max`` (> 1: the polish found
            poses beyond the search; the bound then uses the design's ``g``).
        rounds: column-generation rounds; converged: the last found no ``g > 1 + tol``.
        n_candidates: poses in the cone program at the end; n_searched: local searches run.
    """

    q: np.ndarray
    surface: np.ndarray
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

    @property
    def plane(self) -> np.ndarray:
        """(n,) the plane each touch touches (a plane design's :attr:`surface`)."""
        return self.surface

    @property
    def pivot(self) -> np.ndarray:
        """(n,) the pivot of each pose (a ballbar design's :attr:`surface`)."""
        return self.surface


def _g_and_grad(problem: ContactProblem, q: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``g`` (s,) of poses ``q`` (s, nj) and ``dg/dq`` (s, nj) [per rad]."""
    F, dF = problem.F1(q, with_dq=True)
    FY = F @ Y  # (s, 3)
    dFY = np.einsum("sjk,kc->sjc", dF[:, :, 0], Y)  # (s, nj, 3)
    return np.sum(FY * FY, axis=1), 2.0 * np.einsum("sc,sjc->sj", FY, dFY)


def _tangent(grad: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(s, nj) the joint gradients ``grad`` without their components along the constraints' ``c``."""
    return grad - (np.sum(grad * c, axis=1) / np.sum(c * c, axis=1))[:, None] * c


def _step_onto(
    problem: ContactProblem, q: np.ndarray, surface: np.ndarray, cm
) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``q`` clipped to the joint limits and projected onto their surfaces, and which are
    feasible there (clearance ``cm``, no margin)."""
    S = problem.surfaces
    trial = project_to_surfaces(problem, np.clip(q, problem.robot.lower, problem.robot.upper), surface, S)
    return trial, on_surface_feasible(problem, trial, surface, S, clearance=cm, margin_mm=0.0)


def maximize_on_surfaces(
    problem: ContactProblem, q: np.ndarray, surface: np.ndarray, Y: np.ndarray, *, collision: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of ``g`` from feasible poses ``q`` (s, nj) on surfaces ``surface`` (s,) (module
    docstring): (the poses reached (s, nj), their ``g`` (s,)); every pose stays feasible."""
    cm = contact_clearance(problem, problem.surfaces, collision)
    q = np.array(q, dtype=float)
    g, grad = _g_and_grad(problem, q, Y)
    step = np.full(len(q), FIRST_STEP_RAD)
    for _ in range(SEARCH_STEPS):
        _, c, _ = surface_rows(problem, q, surface, problem.surfaces)
        t = _tangent(grad, c)
        norm = np.linalg.norm(t, axis=1)
        live = (norm > 1e-12) & (step > 1e-6)
        if not live.any():
            break
        trial, ok = _step_onto(problem, q + (step / np.where(live, norm, 1.0))[:, None] * t, surface, cm)
        g_t, grad_t = _g_and_grad(problem, trial, Y)
        better = live & ok & (g_t > g)
        q[better], g[better], grad[better] = trial[better], g_t[better], grad_t[better]
        step = np.where(better, 1.5 * step, 0.5 * step)
    return q, g


def _phi_and_grad(
    problem: ContactProblem, q: np.ndarray, K: np.ndarray, use: np.ndarray
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


def polish_on_surfaces(
    problem: ContactProblem,
    q: np.ndarray,
    surface: np.ndarray,
    *,
    collision: bool,
    steps: int = POLISH_STEPS,
) -> np.ndarray:
    """The design ``q`` (n, nj) [rad] improved on the exact criterion tr(Cs)/3, every pose kept
    feasible on its surface ``surface`` (n,): steps of all poses at once along the criterion's
    gradient projected on each pose's surface tangent, projected back onto the surfaces (a pose
    whose step is infeasible stays), taken if the criterion went down (else the step is halved)."""
    K = kpi_factor(problem)
    cm = contact_clearance(problem, problem.surfaces, collision)
    use = problem.used_columns(q)
    q = np.array(q, dtype=float)
    phi, grad = _phi_and_grad(problem, q, K, use)
    step = FIRST_STEP_RAD
    for _ in range(steps):
        _, c, _ = surface_rows(problem, q, surface, problem.surfaces)
        t = -_tangent(grad, c)
        norm = float(np.linalg.norm(t, axis=1).max())
        if norm <= 0 or step < 1e-6:
            break
        trial, ok = _step_onto(problem, q + (step / norm) * t, surface, cm)
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
    F: np.ndarray, K: np.ndarray, w: np.ndarray, n: int, phi: float, surface: np.ndarray
) -> np.ndarray:
    """Counts (m,) of an ``n``-pose design from weights ``w``: efficient rounding, then exchanges on
    ``[K, delta D]`` (``D``: the parameters' scales ``diag(M_w)^-1/2``, ``delta^2 = A_WEIGHT phi / k``:
    the normalised A-criterion, a small share, keeps the design regular, which rounding alone often
    does not with one row per pose), then exchanges on ``K`` alone; the first of these that is
    regular, else with the poses of a surface used once or twice moved (``surface``: (m,) the
    candidates' surfaces)."""
    G = F.transpose(0, 2, 1) @ F
    diag = np.einsum("i,ikk->k", w, G)
    live = diag > LIVE_SHARE * diag.max()  # not the parameters of a surface the weights leave out
    D = np.diag(np.where(live, 1.0 / np.sqrt(np.where(live, diag, 1.0)), 0.0))
    K_aug = np.concatenate([K, np.sqrt(A_WEIGHT * phi / K.shape[0]) * D], axis=1)
    ridge = np.diag(np.where(live, 1e-12 * diag, 1e-12 * diag.max()))
    rounded = efficient_rounding(w, n)
    counts = _exchanged(F, K_aug, rounded, ridge)
    counts = rounded if counts is None else counts
    tries = [c for c in (_exchanged(F, K, counts, ridge), counts) if c is not None]
    tries += [_without_lone_surfaces(c, surface) for c in tries]
    return next((c for c in tries if _regular(np.einsum("i,ikl->kl", c, G))), tries[-1])


def _exchanged(F: np.ndarray, K: np.ndarray, counts: np.ndarray, M0: np.ndarray) -> np.ndarray | None:
    """:func:`exchange_counts` from ``counts``, or None when an exchange's information is singular (the
    ridge ``M0`` cancels in floating point once the one pose informing a parameter is removed)."""
    try:
        return exchange_counts(F, K, counts, M0=M0)
    except np.linalg.LinAlgError:
        return None


def _without_lone_surfaces(counts: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """``counts`` with the poses of a surface used once or twice (its three parameters undetermined)
    moved to the most repeated candidates of the other surfaces, one each in turn."""
    c = counts.copy()
    lone = [k for k in np.unique(surface) if 0 < c[surface == k].sum() < MIN_PER_SURFACE]
    if not lone:
        return c
    moved = int(c[np.isin(surface, lone)].sum())
    c[np.isin(surface, lone)] = 0
    order = np.argsort(-c, kind="stable")
    for i in range(moved):
        c[order[i % max(int(np.sum(c > 0)), 1)]] += 1
    return c


def _regular(M: np.ndarray) -> bool:
    """The information ``M`` (k, k) determines every parameter whose column it has (a surface left
    out has none): the normalised matrix of those is positive definite (smallest eigenvalue > 1e-12)."""
    d = np.diag(M)
    on = d > 0
    s = 1.0 / np.sqrt(d[on])
    return bool(np.linalg.eigvalsh(M[np.ix_(on, on)] * s[:, None] * s[None, :])[0] > 1e-12)


@dataclasses.dataclass
class _Generation:
    """The column generation's state: the candidates (poses, surfaces, rows), the fresh poses of the
    verification (None: none) and the local searches run."""

    problem: ContactProblem
    collision: bool
    starts: int
    tol: float
    rng: np.random.Generator
    q: np.ndarray
    surface: np.ndarray
    F: np.ndarray
    fresh: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    n_searched: int = 0

    @classmethod
    def begin(cls, problem: ContactProblem, *, seed: int, pool: int, verify: int, **settings) -> _Generation:
        """``pool`` feasible candidates (``seed``) and ``verify`` fresh poses (``seed + 1``)."""
        S, collision = problem.surfaces, settings["collision"]
        q, surface = contact_poses(problem, S, n=pool, seed=seed, collision=collision)
        fresh = None
        if verify:
            q_v, k_v = contact_poses(problem, S, n=verify, seed=seed + 1, collision=collision)
            fresh = (q_v, k_v, pose_rows(problem, q_v))
        return cls(
            problem,
            rng=np.random.default_rng(seed),
            q=q,
            surface=surface,
            F=pose_rows(problem, q),
            fresh=fresh,
            **settings,
        )

    def _maximize(self, q: np.ndarray, surface: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.n_searched += len(q)
        return maximize_on_surfaces(self.problem, q, surface, Y, collision=self.collision)

    def search(self, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The poses (s, nj), surfaces (s,) and ``g`` (s,) a round found: local searches from the
        candidates; when they find no ``g > 1 + tol``, also the fresh poses and the local maxima from
        the best of them."""
        first = _starts(dual_values(self.F, Y), self.starts, self.rng)
        q_new, g_new = self._maximize(self.q[first], self.surface[first], Y)
        k_new = self.surface[first]
        if float(g_new.max()) <= 1.0 + self.tol and self.fresh is not None:
            q_v, k_v, F_v = self.fresh
            g_v = dual_values(F_v, Y)
            fv = _starts(g_v, self.starts, self.rng)
            q_l, g_l = self._maximize(q_v[fv], k_v[fv], Y)
            q_new, k_new = np.concatenate([q_new, q_v, q_l]), np.concatenate([k_new, k_v, k_v[fv]])
            g_new = np.concatenate([g_new, g_v, g_l])
        return q_new, k_new, g_new

    def join(self, q_new: np.ndarray, k_new: np.ndarray, g_new: np.ndarray) -> None:
        """The new poses of ``g > 1`` whose rows are not candidates yet become candidates."""
        F_new = pose_rows(self.problem, q_new)
        keep = (g_new > 1.0) & distinct_rows(self.F, F_new)
        self.q = np.concatenate([self.q, q_new[keep]])
        self.surface = np.concatenate([self.surface, k_new[keep]])
        self.F = np.concatenate([self.F, F_new[keep]])

    def design(self, sol: PoolSolution, K: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The weights ``sol.w`` rounded to ``n`` poses and polished: (poses (n, nj), their surfaces
        (n,), their ``g`` under ``sol.Y`` (n,))."""
        problem = self.problem
        q_design = replicate_poses(problem, self.q, _rounded(self.F, K, sol.w, n, sol.phi, self.surface))
        k_design = problem.surface_of(q_design)
        q_design = polish_on_surfaces(problem, q_design, k_design, collision=self.collision)
        return (
            q_design,
            k_design,
            dual_values(pose_rows(problem, q_design), sol.Y),
        )  # polished: may leave the set


def _bound(
    gen: _Generation, sol: PoolSolution, best: tuple, g_max: float, q_design: np.ndarray, n: int
) -> float:
    """The certificate's bound [mm^2]: the last round's (``g`` over what it searched and the design's
    poses) or the best round's ``best = (dual, Y, g_max)`` with the later candidates and the design
    evaluated under its ``Y``, whichever is larger."""
    F_design = pose_rows(gen.problem, q_design)
    bound = sol.dual / (max(g_max, float(dual_values(F_design, sol.Y).max())) * n)
    dual, Y, g_best = best
    g_best = max(g_best, float(dual_values(gen.F, Y).max()), float(dual_values(F_design, Y).max()))
    return max(bound, dual / (g_best * n))


def _check_size(problem: ContactProblem, n: int) -> None:
    """InputError unless ``n`` rows (one per pose) can determine the robot's parameters and one surface's."""
    fewest = problem.n_params - 3 * (len(problem.surfaces) - 1)
    if n < fewest:
        raise InputError(
            f"n: {n} poses cannot determine the {fewest} parameters of the robot and a "
            f"{problem.surfaces.kind} (one row per pose)",
            fields=("n",),
        )


def contact_design(
    problem: ContactProblem,
    n: int,
    *,
    seed: int = 0,
    collision: bool = True,
    pool: int = 1000,
    starts: int = 24,
    rounds: int = ROUNDS,
    tol: float = 1e-3,
    verify: int = VERIFY_POOL,
) -> ContactDesign:
    """The ``n``-pose KPI design on ``problem``'s surfaces and its certificate (module docstring).

    Args:
        seed: seed of the candidate pool (the verification pool: ``seed + 1``) and random starts.
        collision: the poses avoid collisions (robot, obstacles, a ballbar's bar and stand; not planes).
        pool: feasible poses to start from; starts: local searches per round.
        tol: stop when no search finds ``g > 1 + tol``.
        verify: fresh poses on which ``g`` is evaluated at the end (0: none).

    Raises:
        InputError: fewer poses than parameters, too few feasible poses, a cone program that fails
            or candidates that do not determine the parameters.
    """
    _check_size(problem, n)
    K = kpi_factor(problem)
    gen = _Generation.begin(
        problem, seed=seed, pool=pool, verify=verify, collision=collision, starts=starts, tol=tol
    )
    done, limit, refined, best = 0, rounds, 0, None
    while True:
        done += 1
        sol = solve_pool(gen.F, K)
        q_new, k_new, g_new = gen.search(sol.Y)
        g_max = max(1.0, float(g_new.max()))
        if best is None or sol.dual / g_max > best[0] / best[2]:
            best = (sol.dual, sol.Y, g_max)  # the round of the best bound over what it searched
        if g_max <= 1.0 + tol or done >= limit:
            q_design, k_design, g_d = gen.design(sol, K, n)
            if float(g_d.max()) <= g_max * (1.0 + tol) or refined >= REFINEMENTS:
                break
            refined, limit = refined + 1, done + REFINE_ROUNDS  # its poses join the candidates
            q_new, k_new = np.concatenate([q_new, q_design]), np.concatenate([k_new, k_design])
            g_new = np.concatenate([g_new, g_d])
        gen.join(q_new, k_new, g_new)
    value = float(problem.criteria(q_design)["kpi_avg_var_mm2"])
    bound = _bound(gen, sol, best, g_max, q_design, n)
    return ContactDesign(
        q=q_design,
        surface=problem.surface_of(q_design),
        value=value,
        bound=bound,
        efficiency=bound / value,
        phi=sol.phi,
        g_max=g_max,
        design_beyond_search=float(g_d.max()) / g_max,
        rounds=done,
        converged=g_max <= 1.0 + tol,
        n_candidates=len(gen.q),
        n_searched=gen.n_searched,
    )


def _of_kind(problem: ContactProblem, kind: str, what: str) -> None:
    if problem.surfaces.kind != kind:
        raise InputError(f"{what}: the problem's surfaces are {problem.surfaces.kind}s, not {kind}s")


def plane_design(problem: ContactProblem, n: int, **settings: Any) -> ContactDesign:
    """The ``n``-touch KPI design of a plane problem
    (:func:`~kpioed_drake.design.contact.problem.make_plane_problem`): :func:`contact_design`."""
    _of_kind(problem, "plane", "plane_design")
    return contact_design(problem, n, **settings)


def ballbar_design(problem: ContactProblem, n: int, **settings: Any) -> ContactDesign:
    """The ``n``-pose KPI design of a ballbar problem
    (:func:`~kpioed_drake.design.contact.problem.make_ballbar_problem`): :func:`contact_design`."""
    _of_kind(problem, "pivot", "ballbar_design")
    return contact_design(problem, n, **settings)
