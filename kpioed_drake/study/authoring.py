"""Authoring model files: kinematic rows, enclosing capsules, mass estimates and ``q_work``.

Used once to write the YAML files under ``models/robots`` (``studies/make_models.py``) and by users
who describe a robot of their own. After authoring, the YAML file is the source of truth; nothing at
run time calls these functions.

- :func:`kinematic_rows`: SPEC's DH/Hayati table for a KUKA-like six-axis arm from its datasheet
  lengths (d1, a1, a2, a3, d4, d6), with our sign conventions (see ``models/README.md``).
- :func:`envelope_links`: one capsule per moving link that nearly surrounds it (paper 3.2).
- :func:`solve_q_work`: the working pose of SPEC by Drake inverse kinematics.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.solvers import Solve

from kpioed_drake.robot.kinematics import forward_kinematics
from kpioed_drake.robot.models import (
    CapsuleSpec,
    Cell,
    JointSpec,
    LinkSpec,
    Robot,
    RobotSpec,
    robot_from_spec,
)
from kpioed_drake.robot.plant import MM, build_scene


def kinematic_rows(
    *,
    d1: float,
    a1: float,
    a2: float,
    a3: float,
    d4: float,
    d6: float,
    limits_deg: Iterable[tuple[float, float]],
) -> list[JointSpec]:
    """The six rows [mm, deg] for an arm with a spherical wrist.

    Joint 2 uses Hayati (its axis is parallel to joint 3's). With these rows q = 0 has the upper
    arm horizontal and forward, the forearm straight on, the flange pointing forward; positive
    q2/q3 turn the arm down (KUKA's A2/A3 sense, so KUKA's axis ranges apply unchanged).
    """
    rows = [
        JointSpec("A1", "dh", theta_deg=0.0, d_mm=d1, a_mm=a1, alpha_deg=-90.0),
        JointSpec("A2", "hayati", theta_deg=0.0, a_mm=a2, alpha_deg=0.0, beta_deg=0.0),
        JointSpec("A3", "dh", theta_deg=-90.0, d_mm=0.0, a_mm=a3, alpha_deg=-90.0),
        JointSpec("A4", "dh", theta_deg=0.0, d_mm=d4, a_mm=0.0, alpha_deg=-90.0),
        JointSpec("A5", "dh", theta_deg=0.0, d_mm=0.0, a_mm=0.0, alpha_deg=-90.0),
        JointSpec("A6", "dh", theta_deg=180.0, d_mm=-d6, a_mm=0.0, alpha_deg=180.0),
    ]
    for r, (lo, up) in zip(rows, limits_deg, strict=True):
        r.lower_deg, r.upper_deg = float(lo), float(up)
    return rows


@dataclasses.dataclass
class EnvelopeSize:
    """Capsule radii [mm] and link masses [kg] of a robot class."""

    r_base: float
    r_shoulder: float
    r_upper: float
    r_fore: float
    r_wrist: float
    r_tool: float
    masses: tuple[float, ...]  # links 0..6


def _local(R, o, p_W):
    return (R.T @ (np.asarray(p_W, float) - o)).round(3).tolist()


def envelope_links(rows: list[JointSpec], size: EnvelopeSize, p_FQ: ArrayLike) -> list[LinkSpec]:
    """Capsules that nearly surround each link, and link masses with centres of mass.

    Computed at q = 0 in world coordinates and stored in the link frames:
    base column (link 0), shoulder (1), upper arm (2), forearm with its rear housing (3),
    wrist (5), tool holder up to the reflector (6). Link 4 turns inside the forearm capsule.
    """
    robot = robot_from_spec(RobotSpec(name="tmp", joints=rows))
    f = forward_kinematics(robot, np.zeros(6))
    R, o = f.R[0], f.o[0]
    d1 = rows[0].d_mm
    d4 = rows[3].d_mm
    z = np.array([0.0, 0.0, 1.0])
    caps = {
        0: [
            ("base", size.r_base, _local(R[0], o[0], [0, 0, size.r_base]), _local(R[0], o[0], 0.45 * d1 * z))
        ],
        1: [
            (
                "shoulder",
                size.r_shoulder,
                _local(R[1], o[1], (0.45 * d1 + size.r_base + 30.0) * z),
                _local(R[1], o[1], o[1]),
            )
        ],
        2: [("upper_arm", size.r_upper, _local(R[2], o[2], o[1]), _local(R[2], o[2], o[2]))],
        3: [
            (
                "forearm",
                size.r_fore,
                [0.0, 0.0, round(-0.25 * d4, 3)],
                [0.0, 0.0, round(d4 - size.r_wrist - 40.0, 3)],
            )
        ],
        5: [("wrist", size.r_wrist, [0.0, 0.0, 0.0], _local(R[5], o[5], o[6] - 0.2 * (o[6] - o[5])))],
        6: [
            (
                "tool",
                size.r_tool,
                [0.0, 0.0, size.r_tool],
                (0.82 * np.asarray(p_FQ, float)).round(3).tolist(),
            )
        ],
    }
    links = []
    for i in range(7):
        cs = [
            CapsuleSpec(n, float(r), list(map(float, a)), list(map(float, b)))
            for n, r, a, b in caps.get(i, [])
        ]
        com = (
            (0.5 * (np.array(cs[0].a_mm) + np.array(cs[0].b_mm))).round(1).tolist() if cs else [0.0, 0.0, 0.0]
        )
        links.append(LinkSpec(index=i, mass_kg=float(size.masses[i]), com_mm=com, capsules=cs))
    return links


def work_target(cell: Cell) -> np.ndarray:
    """SPEC's working point: 100 mm above the top of the cabin axis point nearest the robot [mm]."""
    cab = next((o for o in cell.obstacles if o.name == cell.work_cabin_obstacle), None)
    if cab is None:
        raise ValueError(f"cell has no obstacle named {cell.work_cabin_obstacle!r}")
    d = cab.b - cab.a
    t = np.clip(-(cab.a @ d) / (d @ d), 0.0, 1.0)  # nearest to the origin (the robot's base)
    p = cab.a + t * d
    return p + np.array([0.0, 0.0, cab.radius + cell.work_height_above_cabin])


def solve_q_work(
    robot: Robot, cell: Cell, *, seed: int = 0, n_starts: int = 30, min_clearance_mm: float = 20.0
) -> tuple[np.ndarray, float, float]:
    """The working configuration of SPEC by Drake inverse kinematics.

    Reflector at :func:`work_target`; reflector axis as close as possible to the line of sight to
    the tracker (AngleBetweenVectorsCost); joint limits; at least ``min_clearance_mm`` between the
    robot and every obstacle and checked self pair (MinimumDistanceLowerBoundConstraint).

    Returns:
        q: (6,) [rad]; the incidence angle [rad]; the position error [mm].

    Raises:
        RuntimeError: if no start converges.
    """
    scene = build_scene(robot, cell)
    plant = scene.plant
    target = work_target(cell)
    los = cell.p_WT - target
    los /= np.linalg.norm(los)
    rng = np.random.default_rng(seed)
    best = None
    flange = scene.bodies[6].body_frame()
    for _ in range(n_starts):
        ik = InverseKinematics(plant, scene.plant_context)
        ik.AddPositionConstraint(
            flange, cell.p_FQ * MM, plant.world_frame(), target * MM - 1e-4, target * MM + 1e-4
        )
        ik.AddAngleBetweenVectorsCost(plant.world_frame(), los, flange, [0.0, 0.0, 1.0], 1.0)
        ik.AddMinimumDistanceLowerBoundConstraint(min_clearance_mm * MM, 0.1)
        q0 = rng.uniform(robot.lower, robot.upper)
        q0[3:] = rng.uniform(-0.5, 0.5, 3)
        res = Solve(ik.prog(), q0)
        if not res.is_success():
            continue
        q = res.GetSolution(ik.q())
        fr = forward_kinematics(robot, q)
        zf = fr.R[0, 6][:, 2]
        ang = float(np.arccos(np.clip(zf @ los, -1, 1)))
        p = fr.o[0, 6] + fr.R[0, 6] @ cell.p_FQ
        err = float(np.linalg.norm(p - target))
        key = (ang, float(np.abs(q[3:]).sum()))
        if best is None or key < best[0]:
            best = (key, q, ang, err)
    if best is None:
        raise RuntimeError(f"{robot.name}: no inverse-kinematics start reached the working point {target}")
    return best[1], best[2], best[3]
