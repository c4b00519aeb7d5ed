"""The robot, the measuring cell and one measurement pose drawn on a :class:`Canvas`.

The robot is the MultibodyPlant's own collision geometry (:func:`kpioed_drake.robot.plant.build_scene`:
the link capsules), posed by the plant's SceneGraph at each joint vector. The cell is the plant's
world geometry (mount and car capsules) plus the floor and the wall, which the plant models as
12 m boxes (half-spaces) and which are drawn here as panels over the scene's extent, and the laser
tracker at ``p_WT`` with its axes ``R_WT``. A measurement pose (paper eq. 3, 4) is the robot, the
laser beam from the reflector ``p_WQ`` to the tracker, the reflector, and the segment between the
witness points of its smallest clearance (:func:`clearance_witness`).

Units: millimetres in W (robot base frame, z up).
"""

from __future__ import annotations

from collections.abc import Container

import numpy as np
from numpy.typing import ArrayLike
from pydrake.geometry import Box, Rgba

from kpioed_drake.robot.geometry import beam_targets, segment_distance
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.plant import MM, Scene
from kpioed_drake.scene3d.canvas import (
    AXES,
    BEAM,
    CAR,
    CLEARANCE,
    FLOOR,
    MOUNT,
    ROBOT,
    TRACKER,
    WALL,
    Canvas,
)

REFLECTOR_RADIUS = 19.05
"""Drawn radius of the reflector (a 1.5 inch SMR) [mm]."""
_PANEL = 10.0  # [mm] thickness of the floor and wall panels
_WALL_HEIGHT = 2500.0  # [mm]
_MARGIN = 600.0  # [mm] floor beyond the scene's content


def extent(robot: Robot, cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """Corners (lo, hi) (3,) [mm] of a box holding the robot's reach, the obstacles and the tracker."""
    pts = [np.array([-robot.reach, -robot.reach, cell.floor_z]), np.array([robot.reach, robot.reach, 0.0])]
    pts.append(cell.p_WT)
    for ob in cell.obstacles:
        pts += [ob.a - ob.radius, ob.a + ob.radius, ob.b - ob.radius, ob.b + ob.radius]
    P = np.array(pts)
    lo, hi = P.min(axis=0), P.max(axis=0)
    lo[0] = max(lo[0], cell.wall_x)
    return lo, hi


def draw_cell(canvas: Canvas, scene: Scene, robot: Robot, cell: Cell) -> None:
    """Floor and wall panels, the robot base, the obstacles and the tracker (static, under /cell)."""
    lo, hi = extent(robot, cell)
    lo_xy, hi_xy = lo[:2] - _MARGIN, hi[:2] + _MARGIN
    lo_xy[0] = cell.wall_x
    fz = cell.floor_z
    canvas.box("/cell/floor", [*lo_xy, fz - _PANEL], [*hi_xy, fz], FLOOR)
    canvas.box(
        "/cell/wall", [cell.wall_x - _PANEL, lo_xy[1], fz], [cell.wall_x, hi_xy[1], fz + _WALL_HEIGHT], WALL
    )
    draw_robot(canvas, "/cell/robot base", scene, np.zeros(robot.n_joints), ROBOT, links=(0,))
    car = {ob.name for ob in cell.obstacles if ob.moves_with_car}
    qo = scene.query_object()
    inspector = qo.inspector()
    for gid, link in scene.geometry_link.items():
        shape = inspector.GetShape(gid)
        if link == -1 and not isinstance(shape, Box):  # floor and wall boxes: the panels above
            name = scene.geometry_names[gid]
            canvas.shape(f"/cell/{name}", shape, qo.GetPoseInWorld(gid), CAR if name in car else MOUNT)
    p = cell.p_WT
    canvas.rod("/cell/tracker/stand", [p[0], p[1], fz], p - [0.0, 0.0, 120.0], 25.0, TRACKER)
    canvas.rod("/cell/tracker/head", p - [0.0, 0.0, 120.0], p + [0.0, 0.0, 120.0], 110.0, TRACKER)
    for i, colour in enumerate(AXES):
        canvas.rod(f"/cell/tracker/axis {'xyz'[i]}", p, p + 350.0 * cell.R_WT[:, i], 10.0, colour)


def draw_robot(
    canvas: Canvas, path: str, scene: Scene, q: ArrayLike, rgba: Rgba, *, links: Container[int] | None = None
) -> None:
    """The geometry of the robot links ``links`` (default: every moving link) at joint angles
    ``q`` (nj,) [rad], under ``path``."""
    links = range(1, len(scene.bodies)) if links is None else links
    scene.set_q(np.asarray(q, dtype=float))
    qo = scene.query_object()
    inspector = qo.inspector()
    for gid, link in scene.geometry_link.items():
        if link in links:
            name = scene.geometry_names[gid]
            canvas.shape(f"{path}/{name}", inspector.GetShape(gid), qo.GetPoseInWorld(gid), rgba)


def reflector_point(robot: Robot, cell: Cell, q: ArrayLike) -> np.ndarray:
    """(3,) reflector position p_WQ [mm] of the nominal robot at ``q`` (6,) [rad]."""
    return flange_point(forward_kinematics(robot, np.asarray(q, float)[None, :]), cell.p_FQ)[0]


def _capsule_in_world(robot: Robot, cell: Cell, q, name: str):
    """Axis end points (3,), (3,) [mm] and radius [mm] of the robot capsule or obstacle ``name``."""
    for ob in cell.obstacles:
        if ob.name == name:
            return ob.a, ob.b, ob.radius
    fr = forward_kinematics(robot, np.asarray(q, float)[None, :])
    for c in robot.capsules:
        if c.name == name:
            R, o = fr.R[0, c.frame], fr.o[0, c.frame]
            return o + R @ c.a, o + R @ c.b, c.radius
    raise KeyError(f"no capsule or obstacle named {name!r}")


def clearance_witness(
    scene: Scene, robot: Robot, cell: Cell, q: ArrayLike, pair: str
) -> tuple[np.ndarray, np.ndarray]:
    """Witness points (p_WA, p_WB) (3,) [mm] on the two surfaces of a clearance pair at ``q``.

    Args:
        scene: the plant of ``robot`` in ``cell`` (:func:`kpioed_drake.robot.plant.build_scene`).
        q: (6,) joint angles [rad].
        pair: ``"A vs B"`` as named by :class:`kpioed_drake.tracker.feasibility.PoseReport`
            (``min_clearance_pair``): two SceneGraph geometries, whose witness points come from
            Drake's ``ComputeSignedDistancePairClosestPoints``, or ``beam vs B``, the laser beam
            capsule (reflector to tracker, ``cell.beam_radius``) against a link capsule or an
            obstacle, whose points are the closest points of the two axes moved to the surfaces.
    """
    a, _, b = pair.partition(" vs ")
    beams = {label: (p, f) for label, p, f in beam_targets(robot, cell)}  # ``beam``, ``beam1`` ..
    if a in beams:
        p_Q = flange_point(forward_kinematics(robot, np.asarray(q, float)[None, :]), *beams[a])[0]
        A, B, radius = _capsule_in_world(robot, cell, q, b)
        d, s, t = segment_distance(p_Q, cell.p_WT, A, B)
        c_beam = p_Q + s * (cell.p_WT - p_Q)
        c_cap = A + t * (B - A)
        n = (c_cap - c_beam) / max(float(d), 1e-9)
        return c_beam + cell.beam_radius * n, c_cap - radius * n
    ids = {name: gid for gid, name in scene.geometry_names.items()}
    scene.set_q(np.asarray(q, dtype=float))
    qo = scene.query_object()
    sd = qo.ComputeSignedDistancePairClosestPoints(ids[a], ids[b])
    p_WA = qo.GetPoseInWorld(sd.id_A).multiply(sd.p_ACa)
    p_WB = qo.GetPoseInWorld(sd.id_B).multiply(sd.p_BCb)
    return np.asarray(p_WA) / MM, np.asarray(p_WB) / MM


def draw_pose(
    canvas: Canvas,
    path: str,
    scene: Scene,
    robot: Robot,
    cell: Cell,
    q: ArrayLike,
    *,
    rgba: Rgba = ROBOT,
    witness: tuple[np.ndarray, np.ndarray] | None = None,
    reflector: bool = True,
) -> np.ndarray:
    """One measurement pose under ``path``: robot, reflector, beam, and the clearance segment.

    Args:
        q: (6,) joint angles [rad].
        rgba: robot colour.
        witness: the smallest clearance's witness points [mm], drawn as a short segment.
        reflector: draw the reflector and its laser beam (False: a pose without a tracker, e.g.
            a touch of a plane).

    Returns:
        (3,) the reflector position p_WQ [mm].
    """
    draw_robot(canvas, f"{path}/robot", scene, q, rgba)
    p_Q = reflector_point(robot, cell, q)
    if reflector:
        canvas.sphere(f"{path}/reflector", p_Q, REFLECTOR_RADIUS, Rgba(0.85, 0.85, 0.9, 1.0))
        canvas.rod(f"{path}/beam", p_Q, cell.p_WT, max(cell.beam_radius, 10.0), BEAM)
    if witness is not None:
        p_A, p_B = witness
        canvas.rod(f"{path}/clearance/segment", p_A, p_B, 6.0, CLEARANCE)
        canvas.sphere(f"{path}/clearance/A", p_A, 22.0, CLEARANCE)
        canvas.sphere(f"{path}/clearance/B", p_B, 22.0, CLEARANCE)
    return p_Q


def default_camera(canvas: Canvas, robot: Robot, cell: Cell, p_WQ: ArrayLike) -> None:
    """Camera in front of the robot, to its right and above, looking between the robot base and the
    mean of the reflector points ``p_WQ`` (n, 3) [mm], at 700 mm height."""
    lo, hi = extent(robot, cell)
    size = float(np.linalg.norm(hi - lo))
    target = np.append(0.5 * np.mean(np.atleast_2d(p_WQ), axis=0)[:2], 700.0)
    direction = np.array([0.8, -1.0, 0.8])
    canvas.camera(target + 0.4 * size * direction / np.linalg.norm(direction), target)
