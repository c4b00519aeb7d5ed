"""The optimum approximate design over a finite pool of candidates: the cone program and its check.

Over candidates with rows ``F_i`` (paper eq. 24d) the L-criterion's optimum (eq. 24a, 24c) is a
second-order-cone program (Sagnol 2011) whose dual is

    sqrt(Phi*) = max_Y tr(K^T Y)   s.t.  ||F_i Y||_F <= 1  for every candidate i

(:mod:`kpioed_drake.design.approximate.design`: the notation). :func:`solve_pool` solves it with
the structured barrier method of :mod:`.barrier`; if that does not reach its gap, with Drake's
``MathematicalProgram`` and Clarabel (the cones' multipliers give the weights). Either way ``Phi(w)``
and ``tr(K^T Y)^2`` are evaluated here in numpy, so ``dual <= Phi*_pool <= phi`` holds whatever
the solver's accuracy.

Units: millimetres and radians; ``Phi`` in mm^2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
from collections.abc import Iterator

import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions

from kpioed_drake.design.approximate import barrier
from kpioed_drake.design.approximate.barrier import barrier_dual
from kpioed_drake.design.approximate.search import dual_values
from kpioed_drake.errors import InputError

CONE_TOL = 1e-11
"""Relative duality gap the pool's cone program is solved to (a looser 1e-8 left the
equivalence-theorem gap at the pool optimum near 1e-6)."""
BARRIER_ACCEPT = 1e-8
"""The barrier's result is kept when ``1 - dual / phi`` is at most this or 100 times the asked gap;
otherwise Clarabel solves the pool. Pools with nearly equal candidates have many optimal weights,
and both methods then stop near 1e-8 (Clarabel between 1e-10 and 2e-8 at 1e-11 asked, measured on
nine such pools of the 18-joint twin)."""
RETRY_TOLS = (1e-9, 1e-7)
"""Looser tolerances Clarabel tries in turn when it stops short of the asked one ("insufficient
progress", on a few robots at 1e-11, docs/studies.md). The bound stays rigorous; only its tightness
depends on the tolerance."""


def settings() -> dict:
    """The pool solve's settings (part of the certificate cache key): its gap and acceptance and
    the barrier method's (:mod:`.barrier`)."""
    own = {"CONE_TOL": CONE_TOL, "BARRIER_ACCEPT": BARRIER_ACCEPT, "RETRY_TOLS": RETRY_TOLS}
    return {**own, **barrier.settings()}


@contextlib.contextmanager
def quiet_solver_notes() -> Iterator[None]:
    """Drake's log at WARNING within: Clarabel's "returns InsufficientProgress" notes (INFO) are
    expected where a tight tolerance is tried before a looser one, and would reach the user."""
    log = logging.getLogger("drake")
    level = log.level
    log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        log.setLevel(level)


def l_criterion(F: np.ndarray, w: np.ndarray, K: np.ndarray) -> tuple[float, np.ndarray]:
    """``Phi(w) = tr(K^T M(w)^-1 K)`` [mm^2] and ``M(w)^-1 K`` (k, 3) of rows ``F`` (m, 3, k)
    (numpy.linalg.LinAlgError if ``M(w)`` is singular)."""
    X = np.linalg.solve(np.einsum("i,iak,ial->kl", w, F, F), K)
    return float(np.sum(K * X)), X


@dataclasses.dataclass
class PoolSolution:
    """Optimum approximate design over a finite set of candidates (the cone program above).

    Attributes:
        w: (m,) weights (sum 1), the cones' multipliers normalised.
        Y: (k, 3) dual matrix, scaled so that ``max_i g_i = 1`` over the candidates.
        phi: ``Phi(w)`` evaluated in numpy [mm^2], an upper bound on the pool optimum.
        dual: ``tr(K^T Y)^2`` [mm^2], a lower bound on it (as ``max_i g_i = 1``).
    """

    w: np.ndarray
    Y: np.ndarray
    phi: float
    dual: float


def _solution(
    F: np.ndarray, K: np.ndarray, w: np.ndarray, Y: np.ndarray, *, equivalence: bool = False
) -> PoolSolution:
    """:class:`PoolSolution` of weights ``w`` and a dual direction ``Y``, both evaluated here; with
    ``equivalence`` also of ``M(w)^-1 K`` (the equivalence theorem's ``Y`` of ``w``), the one of
    the two with the larger bound kept.

    Raises:
        InputError: the weighted candidates do not determine the parameters.
    """
    try:
        phi, X = l_criterion(F, w, K)
    except np.linalg.LinAlgError:
        raise InputError("the candidate poses do not determine the parameters") from None
    scaled = [Z / math.sqrt(dual_values(F, Z).max()) for Z in ((Y, X) if equivalence else (Y,))]
    Y = max(scaled, key=lambda Z: float(np.sum(K * Z)) ** 2)
    return PoolSolution(w=w, Y=Y, phi=phi, dual=float(np.sum(K * Y)) ** 2)


def solve_pool(F: np.ndarray, K: np.ndarray, *, tol: float = CONE_TOL) -> PoolSolution:
    """The optimum approximate design over the candidates with rows ``F`` (m, 3, k).

    The barrier method (:func:`.barrier.barrier_dual`) to the relative duality gap ``tol``, with
    the better of its ``Y`` and ``M(w)^-1 K``; its result is kept if ``1 - dual / phi`` is at most
    :data:`BARRIER_ACCEPT` or ``100 tol``, else Clarabel solves the same program (gap and
    feasibility tolerances ``tol``, then :data:`RETRY_TOLS`).

    Raises:
        InputError: if the solver fails or the weighted candidates do not determine the parameters.
    """
    try:
        w, Y = barrier_dual(F, K, rtol=tol)
        sol = _solution(F, K, w, Y, equivalence=True)
        if sol.dual >= sol.phi * (1.0 - max(BARRIER_ACCEPT, 100.0 * tol)):
            return sol
    except (np.linalg.LinAlgError, InputError, FloatingPointError):
        pass
    return _clarabel(F, K, tol=tol)


def _clarabel(F: np.ndarray, K: np.ndarray, *, tol: float) -> PoolSolution:
    """:func:`solve_pool` by Drake's ``MathematicalProgram`` and Clarabel."""
    m, r, k = F.shape  # r: 3 rows per pose, 3 T with T targets
    nc = K.shape[1]  # 3; several working poses: 3 K
    prog = MathematicalProgram()
    y = prog.NewContinuousVariables(nc * k, "y")  # Y[j, c] = y[nc j + c]
    A = np.zeros((m, 1 + r * nc, nc * k))  # cone i: (1, vec(F_i Y)) with vec row-major
    for a in range(r):
        for c in range(nc):
            A[:, 1 + nc * a + c, c::nc] = F[:, a]
    b = np.eye(1 + r * nc)[0]
    cones = [prog.AddLorentzConeConstraint(A[i], b, y) for i in range(m)]
    prog.AddLinearCost(-K.reshape(-1), 0.0, y)
    solver = ClarabelSolver()
    for t in (tol, *(x for x in RETRY_TOLS if x > tol)):
        opts = SolverOptions()
        for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio"):
            opts.SetOption(solver.solver_id(), name, t)
        with quiet_solver_notes():
            result = solver.Solve(prog, None, opts)
        if result.is_success():
            break
    else:
        raise InputError(f"the approximate design's cone program failed: {result.get_solution_result()}")
    lam = np.maximum([result.GetDualSolution(c)[0] for c in cones], 0.0)
    Y = np.asarray(result.GetSolution(y)).reshape(k, nc)
    return _solution(F, K, lam / lam.sum(), Y)
