"""The robot and the measuring cell as a Drake MultibodyPlant + SceneGraph.

Built from the same :class:`~kpioed_drake.robot.models.Robot` and :class:`~kpioed_drake.robot.models.Cell` as
the numpy kinematics. Body ``link{i}`` carries DH frame i; joint ``A{i}`` turns about z of frame
i-1 so that ``X_{i-1,i} = Rz(theta_i) Rz(q_i) X_rest`` reproduces the DH / Hayati transform. Link
capsules are collision geometry (Drake's Capsule is centred on its frame's z axis); the floor and
the wall are large boxes (Drake has no HalfSpace-Capsule distance for double), the mount and the
car are capsules on the world body.

Collision filtering: every robot-robot pair is filtered except the robot model's
``self_collision_pairs``; moving links are checked against every obstacle. Base geometry sits on the
world body and is therefore only checked against moving links listed with link 0.

A URDF robot (:mod:`kpioed_drake.robot.urdf`) is the plant Drake's ``Parser`` makes of its file (its
inertias; our capsules as collision geometry); body ``i`` is the child link of the i-th movable
joint, and prismatic joint values are metres in the plant (:attr:`Scene.q_scale`).

Units: Drake uses metres; our files and numpy code use millimetres (factor :data:`MM`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    CollisionFilterDeclaration,
    GeometrySet,
    QueryObject,
    SceneGraph,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, RevoluteJoint, SpatialInertia, UnitInertia
from pydrake.systems.framework import Context, Diagram, DiagramBuilder

from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.urdf import add_urdf, movable_joints

MM = 1e-3
"""Metres per millimetre."""

_SIZE, _THICK = 12.0, 4.0  # [m] extent and thickness of the floor and wall boxes


def _rest_transform(conv: str, row: np.ndarray) -> RigidTransform:
    """Constant part of the joint transform after ``Rz(theta + q)`` (mm -> m)."""
    if conv == "dh":
        _, d, a, alpha = row
        return RigidTransform(RotationMatrix.MakeXRotation(alpha), [a * MM, 0.0, d * MM])
    _, a, alpha, beta = row
    R = RotationMatrix.MakeXRotation(alpha).multiply(RotationMatrix.MakeYRotation(beta))
    return RigidTransform(R, [a * MM, 0.0, 0.0])


def capsule_pose(a: np.ndarray, b: np.ndarray) -> tuple[RigidTransform, float]:
    """Pose of a Drake Capsule frame (z along the axis, centred) for end points a, b [mm].

    Returns the pose in metres and the cylinder length [m].
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    R = RotationMatrix.MakeFromOneVector(z, 2)
    return RigidTransform(R, 0.5 * (a + b) * MM), length * MM


@dataclasses.dataclass
class Scene:
    """A built diagram and handles into it.

    Attributes:
        diagram, plant, scene_graph: the Drake systems.
        context: root diagram context; ``plant_context`` is the plant's sub-context.
        bodies: (nj + 1,) body of each link (index 0 = world body).
        geometry_names: collision geometry id -> our capsule / obstacle name.
        geometry_link: geometry id -> link index (0..nj) or -1 for obstacles.
        q_scale: (nj,) plant position per unit of q (1 for revolute joints, 1e-3 m/mm prismatic).
        q_index: (nj,) position index of each joint in the plant's position vector.
    """

    diagram: Diagram
    plant: MultibodyPlant
    scene_graph: SceneGraph
    context: Context
    plant_context: Context
    bodies: list
    geometry_names: dict
    geometry_link: dict
    q_scale: np.ndarray
    q_index: np.ndarray

    def positions(self, q: np.ndarray) -> np.ndarray:
        """The plant's position vector of joint values ``q`` (nj,) [rad, mm]; the plant's other
        joints (branches, a floating base) at their default positions."""
        x = self.plant.GetDefaultPositions()  # a held joint (a free base) at its default pose
        x[self.q_index] = np.asarray(q, dtype=float) * self.q_scale
        return x

    def set_q(self, q: np.ndarray) -> None:
        """Set the joint values [rad; mm for prismatic joints]."""
        self.plant.SetPositions(self.plant_context, self.positions(q))

    def query_object(self) -> QueryObject:
        """The scene graph's query object at the current joint values."""
        return self.plant.get_geometry_query_input_port().Eval(self.plant_context)

    def X_WB(self, i: int) -> RigidTransform:
        """Pose of link i's DH frame in W (metres)."""
        return self.plant.EvalBodyPoseInWorld(self.plant_context, self.bodies[i])


def build_scene(robot: Robot, cell: Cell | None = None, *, gravity: bool = True) -> Scene:
    """MultibodyPlant + SceneGraph of ``robot`` (and the cell's obstacles, if ``cell`` is given).

    Link masses and centres of mass come from the robot model (used for gravity torques); a URDF
    robot's inertias from its file.
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    if robot.urdf is not None:
        inst = add_urdf(plant, robot.urdf)
        bodies = [plant.world_body()] + [j.child_body() for j in movable_joints(plant, inst, robot.urdf)]
    else:
        bodies = _add_table_robot(plant, robot)
    return _finish(builder, plant, scene_graph, robot, cell, bodies)


def _add_table_robot(plant: MultibodyPlant, robot: Robot) -> list:
    """Bodies and revolute joints of a DH/Hayati robot; returns the bodies (world first)."""
    inst = plant.AddModelInstance(robot.name or "robot")
    bodies = [plant.world_body()]
    for i in range(1, robot.n_joints + 1):
        m = max(float(robot.masses[i]), 1e-6)
        com = robot.coms[i] * MM
        M = SpatialInertia(m, com, UnitInertia.SolidSphere(0.05).ShiftFromCenterOfMass(-com))
        bodies.append(plant.AddRigidBody(f"link{i}", inst, M))
    for i in range(robot.n_joints):
        parent = bodies[i].body_frame()
        theta = float(robot.geometry[i, 0])
        F = plant.AddFrame(
            FixedOffsetFrame(f"A{i + 1}_parent", parent, RigidTransform(RotationMatrix.MakeZRotation(theta)))
        )
        X_CM = _rest_transform(robot.conventions[i], robot.geometry[i]).inverse()
        M = plant.AddFrame(FixedOffsetFrame(f"A{i + 1}_child", bodies[i + 1].body_frame(), X_CM))
        plant.AddJoint(
            RevoluteJoint(f"A{i + 1}", F, M, [0.0, 0.0, 1.0], float(robot.lower[i]), float(robot.upper[i]))
        )
    return bodies


def _finish(builder, plant, scene_graph, robot: Robot, cell: Cell | None, bodies: list) -> Scene:
    """Collision geometry, filters and the built diagram (see :func:`build_scene`)."""
    friction = CoulombFriction(0.5, 0.5)
    names, links = {}, {}
    robot_ids = {i: [] for i in range(robot.n_joints + 1)}
    for c in robot.capsules:
        X, length = capsule_pose(c.a, c.b)
        gid = plant.RegisterCollisionGeometry(
            bodies[c.frame], X, Capsule(c.radius * MM, length), c.name, friction
        )
        names[gid], links[gid] = c.name, c.frame
        robot_ids[c.frame].append(gid)
    obstacle_ids = []
    if cell is not None:
        world = plant.world_body()
        for name, X, shape in (
            ("floor", RigidTransform([0, 0, cell.floor_z * MM - _THICK / 2]), Box(_SIZE, _SIZE, _THICK)),
            ("wall", RigidTransform([cell.wall_x * MM - _THICK / 2, 0, 0]), Box(_THICK, _SIZE, _SIZE)),
        ):
            gid = plant.RegisterCollisionGeometry(world, X, shape, name, friction)
            names[gid], links[gid] = name, -1
            obstacle_ids.append(gid)
        for ob in cell.obstacles:
            X, length = capsule_pose(ob.a, ob.b)
            gid = plant.RegisterCollisionGeometry(
                world, X, Capsule(ob.radius * MM, length), ob.name, friction
            )
            names[gid], links[gid] = ob.name, -1
            obstacle_ids.append(gid)
    plant.Finalize()
    # Collision filters: nothing robot-robot except the declared self pairs.
    all_robot = [g for ids in robot_ids.values() for g in ids]
    manager = scene_graph.collision_filter_manager()
    manager.Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(all_robot)))
    for i, j in robot.self_pairs:
        if robot_ids[i] and robot_ids[j]:
            manager.Apply(
                CollisionFilterDeclaration().AllowBetween(
                    GeometrySet(robot_ids[i]), GeometrySet(robot_ids[j])
                )
            )
    moving = [g for i, ids in robot_ids.items() if i >= 1 for g in ids]
    if obstacle_ids and moving:
        manager.Apply(
            CollisionFilterDeclaration().AllowBetween(GeometrySet(obstacle_ids), GeometrySet(moving))
        )
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    q_scale = np.where(robot.prismatic, MM, 1.0)
    if robot.urdf is not None:
        q_index = np.array([plant.GetJointByName(n).position_start() for n in robot.urdf.joints])
    else:
        q_index = np.arange(robot.n_joints)
    return Scene(diagram, plant, scene_graph, context, plant_context, bodies, names, links, q_scale, q_index)
