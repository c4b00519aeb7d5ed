"""Optimality certificate of a KPI design: a lower bound on tr(Cs)/3 of any n-pose design.

The bound (paper eq. 24a, KPI criterion tr(Cs)/3 = tr(K^T M^-1 K), ``K = Js^T / sqrt(3)``; notation
of :mod:`kpioed_drake.design.approximate.design`). For any matrix ``Y`` (k, 3) and any set ``X`` of poses,

    tr(Cs)/3 of any n poses in X  >=  tr(K^T Y)^2 / (n max_{x in X} ||F_x Y||_F^2).

The proof below uses only the shapes of ``K`` and ``F_x``: it holds for any KPI factor (with an
orientation KPI, ``Js`` stacked with ``L Js_rot``) and any rows per pose (3, 3T targets, 6 of a pose).

Proof: for poses ``x_1..x_n`` with information ``M = sum_i F_i^T F_i`` put ``Z_i = F_i M^-1 K``;
then ``sum_i F_i^T Z_i = K`` and ``sum_i ||Z_i||_F^2 = tr(K^T M^-1 K)``, so by Cauchy-Schwarz
``tr(K^T Y) = sum_i tr(Z_i^T F_i Y) <= sqrt(g_max) sum_i ||Z_i|| <= sqrt(g_max n tr(K^T M^-1 K))``.
With ``Y = M(w)^-1 K`` of an approximate design ``w`` this is the equivalence-theorem bound
``Phi* >= Phi(w)^2 / max_x d(x, w)`` divided by n; the best ``Y`` (the dual of the cone program
over ``X``) makes it equal to the approximate optimum over ``X`` (strong duality).

What is rigorous and what is not:

- Over a finite set ``X`` the maximum is computed exactly, so the bound holds for every design with
  its poses in ``X`` (:func:`pool_certificate`: the dual certificate ``Y``, checked in numpy, and
  the equivalence theorem at the pool optimum; both agree with the primal value to about 1e-9).
- :func:`certify` takes ``X`` = the column generation's candidates, fresh random poses, variants
  with joints at their limits, the local maxima reached from them
  (:mod:`~kpioed_drake.design.approximate.search`), and the design's own poses with their local maxima (those
  beyond the search's maximum join the candidates and the column generation continues,
  :data:`DESIGN_REFINEMENTS`). So ``bound_mm2 <= tr(Cs)/3`` of the design certified is rigorous
  (efficiency <= 1). That it bounds every feasible n-pose design holds only if no feasible pose
  has a larger ``||F_x Y||`` than the largest found: the maximum over the continuous feasible set
  is a search (SNOPT from many starts), not a proof. It can miss poses: an optimised design's
  poses may lie above it (``design_beyond_search`` > 1).

Units: millimetres and radians; variances in mm^2.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np

from kpioed_drake import progress
from kpioed_drake.design.approximate import certcache, pool, search
from kpioed_drake.design.approximate import design as column_generation
from kpioed_drake.design.approximate.design import (
    ROUND_TOL,
    ApproximateDesign,
    approximate_design,
    distinct_rows,
    kpi_factor,
)
from kpioed_drake.design.approximate.given import bound_of, given_design
from kpioed_drake.design.approximate.pool import l_criterion, solve_pool
from kpioed_drake.design.approximate.search import (
    announce_cold_search,
    corner_poses,
    dual_values,
    feasible,
    maximize_dual,
    perturbed_poses,
    pose_rows,
)
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.settings import is_large
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem

CERTIFY_ROUNDS = 12
"""Most column-generation rounds of the design behind a certificate, per stage."""
VERIFY_ROUNDS = 3
"""Most broader searches (:func:`verify_search`), each followed by more column generation if it
found poses of larger ``g``."""
VERIFY_POOL = 5000
"""Random feasible poses (a fresh seed) on which ``g`` is evaluated after the column generation."""
CORNER_VARIANTS = 10
"""Variants (joints at limits; random moves of :data:`PERTURB_RAD`) tried per leading candidate in
:func:`verify_search`: the maxima of ``g`` sit on constraint boundaries (a joint at its limit,
several clearances active) that random poses rarely reach (docs/certificate.md, design notes)."""
DESIGN_STARTS = 8
"""Local maximisations of ``g`` from a certified design's poses (:func:`certify`)."""
DESIGN_REFINEMENTS = 2
"""Most times :func:`certify` continues the column generation with the feasible poses it found near
the design with ``g`` above the search's maximum, each followed by :func:`verify_search`. Without
it, a design that reaches poses beyond the search gets a valid but loose bound, lowered by that
factor (docs/certificate.md)."""
REFINE_ABOVE = 0.01
""":func:`certify` refines only when the design reaches poses more than this fraction beyond the
search (``design_beyond_search > 1 + REFINE_ABOVE``): below it the bound given up is under 1 %, and
a refinement (a continued column generation and a broader search) costs more than the design on a
many-joint robot (docs/certificate.md)."""
REFINE_BELOW_EFFICIENCY = 0.97
"""On a large design (more than :data:`~kpioed_drake.design.settings.LARGE_SOLVE_VARIABLES` joint
variables) :func:`certify` refines only while the design's certified efficiency is below this: on
the 18-joint twin one refinement costs more than two minutes, several times the design, for about
1 % of bound. A six-joint design's refinement costs seconds and refines whenever the search missed
poses (docs/certificate.md)."""
PERTURB_RAD = 0.25
"""Standard deviation of those random moves per joint [rad]."""
VERIFY_STARTS = 48
"""Local maximisations of ``g`` after the column generation: from the verification pool's and the
candidates' poses of largest ``g``, half each."""


@dataclasses.dataclass
class PoolCertificate:
    """The optimum approximate design over a finite pool and its dual certificate.

    Attributes:
        w: (m,) optimum weights (sum 1).
        Y: (k, 3) dual matrix with ``max_i ||F_i Y||_F = 1`` over the pool.
        phi: ``Phi(w) = tr(K^T M(w)^-1 K)`` [mm^2], an upper bound on the pool optimum.
        dual: ``tr(K^T Y)^2`` [mm^2], a lower bound on it (rigorous: checked in numpy).
        equivalence: ``Phi(w)^2 / max_i d(x_i, w)`` [mm^2], the equivalence theorem's lower bound.
        dual_gap: ``1 - dual / phi``.
        equivalence_gap: ``max_i d(x_i, w) / Phi(w) - 1`` (0 at the optimum).
    """

    w: np.ndarray
    Y: np.ndarray
    phi: float
    dual: float
    equivalence: float
    dual_gap: float
    equivalence_gap: float


def pool_certificate(problem: Problem, q_pool: np.ndarray) -> PoolCertificate:
    """Optimum approximate design over the poses ``q_pool`` (m, 6) [rad] and its certificate.

    Rigorous over the pool: for every design of n poses from the pool, tr(Cs)/3 >= dual / n.
    """
    F, K = pose_rows(problem, q_pool), kpi_factor(problem)
    sol = solve_pool(F, K)
    g = dual_values(F, sol.Y)
    dual = float(np.sum(K * sol.Y)) ** 2 / float(g.max())
    phi, X = l_criterion(F, sol.w, K)
    d_max = float(dual_values(F, X).max())
    return PoolCertificate(
        w=sol.w,
        Y=sol.Y,
        phi=phi,
        dual=dual,
        equivalence=phi * phi / d_max,
        dual_gap=1.0 - dual / phi,
        equivalence_gap=d_max / phi - 1.0,
    )


def verify_search(
    problem: Problem, approx: ApproximateDesign, *, seed: int = 0
) -> tuple[ApproximateDesign, np.ndarray]:
    """A broader search for poses of large ``g`` with ``approx``'s ``Y``.

    Evaluates ``g`` on :data:`VERIFY_POOL` fresh random feasible poses (seed ``seed``), on random
    moves (:func:`perturbed_poses`) of :data:`CORNER_VARIANTS` copies of each of the
    :data:`VERIFY_STARTS` candidates of largest ``g``, and on variants of all those with joints at
    their limits (:func:`corner_poses`; only feasible poses are kept); then maximises ``g`` locally
    from the :data:`VERIFY_STARTS` poses of largest ``g``, half from those, half from the candidates.

    Returns:
        ``approx`` with ``g_max`` raised to the largest ``g`` found (counts updated; not
        ``converged`` if something was found), and the feasible poses found with
        ``g > 1 + ROUND_TOL`` (s, 6) [rad].
    """
    coll = approx.collision
    fresh = heuristic_design(
        problem, n=VERIFY_POOL, seed=seed, collision=coll, margin_mm=0.0, max_draws=10**7
    )
    g_cand = dual_values(approx.F, approx.Y)
    near = np.repeat(approx.q[np.argsort(-g_cand)[:VERIFY_STARTS]], CORNER_VARIANTS, axis=0)
    moved = perturbed_poses(problem, near, scale_rad=PERTURB_RAD, seed=seed, collision=coll)
    corners = corner_poses(problem, np.concatenate([fresh, near]), seed=seed, collision=coll)
    fresh = np.concatenate([fresh, moved, corners])
    g_fresh = dual_values(pose_rows(problem, fresh), approx.Y)
    half = VERIFY_STARTS // 2
    starts = np.concatenate([fresh[np.argsort(-g_fresh)[:half]], approx.q[np.argsort(-g_cand)[:half]]])
    q_found, g_found, ok = maximize_dual(problem, starts, approx.Y, collision=coll)
    g_max = max(approx.g_max, float(g_fresh.max()), float(g_found[ok].max(initial=0.0)))
    out = dataclasses.replace(
        approx,
        g_max=g_max,
        n_searched=approx.n_searched + len(starts),
        n_checked=approx.n_checked + len(fresh),
    )
    found = q_found[ok & (g_found > 1.0 + ROUND_TOL)]
    return dataclasses.replace(out, converged=approx.converged and len(found) == 0), found


def _with_candidates(problem: Problem, approx: ApproximateDesign, q_new: np.ndarray) -> ApproximateDesign:
    """``approx`` with those of the poses ``q_new`` (s, 6) whose rows differ from every candidate's
    (:func:`distinct_rows`; copies make the cone program degenerate) added as candidates of weight 0."""
    F_new = pose_rows(problem, q_new)
    keep = distinct_rows(approx.F, F_new)
    return dataclasses.replace(
        approx,
        q=np.concatenate([approx.q, q_new[keep]]),
        F=np.concatenate([approx.F, F_new[keep]]),
        w=np.concatenate([approx.w, np.zeros(int(keep.sum()))]),
    )


_LOCAL = threading.local()


def certified_design(
    problem: Problem, *, collision: bool = True, seed: int = 0, warm: ApproximateDesign | None = None
) -> ApproximateDesign:
    """The approximate design behind :func:`certify`, cached per problem object, ``collision`` and
    ``seed`` (per thread) and, without ``warm``, on disk (:mod:`~kpioed_drake.design.approximate.certcache`:
    keyed by the problem's content, ``collision``, ``seed`` and :func:`search_settings`). Without
    ``warm`` the search is that of the problem with unit noise, scaled by :func:`with_noise` (one
    search for every noise level).

    Column generation (:data:`CERTIFY_ROUNDS` rounds at most, continuing ``warm`` if given), then up
    to :data:`VERIFY_ROUNDS` times :func:`verify_search` (seeds ``seed + 1``, ``seed + 2``, ...);
    poses it finds with ``g > 1 + tol`` join the candidates and the column generation goes on.
    """
    cache = _LOCAL.__dict__.setdefault("designs", {})
    key = (id(problem), bool(collision), int(seed))
    hit = cache.get(key)
    if hit is not None and hit[0] is problem:
        return hit[1]
    if warm is not None:
        approx = _search(problem, collision=collision, seed=seed, warm=warm)
    else:  # the search of the problem with unit noise, scaled (it does not depend on the noise)
        unit = certcache.unit_noise(problem)
        disk_key = certcache.problem_key(unit, collision=collision, seed=seed, settings=search_settings())
        approx = certcache.load(disk_key)
        if approx is None:
            announce_cold_search(unit)
            approx = _search(unit, collision=collision, seed=seed, warm=None)
            certcache.store(disk_key, approx)
            approx = _c_order(approx)  # as a stored design loads: the same bits for every later use
        approx = with_noise(approx, problem.sigma)
    if len(cache) > 8:
        cache.clear()
    cache[key] = (problem, approx)
    return approx


def _c_order(approx: ApproximateDesign) -> ApproximateDesign:
    """``approx`` with its arrays in C order, as :func:`certcache.load` returns them: the sums of
    later steps (a refinement's cone program) depend on memory layout in their last bits, and a
    design must not change when it comes from the disk cache instead of a fresh search."""
    arrays = {
        f.name: np.ascontiguousarray(getattr(approx, f.name))
        for f in dataclasses.fields(approx)
        if isinstance(getattr(approx, f.name), np.ndarray)
    }
    return dataclasses.replace(approx, **arrays)


def with_noise(approx: ApproximateDesign, sigma: float) -> ApproximateDesign:
    """``approx`` of a problem with unit noise for noise ``sigma`` [mm]: rows ``F / sigma``, ``Y``
    times ``sigma`` (so ``g = ||F Y||^2`` and the weights are unchanged), ``phi`` and ``dual`` times
    ``sigma^2``: the same search, as every step depends on ``F`` only through ``g`` and ``Phi``."""
    if sigma == 1.0:
        return approx
    s = float(sigma)
    return dataclasses.replace(
        approx, F=approx.F / s, Y=approx.Y * s, phi=approx.phi * s * s, dual=approx.dual * s * s
    )


def search_settings() -> dict:
    """The settings of the search behind :func:`certified_design` (part of its disk-cache key): this
    module's, the column generation's and the local maximisation's."""
    own = ("CERTIFY_ROUNDS", "VERIFY_ROUNDS", "VERIFY_POOL", "CORNER_VARIANTS", "PERTURB_RAD")
    generation = ("POOL_POSES", "FIRST_WORKING", "WORKING_POSES")
    return {
        **{name: globals()[name] for name in (*own, "VERIFY_STARTS")},
        **{name: getattr(column_generation, name) for name in (*generation, "ROUND_TOL")},
        **pool.settings(),
        **search.settings(),
    }


def _search(
    problem: Problem, *, collision: bool, seed: int, warm: ApproximateDesign | None
) -> ApproximateDesign:
    """The column generation and broader searches of :func:`certified_design` (not cached)."""
    with progress.stage("certificate search", total=VERIFY_ROUNDS * (CERTIFY_ROUNDS + 1), unit="round"):
        approx = approximate_design(
            problem, collision=collision, seed=seed, max_rounds=CERTIFY_ROUNDS, warm=warm
        )
        for k in range(1, VERIFY_ROUNDS + 1):
            approx, found = verify_search(problem, approx, seed=seed + k)
            progress.step(g_max=approx.g_max)
            if len(found) == 0 or k == VERIFY_ROUNDS:
                break
            warm = _with_candidates(problem, approx, found)
            rounds = approx.rounds + CERTIFY_ROUNDS
            approx = approximate_design(
                problem, collision=collision, seed=seed + k, max_rounds=rounds, warm=warm
            )
    return approx


def _near_design(problem: Problem, q: np.ndarray, approx: ApproximateDesign, *, collision: bool):
    """``max g`` at the design's poses ``q`` (n, 6) [rad] and at the local maxima from the
    :data:`DESIGN_STARTS` of them with largest ``g``; those poses and maxima that are feasible and
    have ``g`` above ``approx.g_max (1 + ROUND_TOL)`` (s, 6) [rad]; the number of starts."""
    g_design = dual_values(pose_rows(problem, q), approx.Y)
    starts = q[np.argsort(-g_design)[:DESIGN_STARTS]]
    q_found, g_found, ok = maximize_dual(problem, starts, approx.Y, collision=collision)
    g_near = max(float(g_design.max()), float(g_found[ok].max(initial=0.0)))
    q_all, g_all = np.concatenate([q, q_found]), np.concatenate([g_design, g_found])
    ok_all = np.concatenate([feasible(problem, q, collision=collision), ok])
    return g_near, q_all[ok_all & (g_all > approx.g_max * (1.0 + ROUND_TOL))], len(starts)


def given_bound(
    problem: Problem, q: np.ndarray, approx: ApproximateDesign, *, given: np.ndarray, collision: bool
) -> float:
    """The bound on tr(Cs)/3 of the measured poses ``given`` and any ``len(q)`` more with the
    ``Y`` of the approximate design made with the measured information
    (:func:`~kpioed_drake.design.approximate.given.given_design`, one round), ``g`` also at the
    design's poses ``q`` and the local maxima from the :data:`DESIGN_STARTS` of them with largest
    ``g`` [mm^2]."""
    gd = given_design(problem, approx, given=given, n=len(q), collision=collision, rounds=1)
    g_design = dual_values(pose_rows(problem, q), gd.Y)
    starts = q[np.argsort(-g_design)[:DESIGN_STARTS]]
    _, g_found, ok = maximize_dual(problem, starts, gd.Y, collision=collision)
    g_max = max(gd.g_max, float(g_design.max()), float(g_found[ok].max(initial=0.0)))
    return float(bound_of(kpi_factor(problem), gd.Y, gd.fixed, g_max, len(q)))


def certify(
    problem: Problem,
    q: np.ndarray,
    *,
    collision: bool = True,
    seed: int = 0,
    approx: ApproximateDesign | None = None,
    refinements: int = DESIGN_REFINEMENTS,
    given: np.ndarray | None = None,
) -> dict:
    """Lower bound on tr(Cs)/3 of any feasible design of ``len(q)`` poses, and ``q``'s efficiency.

    With ``given`` poses (information ``M0 = F0^T F0`` held fixed) the bound is on the combined
    design: for any ``Y``, tr(K^T (M0 + M)^-1 K) >= tr(K^T Y)^2 / (n g_max + tr(Y^T M0 Y)) (the
    proof of the module docstring with the given rows as one more term of the Cauchy-Schwarz sum);
    with ``Y`` of the design without given poses this bound is valid but loose, so the bound of
    :func:`given_bound` (``Y`` of the approximate design with the measured information) is
    computed too and the larger kept.

    ``g`` is also evaluated at the design's poses and maximised locally from the
    :data:`DESIGN_STARTS` of them with largest ``g`` (the optimiser may have found feasible poses
    beyond the search), so the bound is rigorous for ``q`` and efficiency <= 1. Feasible poses
    found there with ``g`` above the search's maximum join the candidates, the column generation
    and :func:`verify_search` continue (while the design reaches more than :data:`REFINE_ABOVE`
    beyond the search and, on a large design, its efficiency is below
    :data:`REFINE_BELOW_EFFICIENCY`; at most ``refinements`` times; the cached design of
    :func:`certified_design` is not changed) and the design's poses are searched again.

    Args:
        problem: robot, cell, model, ``q_work`` and noise.
        q: (n, 6) the design [rad].
        collision: whether the design had to avoid collisions (the feasible set searched).
        seed: seed of the search (:func:`certified_design`).
        approx: the approximate design to bound with (default: :func:`certified_design`), made
            with the same ``collision`` (else ValueError).
        refinements: most continuations of the column generation with poses found near ``q``.
        given: (m, 6) [rad] poses already measured (``q`` the new ones), or None.

    Returns:
        JSON-ready dict:
        ``bound_mm2``: the lower bound on tr(Cs)/3 of n poses (rigorous for designs with poses
        among those evaluated, ``q``'s included; over all feasible poses as good as the search);
        ``efficiency``: ``bound_mm2 / value_mm2`` (<= 1); ``value_mm2``: tr(Cs)/3 of ``q``
        (several working poses: their KPI; the bound is on the weighted mean, hence also on the
        worst); ``n_poses``: n;
        ``search_bound_mm2``: the bound from the search alone (the same for every design
        unless refined);
        ``design_beyond_search``: ``max g`` near the design's poses over the search's (> 1: the
        design reached poses the search missed, and the bound is lowered to cover them);
        ``approximate_mm2``: ``Phi(w) / n`` of the approximate design (an upper bound on the
        approximate optimum); ``dual_gap``: ``1 - bound_mm2 / approximate_mm2`` (0: the search
        proved its approximate design optimal); ``n_candidates``: poses at which ``g`` was
        evaluated; ``n_local_searches``: local maximisations of ``g``; ``rounds``, ``converged``:
        of the column generation; ``refinements``: continuations run; ``method``: how the bound
        was found.
    """
    q = np.asarray(q, dtype=float).reshape(-1, problem.robot.n_joints)
    approx = certified_design(problem, collision=collision, seed=seed) if approx is None else approx
    if approx.collision != collision:
        raise ValueError(f"the approximate design has collision={approx.collision}, not {collision}")
    n = q.shape[0]
    value = problem.criteria(q if given is None else np.concatenate([given, q]))["kpi_avg_var_mm2"]

    G0 = None if given is None else pose_rows(problem, given)
    approx, g_near, n_starts, refined = _refined(
        problem, q, approx, G0, value=value, collision=collision, seed=seed, refinements=refinements
    )
    bound = _dual_bound(approx, g_near, n, G0)
    if given is not None:  # both bounds are valid: keep the larger
        bound = max(bound, given_bound(problem, q, approx, given=given, collision=collision))
    return _certificate_record(approx, bound, value, n, g_near, n_starts, refined, given)


def _dual_bound(approx: ApproximateDesign, g_near: float, n: int, G0: np.ndarray | None) -> float:
    """The bound of :func:`certify` from ``approx``'s dual ``Y``: its maximum of ``g`` raised to
    ``g_near``, with the given poses' rows ``G0`` (or None) as one more term."""
    fixed = 0.0 if G0 is None else float(np.sum((G0 @ approx.Y) ** 2))
    return approx.dual / (max(approx.g_max, g_near) * n + fixed)


def _refined(
    problem: Problem,
    q: np.ndarray,
    approx: ApproximateDesign,
    G0: np.ndarray | None,
    *,
    value: float,
    collision: bool,
    seed: int,
    refinements: int,
) -> tuple[ApproximateDesign, float, int, int]:
    """:func:`certify`'s search near the design ``q`` and its continuations of the column generation
    (while poses found there lie beyond the search): the approximate design, ``g_near``, the local
    searches near the design and the continuations run."""
    n = q.shape[0]
    g_near, found, n_starts = _near_design(problem, q, approx, collision=collision)
    small = not is_large(n, problem.robot.n_joints)
    refined = 0
    while (
        len(found)
        and refined < refinements
        and g_near > approx.g_max * (1.0 + REFINE_ABOVE)
        and (small or _dual_bound(approx, g_near, n, G0) < REFINE_BELOW_EFFICIENCY * value)
    ):
        warm = _with_candidates(problem, approx, found)
        try:
            more_rounds = approximate_design(
                problem, collision=collision, seed=seed, max_rounds=approx.rounds + CERTIFY_ROUNDS, warm=warm
            )
        except InputError:  # the cone program failed: keep the bound found so far (still rigorous)
            break
        approx, _ = verify_search(problem, more_rounds, seed=seed + VERIFY_ROUNDS + 1 + refined)
        refined += 1
        g_near, found, more = _near_design(problem, q, approx, collision=collision)
        n_starts += more
    return approx, g_near, n_starts, refined


def _certificate_record(
    approx: ApproximateDesign,
    bound: float,
    value: float,
    n: int,
    g_near: float,
    n_starts: int,
    refined: int,
    given: np.ndarray | None,
) -> dict:
    """The dict :func:`certify` returns."""
    return {
        "bound_mm2": bound,
        "efficiency": bound / value,
        "value_mm2": value,
        "n_poses": int(n),
        "search_bound_mm2": approx.bound / n,
        "design_beyond_search": g_near / approx.g_max,
        "approximate_mm2": approx.phi / n,
        "dual_gap": 1.0 - bound * n / approx.phi,
        "n_given": 0 if given is None else int(len(given)),
        "n_candidates": int(len(approx.q) + approx.n_checked + n + n_starts),
        "n_local_searches": int(approx.n_searched + n_starts),
        "rounds": int(approx.rounds),
        "converged": bool(approx.converged),
        "refinements": refined,
        "method": (
            "dual bound tr(K^T Y)^2 / (n max_x ||F_x Y||^2) with Y from the cone program over the "
            "column generation's candidates; max over the candidates, random and limit-corner poses, "
            "the design's poses and local maxima from all of them (a search of the feasible set); "
            "poses found near the design beyond the search join the candidates"
        ),
    }


def certificate_fields(cert: dict | None) -> dict:
    """The fields a certificate adds to a JSON record: ``bound_mm2``, ``efficiency``,
    ``design_beyond_search`` and ``certificate`` (the whole dict of :func:`certify`); all None
    without a certificate (``--no-certify``)."""
    keys = ("bound_mm2", "efficiency", "design_beyond_search")
    return {**{k: None if cert is None else cert[k] for k in keys}, "certificate": cert}


def certificate_line(cert: dict) -> str:
    """One line for a printed summary: the bound, the efficiency and what the search missed."""
    line = (
        f"lower bound for any {cert['n_poses']}-pose design: {cert['bound_mm2']:.4g} mm^2; "
        f"efficiency {cert['efficiency']:.3f}"
    )
    if cert["design_beyond_search"] > 1.0 + ROUND_TOL:  # (smaller excesses lower the bound too)
        line += f" (the design reached poses {cert['design_beyond_search'] - 1.0:.1%} beyond the search)"
    return line
