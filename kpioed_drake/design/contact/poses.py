"""Poses on the planes: the feasible set of a plane-contact design, sampled and kept on it.

A pose touches plane k when its nominal tool point (target 0) lies on it, ``n_k . p_WQ(q) = d_k``: one
equality per pose. :func:`project_to_planes` moves poses onto their planes by Gauss-Newton steps of
least joint motion, ``q <- q - r g / |g|^2`` with ``r = n_k . p - d_k`` [mm] and its gradient
``g = n_k^T dp/dq`` (closed form). A pose on its plane is feasible (:func:`on_plane_feasible`) if it
is within :data:`ON_PLANE_TOL_MM` of the plane, within the joint limits, its flange is on the plane's
free side at least :data:`FLANGE_CLEARANCE_MM` from it (the tool comes from the free side) and,
with collision avoidance, every capsule clearance of the robot and the cell's obstacles (no laser
beam: nothing is tracked) is at least the margin. The planes themselves are not obstacles: a link
other than the tool behind a plane is not detected (a limit; the flange test keeps the wrist out).

:func:`plane_poses` draws uniform poses from the joint box (seeded), gives them the planes in turn,
projects them and keeps the first ``n`` feasible: the heuristic design on the planes and the
candidate pools of the design. Robots whose controller couples joints are refused (the projection
does not keep a coupling). Units: millimetres and radians.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.design.settings import HEURISTIC_MARGIN_MM
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.kinematics import point_jacobian

ON_PLANE_TOL_MM = 1e-6
"""A pose is on its plane if its nominal tool point is this close to it [mm]."""
FLANGE_CLEARANCE_MM = 20.0
"""The flange's origin stays at least this far on the plane's free side [mm]."""
PROJECTION_STEPS = 30
"""Gauss-Newton steps of :func:`project_to_planes` (converges in a few from a pose within reach)."""


def plane_rows(
    problem: Problem, q: np.ndarray, plane: np.ndarray, normals: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The on-plane equalities of poses ``q`` (n, nj) [rad] touching planes ``plane`` (n,).

    Returns:
        r: (n,) ``n_k . p_WQ - d_k`` [mm]; g: (n, nj) ``dr/dq`` [mm/rad]; side: (n,) the flange
        origin's signed distance to the plane [mm].
    """
    frames = problem.model.frames(q)
    p, _ = point_jacobian(frames, problem.model.p_FQ)
    nk = normals[plane]
    dp = frames.joint_motion(p)  # (n, nj, 3)
    on = frames.point_path(None)
    if on is not None:
        dp = dp * on[:, :, None]
    o_F = frames.at_link(None)[1]
    return (
        np.sum(nk * p, axis=1) - offsets[plane],
        np.einsum("nji,ni->nj", dp, nk),
        np.sum(nk * o_F, axis=1) - offsets[plane],
    )


def project_to_planes(
    problem: Problem, q: np.ndarray, plane: np.ndarray, normals: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """Poses ``q`` (n, nj) [rad] moved onto their planes ``plane`` (n,) by :data:`PROJECTION_STEPS`
    least-norm Gauss-Newton steps (a pose that cannot reach its plane stays off it)."""
    q = np.array(q, dtype=float)
    for _ in range(PROJECTION_STEPS):
        r, g, _ = plane_rows(problem, q, plane, normals, offsets)
        gg = np.sum(g * g, axis=1)
        step = np.where(gg > 1e-12, r / np.where(gg > 1e-12, gg, 1.0), 0.0)
        q -= step[:, None] * g
        if np.all(np.abs(r) < 0.1 * ON_PLANE_TOL_MM):
            break
    return q


def on_plane_feasible(
    problem: Problem,
    q: np.ndarray,
    plane: np.ndarray,
    normals: np.ndarray,
    offsets: np.ndarray,
    *,
    clearance: ClearanceModel | None,
    margin_mm: float = HEURISTIC_MARGIN_MM,
) -> np.ndarray:
    """(n,) bool: the poses are feasible touches (module docstring); ``clearance`` None: no
    collision avoidance."""
    robot = problem.robot
    r, _, side = plane_rows(problem, q, plane, normals, offsets)
    ok = (np.abs(r) <= ON_PLANE_TOL_MM) & (side >= FLANGE_CLEARANCE_MM)
    ok &= np.all((q >= robot.lower) & (q <= robot.upper), axis=1)
    if clearance is not None and ok.any():
        ok[ok] = np.all(clearance.values(q[ok]) >= margin_mm, axis=1)
    return ok


def plane_clearance(problem: Problem, collision: bool) -> ClearanceModel | None:
    """The clearances a touch must keep: robot, self pairs and obstacles, no beam (None: none)."""
    return ClearanceModel(problem.robot, problem.cell, beam=False) if collision else None


def plane_poses(
    problem: Problem,
    normals: np.ndarray,
    offsets: np.ndarray,
    *,
    n: int,
    seed: int = 0,
    collision: bool = True,
    margin_mm: float = HEURISTIC_MARGIN_MM,
    batch: int = 2048,
    max_draws: int = 400_000,
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` feasible touches of the planes: uniform draws (``default_rng(seed)``), planes in turn
    (draw i: plane i mod K), projected, the first ``n`` feasible in draw order.

    Returns:
        q: (n, nj) [rad]; plane: (n,) 0-based.

    Raises:
        InputError: a robot with coupled joints, fewer than ``n`` feasible touches in ``max_draws``.
    """
    robot = problem.robot
    if robot.joint_map is not None and robot.joint_map.coupling_equations()[0].size:
        raise InputError(
            f"{robot.name}: plane-contact designs of robots with coupled joints are not supported"
        )
    rng = np.random.default_rng(seed)
    cm = plane_clearance(problem, collision)
    K = len(offsets)
    kept_q, kept_k, draws, n_kept = [], [], 0, 0
    while n_kept < n and draws < max_draws:
        q0 = rng.uniform(robot.lower, robot.upper, size=(batch, robot.n_joints))
        k = (draws + np.arange(batch)) % K
        draws += batch
        q = project_to_planes(problem, q0, k, normals, offsets)
        ok = on_plane_feasible(problem, q, k, normals, offsets, clearance=cm, margin_mm=margin_mm)
        kept_q.append(q[ok])
        kept_k.append(k[ok])
        n_kept += int(ok.sum())
    q, k = np.concatenate(kept_q)[:n], np.concatenate(kept_k)[:n]
    if len(q) < n:
        raise InputError(
            f"{robot.name}: only {len(q)} of {n} feasible touches of the planes in {draws} draws; "
            "check the planes (within reach, a free side the flange can be on)"
        )
    return q, k
