"""Poses on the surfaces: the feasible set of a contact design, sampled and kept on it.

A pose is on surface k of a contact system (:mod:`.surfaces`: a plane, a ballbar's sphere about
its pivot) when its nominal tool point (target 0) is, ``r_k(p_WQ(q)) = 0``: one equality per pose.
:func:`project_to_surfaces` moves poses onto their surfaces by Gauss-Newton steps of least joint
motion, ``q <- q - r g / |g|^2`` with the residual ``r`` [mm] and its gradient ``g = dr/dp dp/dq``
(closed form). A pose on its surface is feasible (:func:`on_surface_feasible`) if it is within
:data:`ON_SURFACE_TOL_MM` of it, within the joint limits, keeps the system's rules (a touch's flange
on the plane's free side; a ballbar's bar within the cups' angles: ``admissible``) and, with
collision avoidance, every clearance of its system's model (:class:`ContactClearance`: the robot
and the cell's obstacles, for a ballbar also the bar and the pivot's stand) is at least the margin.
The planes themselves are not obstacles: a link other than the tool behind a plane is not detected
(a limit; the flange test keeps the wrist out).

:func:`contact_poses` draws uniform poses from the joint box (seeded), gives them the surfaces in
turn, projects them and keeps the first ``n`` feasible: the heuristic design on the surfaces and
the candidate pools of the design. Robots whose controller couples joints are refused (the
projection does not keep a coupling). Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.design.contact.surfaces import Surfaces
from kpioed_drake.design.settings import HEURISTIC_MARGIN_MM
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.kinematics import Frames, point_jacobian

ON_SURFACE_TOL_MM = 1e-6
"""A pose is on its surface if its nominal tool point is this close to it [mm]."""
PROJECTION_STEPS = 30
"""Gauss-Newton steps of :func:`project_to_surfaces` (converges in a few from a pose within reach)."""


@dataclasses.dataclass(frozen=True)
class ContactClearance:
    """The clearance models of a contact system's poses: one for every surface, or one per surface."""

    models: tuple[ClearanceModel, ...]

    def ok(self, q: np.ndarray, surface: np.ndarray, margin_mm: float) -> np.ndarray:
        """(n,) bool: every clearance of poses ``q`` (n, nj) on surfaces ``surface`` >= the margin."""
        if len(self.models) == 1:
            return np.all(self.models[0].values(q) >= margin_mm, axis=1)
        out = np.zeros(len(q), dtype=bool)
        for k in np.unique(surface):
            on = surface == k
            out[on] = np.all(self.models[k].values(q[on]) >= margin_mm, axis=1)
        return out


def tool_motion(frames: Frames, p: np.ndarray) -> np.ndarray:
    """(n, nj, 3) ``dp/dq`` of the tool points ``p`` (n, 3) on the flange (joints off its path: 0)."""
    dp = frames.joint_motion(p)
    on = frames.point_path(None)
    return dp if on is None else dp * on[:, :, None]


def surface_rows(
    problem: Problem, q: np.ndarray, surface: np.ndarray, surfaces: Surfaces
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The on-surface equalities of poses ``q`` (n, nj) [rad] on surfaces ``surface`` (n,).

    Returns:
        r: (n,) the residual [mm]; g: (n, nj) ``dr/dq`` [mm/rad]; ok: (n,) the system's rules kept.
    """
    frames = problem.model.frames(q)
    p, _ = point_jacobian(frames, problem.model.p_FQ)
    dp = tool_motion(frames, p)
    o_F = frames.at_link(None)[1]
    return (
        surfaces.residual(p, surface),
        np.einsum("nji,ni->nj", dp, surfaces.gradient(p, surface)),
        surfaces.admissible(p, o_F, surface),
    )


def project_to_surfaces(
    problem: Problem, q: np.ndarray, surface: np.ndarray, surfaces: Surfaces
) -> np.ndarray:
    """Poses ``q`` (n, nj) [rad] moved onto their surfaces ``surface`` (n,) by :data:`PROJECTION_STEPS`
    least-norm Gauss-Newton steps (a pose that cannot reach its surface stays off it)."""
    q = np.array(q, dtype=float)
    for _ in range(PROJECTION_STEPS):
        r, g, _ = surface_rows(problem, q, surface, surfaces)
        gg = np.sum(g * g, axis=1)
        step = np.where(gg > 1e-12, r / np.where(gg > 1e-12, gg, 1.0), 0.0)
        q -= step[:, None] * g
        if np.all(np.abs(r) < 0.1 * ON_SURFACE_TOL_MM):
            break
    return q


def on_surface_feasible(
    problem: Problem,
    q: np.ndarray,
    surface: np.ndarray,
    surfaces: Surfaces,
    *,
    clearance: ContactClearance | None,
    margin_mm: float = HEURISTIC_MARGIN_MM,
) -> np.ndarray:
    """(n,) bool: the poses are feasible (module docstring); ``clearance`` None: no collision
    avoidance."""
    robot = problem.robot
    r, _, rules = surface_rows(problem, q, surface, surfaces)
    ok = (np.abs(r) <= ON_SURFACE_TOL_MM) & rules
    ok &= np.all((q >= robot.lower) & (q <= robot.upper), axis=1)
    if clearance is not None and ok.any():
        ok[ok] = clearance.ok(q[ok], surface[ok], margin_mm)
    return ok


def contact_clearance(problem: Problem, surfaces: Surfaces, collision: bool) -> ContactClearance | None:
    """The clearances a pose on ``surfaces`` must keep (None: no collision avoidance)."""
    if not collision:
        return None
    cells = surfaces.cells(problem.cell)
    return ContactClearance(tuple(ClearanceModel(problem.robot, c, beam=surfaces.beam) for c in cells))


def contact_poses(
    problem: Problem,
    surfaces: Surfaces,
    *,
    n: int,
    seed: int = 0,
    collision: bool = True,
    margin_mm: float = HEURISTIC_MARGIN_MM,
    batch: int = 2048,
    max_draws: int = 400_000,
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` feasible poses on the surfaces: uniform draws (``default_rng(seed)``), surfaces in turn
    (draw i: surface i mod K), projected, the first ``n`` feasible in draw order.

    Returns:
        q: (n, nj) [rad]; surface: (n,) 0-based.

    Raises:
        InputError: a robot with coupled joints, fewer than ``n`` feasible poses in ``max_draws``.
    """
    robot = problem.robot
    if robot.joint_map is not None and robot.joint_map.coupling_equations()[0].size:
        raise InputError(
            f"{robot.name}: {surfaces.words.label} designs of robots with coupled joints are not supported"
        )
    rng = np.random.default_rng(seed)
    cm = contact_clearance(problem, surfaces, collision)
    K = len(surfaces)
    kept_q, kept_k, draws, n_kept = [], [], 0, 0
    while n_kept < n and draws < max_draws:
        q0 = rng.uniform(robot.lower, robot.upper, size=(batch, robot.n_joints))
        k = (draws + np.arange(batch)) % K
        draws += batch
        q = project_to_surfaces(problem, q0, k, surfaces)
        ok = on_surface_feasible(problem, q, k, surfaces, clearance=cm, margin_mm=margin_mm)
        kept_q.append(q[ok])
        kept_k.append(k[ok])
        n_kept += int(ok.sum())
    q, k = np.concatenate(kept_q)[:n], np.concatenate(kept_k)[:n]
    if len(q) < n:
        raise InputError(
            f"{robot.name}: only {len(q)} of {n} feasible {surfaces.words.noun} {surfaces.words.on} in "
            f"{draws} draws; check the {surfaces.words.hint}"
        )
    return q, k
