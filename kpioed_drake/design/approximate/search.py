"""The search over the continuous feasible poses: local maxima of ``g(x) = ||F_x Y||_F^2``.

``g`` is the pricing function of the approximate design's column generation and the quantity whose
maximum over the feasible poses (paper eq. 24b) makes the certificate's bound
(:mod:`kpioed_drake.design.approximate.design`, :mod:`kpioed_drake.design.approximate.certificate`);
``F_x`` is the pose's rows of the weighted identification Jacobian (paper eq. 24d; 3, or 6 with a
6-DoF probe's pose) and ``Y`` (k, c) a dual matrix (c: the KPI's rows, 3 per working pose). Up to a
factor, ``g`` is the directional derivative ``d(x, w) = tr(A M^-1 M_x M^-1)`` of the general
equivalence theorem.

- :func:`maximize_dual`: local maxima by SNOPT under the design's own constraint rows (a
  :class:`DesignProgram` of a few poses whose objective is ``-sum g``);
- :func:`corner_poses`: starting poses with joints at their limits. Maxima of ``g`` sit on the
  constraint boundaries (incidence limit, clearances, joint limits), which uniform random poses
  almost never reach (docs/certificate.md, design notes).

This is a search: it does not prove that no feasible pose has a larger ``g``.

Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from pydrake.solvers import SnoptSolver, SolverOptions

from kpioed_drake import parallel, progress
from kpioed_drake.design.exact.constraints import DesignConstraints
from kpioed_drake.design.exact.program import DesignProgram
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.jointmap import commandable_projection
from kpioed_drake.robot.kinematics import Frames

SEARCH_VARIABLES = 48
"""Joint variables per SNOPT solve of the local maximisation: :func:`search_batch` starts per solve
(8 on a six-joint robot, 2 on the 18-joint twin). Independent starts share the solver's steps, so a
solve takes the iterations of its slowest start; few starts per solve pay Python's overhead per
evaluation instead (docs/certificate.md, design notes)."""
SEARCH_OPTIONS = {
    "Major optimality tolerance": 1e-5,
    "Major feasibility tolerance": 1e-7,
    "Major step limit": 0.2,
}
"""SNOPT options of the local maximisation (step limit as in the design: long first steps left poses
deep in incidence violation)."""


ROUND_VARIABLES = 144
"""Joint variables of the column generation's local maximisations per round (:func:`round_starts`):
24 starts on a six-joint robot. On many joints a start costs more, while the rounds (cone programs),
not the starts per round, set how fast the column generation converges (docs/certificate.md)."""
ROUND_STARTS_MIN = 12
"""Fewest local maximisations per round (:func:`round_starts`)."""


def round_starts(n_joints: int) -> tuple[int, int]:
    """Local maximisations of ``g`` per column-generation round on a robot of ``n_joints`` joints
    (:data:`ROUND_VARIABLES` joint variables, at least :data:`ROUND_STARTS_MIN`) and how many of
    them start from random candidates (a third; the rest from the candidates of largest ``g``)."""
    starts = max(ROUND_STARTS_MIN, ROUND_VARIABLES // int(n_joints))
    return starts, starts // 3


def settings() -> dict:
    """The local maximisations' settings (part of the certificate cache key)."""
    local = ("SEARCH_VARIABLES", "ROUND_VARIABLES", "ROUND_STARTS_MIN")
    return {**{name: globals()[name] for name in local}, "SEARCH_OPTIONS": sorted(SEARCH_OPTIONS.items())}


def search_batch(n_joints: int) -> int:
    """Starts per SNOPT solve of :func:`maximize_dual` on a robot of ``n_joints`` joints:
    :data:`SEARCH_VARIABLES` joint variables, at least one start."""
    return max(1, SEARCH_VARIABLES // int(n_joints))


def pose_rows(problem: Problem, q: np.ndarray) -> np.ndarray:
    """Each pose's rows of the weighted identification Jacobian: (m, r, k) for ``q`` (m, 6) [rad]
    (r = :attr:`Problem.rows_per_pose`: 3, 3 T with T targets, 6 with pose measurements)."""
    q = np.asarray(q, dtype=float).reshape(-1, problem.robot.n_joints)
    return problem.F1(q).reshape(q.shape[0], -1, problem.n_params)


def dual_values(F: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``g_i = ||F_i Y||_F^2`` (m,) of rows ``F`` (m, 3, k) and a dual matrix ``Y`` (k, 3)."""
    FY = np.einsum("iak,kc->iac", F, Y)
    return np.einsum("iac,iac->i", FY, FY)


class DualObjective:
    """``-sum_i g(x_i)``, ``g(x) = ||F_x Y||_F^2``, of n poses and its gradient (n, 6): the
    interface of the design's objective, so that a :class:`DesignProgram` maximises ``g``.
    ``d g/d q_j = 2 sum (F Y) * (dF/dq_j Y)`` with ``dF/dq`` of :meth:`Problem.F1`."""

    def __init__(self, problem: Problem, Y: np.ndarray):
        self.problem, self.Y = problem, Y

    def value(self, q: np.ndarray, *, frames: Frames | None = None) -> float:
        """``-sum_i g(q_i)`` of ``q`` (n, 6) [rad]."""
        q = np.asarray(q, dtype=float).reshape(-1, self.problem.robot.n_joints)
        F = self.problem.F1(q, frames=frames).reshape(q.shape[0], -1, self.problem.n_params)
        return -float(dual_values(F, self.Y).sum())

    def value_and_grad(self, q: np.ndarray, *, frames: Frames | None = None) -> tuple[float, np.ndarray]:
        """The value and its gradient (n, 6) [1/rad]."""
        q = np.asarray(q, dtype=float).reshape(-1, self.problem.robot.n_joints)
        F1, dF = self.problem.F1(q, with_dq=True, frames=frames)
        FY = np.einsum("iak,kc->iac", F1.reshape(q.shape[0], -1, self.problem.n_params), self.Y)
        dFY = np.einsum("ijak,kc->ijac", dF, self.Y)
        return -float(np.sum(FY * FY)), -2.0 * np.einsum("iac,ijac->ij", FY, dFY)


def maximize_dual(
    problem: Problem, q_start: np.ndarray, Y: np.ndarray, *, collision: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima of ``g(x) = ||F_x Y||_F^2`` over the feasible poses, one from each start.

    SNOPT solves the separable problem ``max sum_i g(x_i)`` (independent problems solved together)
    for :func:`search_batch` starts at a time (the batches in worker processes,
    :func:`kpioed_drake.parallel.independent`: the same poses with any number of workers), under
    the design's constraint rows (joint limits, incidence, with ``collision`` the clearances;
    :class:`DesignProgram` with its margins).

    Args:
        q_start: (s, 6) starting poses [rad].
        Y: (k, 3) dual matrix.

    Returns:
        q: (s, 6) poses reached [rad] (on the joint map's couplings); g: (s,) their ``g``;
        feasible: (s,) bool, :func:`feasible`.
    """
    if problem.worst_case:  # the constraint rows without the worst case's epigraph variable
        problem = dataclasses.replace(problem, kpi_aggregate="mean")
    b = search_batch(problem.robot.n_joints)
    batches = [q_start[k0 : k0 + b] for k0 in range(0, q_start.shape[0], b)]
    out = parallel.independent(
        lambda i: _local_maxima(problem, batches[i], Y, collision=collision), len(batches)
    )
    q = np.clip(
        commandable_projection(problem.robot, np.concatenate(out)), problem.robot.lower, problem.robot.upper
    )
    return q, dual_values(pose_rows(problem, q), Y), feasible(problem, q, collision=collision)


def _local_maxima(problem: Problem, q_start: np.ndarray, Y: np.ndarray, *, collision: bool) -> np.ndarray:
    """One SNOPT solve of :func:`maximize_dual` from the b poses ``q_start`` (b, 6): the poses reached."""
    snopt, opts = SnoptSolver(), SolverOptions()
    for name, val in SEARCH_OPTIONS.items():
        opts.SetOption(snopt.solver_id(), name, val)
    b = q_start.shape[0]
    dp = DesignProgram(problem, criterion="kpi", n=b, collision=collision)
    dp.objective = DualObjective(problem, Y)
    result = snopt.Solve(dp.prog, q_start.reshape(-1), opts)
    return np.asarray(result.GetSolution(dp.x)).reshape(b, problem.robot.n_joints)


COUPLING_TOL = 1e-7
"""Largest violation of a joint map's coupling equations in a feasible pose [rad, mm]."""
CORNER_PROBABILITY = 1.0 / 3.0
"""Probability that :func:`corner_poses` puts a joint of a pose at one of its limits."""


def feasible(problem: Problem, q: np.ndarray, *, collision: bool = True) -> np.ndarray:
    """(m,) bool: every constraint row of the pose (:meth:`DesignConstraints.evaluate`: incidence,
    with ``collision`` the clearances) is >= 0, the joints are within their limits and follow the
    joint map's couplings (a pose the controller can command)."""
    rows, _ = DesignConstraints(problem, collision=collision).evaluate(q)
    inside = np.all((q >= problem.robot.lower) & (q <= problem.robot.upper), axis=1)
    inside &= np.all(np.abs(commandable_projection(problem.robot, q) - q) <= COUPLING_TOL, axis=1)
    return inside & np.all(rows >= 0.0, axis=1)


def corner_poses(problem: Problem, q: np.ndarray, *, seed: int = 0, collision: bool = True) -> np.ndarray:
    """Variants of the poses ``q`` (m, 6) [rad] with joints at their limits; the feasible ones.

    Each joint of each pose is set, with probability :data:`CORNER_PROBABILITY`, to its lower or
    upper limit (equally likely; seeded). Variants with a joint at a limit that are
    :func:`feasible` are kept.

    Returns:
        (s, 6) [rad], s <= m.
    """
    rng = np.random.default_rng(seed)
    lo, up = problem.robot.lower, problem.robot.upper
    limit = np.where(rng.random(q.shape) < 0.5, lo, up)
    at = rng.random(q.shape) < CORNER_PROBABILITY
    qc = commandable_projection(problem.robot, np.where(at, limit, q)[at.any(axis=1)])
    return qc[feasible(problem, qc, collision=collision)]


def perturbed_poses(
    problem: Problem, q: np.ndarray, *, scale_rad: float, seed: int = 0, collision: bool = True
) -> np.ndarray:
    """The :func:`feasible` ones of ``q`` (m, 6) [rad] plus normal noise of ``scale_rad`` per joint."""
    qp = np.asarray(q, dtype=float) + np.random.default_rng(seed).normal(scale=scale_rad, size=np.shape(q))
    qp = commandable_projection(problem.robot, qp)
    return qp[feasible(problem, qp, collision=collision)]


COLD_SEARCH_UNITS = 30_000.0
"""CPU time of a cold :func:`certified_design` of a six-joint robot in units of one evaluation of
``F1`` and ``dF1/dq`` at :data:`ESTIMATE_POSES` poses (measured in one process: kr16 30,100 units,
the 18-joint twin with two targets 60,400, hence the growth :data:`COLD_SEARCH_GROWTH` with the
joints): a rough estimate, to tell a user before a run of minutes."""
COLD_SEARCH_GROWTH = 0.64
"""Exponent of the joint count in :func:`cold_search_estimate_s`."""


ESTIMATE_POSES = 8
"""Poses of the timed evaluation that is the unit of :data:`COLD_SEARCH_UNITS`."""


def cold_search_estimate_s(problem: Problem, *, evaluations: int = 5) -> float:
    """A rough estimate of a cold certificate search's time here [s]: ``evaluations`` timed
    evaluations of ``F1`` with ``dF1/dq`` at seeded poses in the limits, times
    :data:`COLD_SEARCH_UNITS` grown with the joint count."""
    robot = problem.robot
    q = np.random.default_rng(0).uniform(robot.lower, robot.upper, size=(ESTIMATE_POSES, robot.n_joints))
    problem.F1(q, with_dq=True)
    t0 = time.process_time()
    for _ in range(evaluations):
        problem.F1(q, with_dq=True)
    unit = (time.process_time() - t0) / evaluations
    return unit * COLD_SEARCH_UNITS * (robot.n_joints / 6.0) ** COLD_SEARCH_GROWTH


ANNOUNCE_ABOVE_S = 20.0
"""A cold search estimated longer than this is announced (:func:`progress.note`)."""


def announce_cold_search(problem: Problem) -> None:
    """The estimate of a long cold search, before it starts (shown where progress is)."""
    if not progress.shown():
        return
    est = cold_search_estimate_s(problem)
    if est > ANNOUNCE_ABOVE_S:
        progress.note(
            f"first design of this robot and cell: searching the poses of its certificate, about "
            f"{max(1, round(est / 60))} min here (stored: later designs of it start at once)"
        )
