"""The approximate KPI design of n poses added to measured ones, and the dual bound it gives.

With measured poses of information ``M0`` held fixed (paper section 3.1, sequential
re-identification) the KPI criterion of n new poses ``x_i`` is
``tr(K^T (M0 + sum_i F_i^T F_i)^-1 K)`` = tr(Cs)/3 of the combined design (notation of
:mod:`.design`). As ``tr(K^T M^-1 K) = max_Y 2 tr(K^T Y) - tr(Y^T M Y)`` for a regular ``M``,
for any ``Y`` (k, 3) and any n feasible poses

    tr(Cs)/3  >=  2 tr(K^T Y) - ||R0 Y||_F^2 - n max_x ||F_x Y||_F^2      (R0^T R0 = M0),

and with ``Y`` scaled by its best factor ``>= tr(K^T Y)^2 / (||R0 Y||_F^2 + n g_max)`` (the bound
:func:`~.certificate.certify` uses). Over a finite candidate set the best ``Y`` is a cone program
(:func:`solve_given_pool`: ``max 2 tr(K^T Y) - s - n t`` with ``s >= ||R0 Y||^2`` and
``t >= ||F_i Y||^2``, rotated Lorentz cones, Clarabel); by minimax its value is the optimum of the
approximate design of n new poses over the candidates (weights summing to n) with ``M0`` held
fixed. The ``Y`` of the design without measured poses (:func:`~.certificate.certified_design`)
ignores what the measured poses already cover: its bound is valid but loose, and the candidates of
that design lack the poses that complement them.

:func:`given_design` runs the column generation of :mod:`.design` with this cone program, warm
from the certified design's candidates: cone program over a working set, ``g`` on every candidate,
local maxima of ``g`` over the feasible poses (:func:`~.search.maximize_dual`), new maxima join.
Its candidates make a second start of the optimiser with measured poses
(:func:`~.sequential.given_counts` on them) and its ``Y`` the tight bound of a design with given
poses; :func:`fewest_certified` is the fewest new poses for which the bound does not exclude a
target (fewer provably cannot reach it, as far as the search found the largest ``g``).

Units: millimetres and radians; criteria in mm^2.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions

from kpioed_drake.design.approximate.design import (
    ROUND_TOL,
    ApproximateDesign,
    distinct_rows,
    kpi_factor,
)
from kpioed_drake.design.approximate.pool import quiet_solver_notes
from kpioed_drake.design.approximate.search import dual_values, maximize_dual, pose_rows
from kpioed_drake.estimation.problem import Problem

GIVEN_ROUNDS = 3
"""Most column-generation rounds of :func:`given_design`."""
GIVEN_STARTS = 12
"""Local maximisations of ``g`` per round (from the candidates of largest ``g``)."""
GIVEN_WORKING = 300
"""Candidates of largest ``g`` under the certified design's ``Y`` in the first cone program (its
support among them); later ones: the largest ``g`` under the last ``Y``. All 2000-3000 candidates
in one program take 4-9 s (kr16), these a small part of it."""
GIVEN_CONE_TOLS = (1e-8, 1e-6)
"""Clarabel's tolerances, tried in turn (it stops short of 1e-9 on most kr16 sets with these
cones). The bound stays rigorous at any of them: it is evaluated in numpy from ``Y``."""


def information_factor(M0: np.ndarray) -> np.ndarray:
    """``R0`` (r, k) with ``R0^T R0 = M0`` (k, k) symmetric positive semidefinite (its eigenvectors
    scaled; directions of zero information dropped)."""
    lam, V = np.linalg.eigh(0.5 * (M0 + M0.T))
    keep = lam > max(float(lam.max(initial=0.0)), 1e-300) * 1e-14
    return np.sqrt(lam[keep])[:, None] * V[:, keep].T


def _vec_rows(F: np.ndarray, nc: int) -> np.ndarray:
    """Rows ``A`` (r nc, k nc) with ``A y = vec(F Y)`` for ``y = vec(Y)`` row-major, ``F`` (r, k)."""
    r, k = F.shape
    A = np.zeros((r * nc, k * nc))
    for c in range(nc):
        A[c::nc, c::nc] = F
    return A


def _square_bound(prog: MathematicalProgram, rows: np.ndarray, y, t) -> None:
    """``t >= ||rows y||^2`` as the rotated Lorentz cone ``(t, 1, rows y)``."""
    m = rows.shape[0]
    A = np.zeros((2 + m, rows.shape[1] + 1))
    A[0, -1] = 1.0
    A[2:, :-1] = rows
    b = np.zeros(2 + m)
    b[1] = 1.0
    prog.AddRotatedLorentzConeConstraint(A, b, np.concatenate([y, [t]]))


def solve_given_pool(F: np.ndarray, K: np.ndarray, R0: np.ndarray, n: int) -> np.ndarray | None:
    """The best ``Y`` (k, nc) over the candidates with rows ``F`` (m, r, k) for ``n`` new poses and
    measured information ``R0^T R0`` (module docstring). If Clarabel stops short at every
    tolerance, its last finite iterate (any ``Y`` gives a valid bound; the caller keeps the
    better one); None if there is none."""
    m, r, k = F.shape
    nc = K.shape[1]
    prog = MathematicalProgram()
    y = prog.NewContinuousVariables(k * nc, "y")
    t, s = prog.NewContinuousVariables(2, "ts")
    for i in range(m):
        _square_bound(prog, _vec_rows(F[i], nc), y, t)
    if R0.size:
        _square_bound(prog, _vec_rows(R0, nc), y, s)
    prog.AddLinearCost(-2.0 * K.reshape(-1), 0.0, y)
    prog.AddLinearCost(float(n) * t + s)
    solver = ClarabelSolver()
    for tol in GIVEN_CONE_TOLS:
        opts = SolverOptions()
        for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio"):
            opts.SetOption(solver.solver_id(), name, tol)
        with quiet_solver_notes():
            result = solver.Solve(prog, None, opts)
        Y = np.asarray(result.GetSolution(y)).reshape(k, nc)
        if result.is_success():
            return Y
    return Y if np.all(np.isfinite(Y)) and np.any(Y) else None


def bound_of(
    K: np.ndarray, Y: np.ndarray, fixed: float, g_max: float, n: int | np.ndarray
) -> np.ndarray | float:
    """``tr(K^T Y)^2 / (fixed + n g_max)`` [mm^2] (``n`` an int or an array of counts)."""
    return float(np.sum(K * Y)) ** 2 / (fixed + np.asarray(n) * g_max)


@dataclasses.dataclass
class GivenDesign:
    """The approximate design of ``n`` poses added to measured ones (module docstring).

    Attributes:
        q: (m, 6) candidate poses [rad]: the certified design's and the maxima found here.
        F: (m, 3, k) their weighted identification rows.
        Y: (k, 3) the dual matrix of the last cone program.
        fixed: ``||R0 Y||_F^2`` of the measured poses.
        g_max: largest ``g = ||F_x Y||_F^2`` over every pose evaluated or searched with ``Y``.
        n: the new poses the cone program was solved for.
        rounds: column-generation rounds run.
        n_searched: local maximisations of ``g`` run.
    """

    q: np.ndarray
    F: np.ndarray
    Y: np.ndarray
    fixed: float
    g_max: float
    n: int
    rounds: int
    n_searched: int

    def bound(self, K: np.ndarray, n: int | np.ndarray) -> np.ndarray | float:
        """Lower bound [mm^2] on tr(Cs)/3 of the measured and any ``n`` more feasible poses."""
        return bound_of(K, self.Y, self.fixed, self.g_max, n)


_LOCAL = threading.local()


def given_design(
    problem: Problem,
    approx: ApproximateDesign,
    *,
    given: np.ndarray,
    n: int,
    collision: bool = True,
    rounds: int = GIVEN_ROUNDS,
    starts: int = GIVEN_STARTS,
    working: int = GIVEN_WORKING,
) -> GivenDesign:
    """The column generation of ``n`` poses added to the measured ``given`` (m0, 6) [rad], warm
    from ``approx`` (the certified approximate design of ``problem``, same ``collision``): each
    round prices every candidate and the local maxima found; the candidates of largest ``g`` join
    the working set until none lies above it (or ``rounds`` are run).

    Returns:
        :class:`GivenDesign`; its ``Y`` is the certified design's if every cone program failed.
        Cached per thread for the same problem object, approximate design, measured poses and
        settings (an online step's count and its design's second start share one when the greedy
        count equals the plan).
    """
    given = np.asarray(given, dtype=float)
    key = (id(problem), id(approx), given.tobytes(), int(n), bool(collision), rounds, starts, working)
    cache = _LOCAL.__dict__.setdefault("designs", {})
    hit = cache.get(key)
    if hit is not None and hit[0] is problem and hit[1] is approx:
        return hit[2]
    gd = _column_generation(
        problem, approx, given=given, n=n, collision=collision, rounds=rounds, starts=starts, working=working
    )
    if len(cache) > 8:
        cache.clear()
    cache[key] = (problem, approx, gd)
    return gd


def _column_generation(
    problem: Problem, approx: ApproximateDesign, *, given, n, collision, rounds, starts, working
) -> GivenDesign:
    """:func:`given_design`, not cached. The ``Y`` kept is the one of the largest bound among those
    tried (the certified design's and each round's), each with the largest ``g`` over its own
    search and every candidate at the end: a valid bound for every pose evaluated."""
    K = kpi_factor(problem)
    R0 = information_factor(_information(problem, given))
    q, F = approx.q, approx.F
    tried = [(approx.Y, approx.g_max)]  # each Y with the largest g of its own search
    done, searched = 0, 0
    work = np.union1d(approx.support, np.argsort(-dual_values(F, approx.Y))[:working])
    while done < rounds:
        Y = solve_given_pool(F[work], K, R0, n)
        if Y is None:
            break
        done += 1
        g = dual_values(F, Y)
        top = np.argsort(-g)[:starts]
        q_max, g_found, ok = maximize_dual(problem, q[top], Y, collision=collision)
        searched += len(top)
        g_max = max(float(g.max()), float(g_found[ok].max(initial=0.0)))
        tried.append((Y, g_max))
        g_work = float(g[work].max())
        new = ok & (g_found > g_work * (1.0 + ROUND_TOL))
        if new.any():
            F_new = pose_rows(problem, q_max[new])
            keep = distinct_rows(F, F_new)
            q, F = np.concatenate([q, q_max[new][keep]]), np.concatenate([F, F_new[keep]])
        if g_max <= g_work * (1.0 + ROUND_TOL):  # nothing priced above the working set: optimal
            break
        g = dual_values(F, Y)  # the candidates above the working set join it (at most ``working``)
        above = np.flatnonzero(g > g_work * (1.0 + ROUND_TOL))
        work = np.union1d(work, above[np.argsort(-g[above])[:working]])
    # every Y's largest g over all poses evaluated (candidates found later included), the best kept
    tried = [(Y, max(g, float(dual_values(F, Y).max()))) for Y, g in tried]
    Y, g_max = max(tried, key=lambda t: float(bound_of(K, t[0], _fixed(R0, t[0]), t[1], n)))
    return GivenDesign(
        q=q, F=F, Y=Y, fixed=_fixed(R0, Y), g_max=g_max, n=int(n), rounds=done, n_searched=searched
    )


def _fixed(R0: np.ndarray, Y: np.ndarray) -> float:
    """``||R0 Y||_F^2``: the measured poses' term of the bound."""
    return float(np.sum((R0 @ Y) ** 2)) if R0.size else 0.0


def _information(problem: Problem, given: np.ndarray) -> np.ndarray:
    F0 = pose_rows(problem, given).reshape(-1, problem.n_params)
    return F0.T @ F0


def fewest_certified(problem: Problem, gd: GivenDesign, *, target: float, n_max: int) -> int:
    """The fewest new poses (0..``n_max``) whose bound (:meth:`GivenDesign.bound`) is at most
    ``target`` [mm^2]: with fewer, no feasible poses the search reached make tr(Cs)/3 <= target;
    ``n_max + 1`` if even ``n_max`` cannot."""
    counts = np.arange(n_max + 1)
    ok = gd.bound(kpi_factor(problem), counts) <= target
    return int(counts[ok][0]) if ok.any() else n_max + 1
