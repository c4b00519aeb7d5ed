"""The heuristic design (paper section 3.2, SPEC): uniform random poses kept if feasible.

It is the paper's baseline design and the optimiser's starting point. A robot whose controller
couples joints (a joint map with fewer axes than joints) draws its poses on the coupling (each
uniform draw moved onto it, kept if still within the joint limits). A drawn pose is kept if its
incidence angle is within the cell's limit (paper eq. 4) and, with collision avoidance, every
capsule clearance of :class:`~kpioed_drake.robot.geometry.ClearanceModel` (robot, obstacles, self pairs,
laser beam; paper eq. 20-22) is at least :data:`~kpioed_drake.design.settings.HEURISTIC_MARGIN_MM`.
"""

from __future__ import annotations

import math

import numpy as np

from kpioed_drake import parallel
from kpioed_drake.design.settings import HEURISTIC_MARGIN_MM
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.jointmap import commandable_projection
from kpioed_drake.robot.kinematics import link_frames
from kpioed_drake.tracker.measurement import target_incidence

PARALLEL_POSES = 1000
"""Designs of this many poses or more (the certificate's pools of random poses) check their batches of
draws in worker processes, a batch per worker at a time."""


def heuristic_design(
    problem: Problem,
    *,
    n: int = 60,
    seed: int = 0,
    collision: bool = True,
    max_draws: int = 200_000,
    margin_mm: float = HEURISTIC_MARGIN_MM,
    batch: int = 4096,
) -> np.ndarray:
    """The paper's heuristic: uniform random poses from the joint box, kept only if feasible.

    Poses are drawn with ``numpy.random.default_rng(seed)`` in batches (the result does not depend
    on ``batch`` nor on the worker processes that check batches side by side for a design of
    :data:`PARALLEL_POSES` or more, :mod:`kpioed_drake.parallel`: the first ``n`` feasible draws are
    kept, in draw order). A pose is kept if its
    incidence angle is within the cell's limit and, with ``collision``, every clearance of
    :class:`~kpioed_drake.robot.geometry.ClearanceModel` (robot, obstacles, self pairs, laser beam) is at
    least ``margin_mm``.

    Args:
        problem: robot, cell and measurement model.
        n: number of poses.
        seed: random seed.
        collision: require collision and beam clearance.
        max_draws: give up after this many draws.
        margin_mm: smallest admitted clearance [mm].
        batch: poses drawn per vectorised feasibility evaluation.

    Returns:
        q: (n, n_joints) [rad, mm].

    Raises:
        InputError: fewer than ``n`` feasible poses in ``max_draws`` draws.
    """
    if n < 1:
        raise InputError(f"the number of poses must be positive, got {n}")
    robot, cell = problem.robot, problem.cell
    rng = np.random.default_rng(seed)
    cos_max = math.cos(cell.max_incidence)
    cm = ClearanceModel(robot, cell) if collision else None

    def feasible(q: np.ndarray) -> np.ndarray:
        """(b,) bool: the poses ``q`` (b, n_joints) within the incidence limit, the box and the margin."""
        ok = np.all((q >= robot.lower) & (q <= robot.upper), axis=1)  # a coupling may leave the box
        for t in range(problem.model.layout.n_targets):  # most draws fail the first target's incidence
            if ok.any():
                ok[ok] = _within_incidence(problem, q[ok], t, cos_max)
        if cm is not None and ok.any():
            ok[ok] = np.all(cm.values(q[ok]) >= margin_mm, axis=1)
        return ok

    kept, n_kept, draws = [], 0, 0
    large = n >= PARALLEL_POSES
    with parallel.pool(feasible, parallel=large) as check:
        per_round = parallel.workers() if large else 1
        while n_kept < n and draws < max_draws:  # a round: a batch per worker, in draw order
            qs = []
            for _ in range(per_round):
                b = min(batch, max_draws - draws)
                if b <= 0:
                    break
                qs.append(
                    commandable_projection(
                        robot, rng.uniform(robot.lower, robot.upper, size=(b, robot.n_joints))
                    )
                )
                draws += b
            for q, ok in zip(qs, check(qs), strict=True):
                kept.append(q[ok])
                n_kept += int(ok.sum())
    q = np.concatenate(kept, axis=0)[:n] if kept else np.zeros((0, robot.n_joints))
    if q.shape[0] < n:
        what = "incidence and collision-free" if collision else "incidence"
        msg = (
            f"no feasible pose found in {draws} draws"
            if q.shape[0] == 0
            else f"only {q.shape[0]} of {n} feasible poses found in {draws} draws"
        )
        raise InputError(
            f"{robot.name}: {msg} ({what} constraints): check the cell (car position, tracker, "
            "incidence limit) and the robot's joint limits"
        )
    return q


def _within_incidence(problem: Problem, q: np.ndarray, target: int, cos_max: float) -> np.ndarray:
    """(b,) bool: the poses ``q`` (b, n_joints) [rad, mm] whose incidence cosine to ``target``
    (0-based) is at least ``cos_max``, from the link frames on the path to the target's link alone
    (a tree's other arms are not computed)."""
    link = int(problem.model.robot.target_frames[target])
    frames = link_frames(problem.robot, q, path_to=link)
    return target_incidence(problem.model, q, target, frames=frames) >= cos_max
