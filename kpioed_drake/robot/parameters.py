"""The parameter vector ``p`` of the measurement model: its layout, names, units and estimated subset.

Paper eq. (3) writes the measurement ``h(p, q)`` as a function of one parameter vector; this module
says where each parameter sits in it, so that no other module slices it by number. For a robot of
``n_joints`` joints with ``per_joint`` kinematic parameters each and ``n_targets`` reflectors, the
vector is, in this order:

- the joint rows, joint-major, each joint in its own convention's order (DH ``theta, d, a, alpha``;
  Hayati ``theta, a, alpha, beta``) [rad, mm]; the first parameter of every row (``theta``) is the
  joint-angle offset, so its column is also the derivative with respect to the joint angle;
- the tracker position ``p_WT`` in W (3) [mm];
- the tracker's three small rotations ``r`` about its axes (3) [rad],
  ``R_WT = R_WT_ref @ Rx(rx) @ Ry(ry) @ Rz(rz)``;
- the target (reflector) offsets ``p_FQ`` in the flange frame F, 3 per target [mm];
- only when the data have a 6-DoF probe's orientations (``ParameterLayout.probe``): the probe's
  three small rotations ``r_FP`` on the flange (3) [rad], ``R_FP = Rx(rx) Ry(ry) Rz(rz) @ R_FP_ref``
  (:mod:`kpioed_drake.tracker.orientation`); its position is target 0's offset.

For the six-joint robots with one reflector that is 24 + 3 + 3 + 3 = 33 parameters. The gauge
parameters (SPEC: theta1, d1 against the tracker pose; theta6, d6, a6, alpha6 against the reflector
offset) trade exactly against others and are held at their nominal values; the others are *free*
(estimated): 27. Effect parameters (:mod:`kpioed_drake.effects`) come after the free geometric ones
in an estimation's unknown vector: ``n_effects`` of them.

With a probe's orientations the gauge is the same for the six-joint tables (the last joint's four
parameters trade against the probe's full pose on the flange just as against a point), but a model
file's ``extra_gauge`` (parameters a point on joint 6's axis leaves undetermined) is not applied:
the orientation rows determine them, and the rank test of the data holds what they do not; a chain
robot's automatic gauge is chosen on positions and orientations
(:attr:`kpioed_drake.robot.models.Robot.pose_gauge`).

Distance and plane-contact measurements (:mod:`kpioed_drake.tracker.contacts`) append their own
parameters after all of these (:class:`ContactLayout`, ``ParameterLayout.contacts``): a length
correction per bar ``bar{b}_dL`` [mm], a pivot's position ``pivot{c}_x, _y, _z`` in W [mm], and per
plane two tilts of its normal ``plane{k}_tx, _ty`` [rad] and its offset ``plane{k}_d`` [mm].

SPEC's scaling of the criteria to millimetres at the tool: lengths 1, angles times the reach.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from kpioed_drake.robot.models import N_JOINTS, Robot

PER_JOINT = 4
"""Kinematic parameters per joint row (DH and Hayati alike)."""
FIXED_NAMES = ("theta1", "d1", "theta6", "d6", "a6", "alpha6")
"""The gauge of the six-joint robots: held at their nominal values."""
TRACKER_POSITION_NAMES = ("tracker_x", "tracker_y", "tracker_z")
TRACKER_ROTATION_NAMES = ("tracker_rx", "tracker_ry", "tracker_rz")
TRACKER_NAMES = TRACKER_POSITION_NAMES + TRACKER_ROTATION_NAMES
REFLECTOR_NAMES = ("reflector_x", "reflector_y", "reflector_z")
PROBE_NAMES = ("probe_rx", "probe_ry", "probe_rz")
"""The probe's small rotations on the flange (a 6-DoF probe's orientations measured)."""
ANGLE_PREFIXES = ("theta", "alpha", "beta", "tracker_r", "probe_r")


@dataclasses.dataclass(frozen=True)
class ContactLayout:
    """The parameters of distance and plane-contact systems, in this order: ``bars`` length
    corrections (1 each) [mm], ``pivots`` positions in W (3 each) [mm], ``planes`` (the normal's two
    tilts [rad] and the offset [mm] each); names 1-based (``bar1_dL``, ``pivot2_x``, ``plane3_tx``)."""

    bars: int = 0
    pivots: int = 0
    planes: int = 0

    @property
    def size(self) -> int:
        return self.bars + 3 * self.pivots + 3 * self.planes

    @property
    def names(self) -> tuple[str, ...]:
        bars = tuple(f"bar{b + 1}_dL" for b in range(self.bars))
        pivots = tuple(f"pivot{c + 1}_{x}" for c in range(self.pivots) for x in "xyz")
        planes = tuple(f"plane{k + 1}_{x}" for k in range(self.planes) for x in ("tx", "ty", "d"))
        return bars + pivots + planes

    @property
    def is_angle(self) -> np.ndarray:
        """(size,) True for the planes' tilts [rad]."""
        return np.array([n.endswith(("_tx", "_ty")) for n in self.names], dtype=bool)


def n_parameters(n_joints: int = N_JOINTS, *, per_joint: int = PER_JOINT, n_targets: int = 1) -> int:
    """Length of the parameter vector: joint rows, tracker pose (6), 3 per target."""
    return n_joints * per_joint + 6 + 3 * n_targets


N_FULL = n_parameters()
"""Length of the parameter vector of a six-joint robot with one reflector (33)."""


def _target_names(n_targets: int) -> tuple[str, ...]:
    if n_targets == 1:
        return REFLECTOR_NAMES
    return tuple(f"{n}{t + 1}" for t in range(n_targets) for n in REFLECTOR_NAMES)


@dataclasses.dataclass(frozen=True)
class ParameterLayout:
    """Where every parameter sits in the vector, its name and unit, and which are estimated.

    Attributes:
        names: (n_full,) parameter names.
        is_angle: (n_full,) True for angles [rad], False for lengths [mm].
        free: (n_free,) indices of the estimated parameters into the full vector, ascending.
        n_joints: joints of the robot.
        per_joint: kinematic parameters per joint row.
        n_targets: reflectors (each 3 offset coordinates in the flange frame).
        n_effects: effect parameters estimated after the free geometric ones (0 for the
            geometric model).
        probe: the vector has the probe's three small rotations (data with orientations).
        contacts: the distance and plane-contact parameters at the end of the vector (none for
            tracker data alone).
    """

    names: tuple[str, ...]
    is_angle: np.ndarray
    free: np.ndarray
    n_joints: int = N_JOINTS
    per_joint: int = PER_JOINT
    n_targets: int = 1
    n_effects: int = 0
    probe: bool = False
    contacts: ContactLayout = ContactLayout()

    # --- segments of the full vector --------------------------------------------------------
    @property
    def size(self) -> int:
        """Length of the full (geometric) vector."""
        return len(self.names)

    @property
    def joints(self) -> slice:
        """The joint rows (``n_joints * per_joint`` entries)."""
        return slice(0, self.n_joints * self.per_joint)

    @property
    def tracker_position(self) -> slice:
        """``p_WT`` [mm]."""
        j = self.joints.stop
        return slice(j, j + 3)

    @property
    def tracker_rotation(self) -> slice:
        """The three small rotations of the tracker frame [rad]."""
        j = self.tracker_position.stop
        return slice(j, j + 3)

    @property
    def tracker(self) -> slice:
        """Tracker position and small rotations (6 entries)."""
        return slice(self.tracker_position.start, self.tracker_rotation.stop)

    @property
    def tracker_names(self) -> frozenset[str]:
        """Names of the tracker pose's six entries."""
        return frozenset(self.names[self.tracker])

    @property
    def targets(self) -> slice:
        """All target offsets (3 per target) [mm]."""
        j = self.tracker_rotation.stop
        return slice(j, j + 3 * self.n_targets)

    @property
    def probe_rotation(self) -> slice:
        """The probe's three small rotations on the flange [rad] (empty without :attr:`probe`)."""
        j = self.targets.stop
        return slice(j, j + (3 if self.probe else 0))

    @property
    def free_probe_rotation(self) -> np.ndarray:
        """Positions of the probe's small rotations in the free vector (empty without a probe)."""
        return self.in_free(self.probe_rotation)

    @property
    def contact(self) -> slice:
        """The distance and plane-contact parameters (:class:`ContactLayout`; empty without them)."""
        j = self.probe_rotation.stop
        return slice(j, j + self.contacts.size)

    def bar_columns(self, bar: np.ndarray) -> np.ndarray:
        """(n,) indices of the length corrections of the (n,) 0-based ``bar`` indices."""
        return self.contact.start + np.asarray(bar, dtype=int)

    def pivot_columns(self, pivot: np.ndarray) -> np.ndarray:
        """(n, 3) indices of the positions of the (n,) 0-based ``pivot`` indices."""
        start = self.contact.start + self.contacts.bars
        return start + 3 * np.asarray(pivot, dtype=int)[:, None] + np.arange(3)

    def plane_columns(self, plane: np.ndarray) -> np.ndarray:
        """(n, 3) indices of (tilt x, tilt y, offset) of the (n,) 0-based ``plane`` indices."""
        start = self.contact.start + self.contacts.bars + 3 * self.contacts.pivots
        return start + 3 * np.asarray(plane, dtype=int)[:, None] + np.arange(3)

    def target(self, t: int = 0) -> slice:
        """Offset ``p_FQ`` of target ``t`` (0-based) [mm]."""
        j = self.targets.start + 3 * t
        return slice(j, j + 3)

    def joint_row(self, joint: int) -> slice:
        """The parameters of ``joint`` (1-based)."""
        return slice(self.per_joint * (joint - 1), self.per_joint * joint)

    def joint_angle(self, joint: int) -> int:
        """Index of the angle offset ``theta`` of ``joint`` (1-based); its column is dh/dq_joint."""
        return self.per_joint * (joint - 1)

    @property
    def joint_angles(self) -> slice:
        """Indices of every joint's angle offset, as a slice of the full vector."""
        return slice(0, self.joints.stop, self.per_joint)

    def geometry_shape(self) -> tuple[int, int]:
        """Shape of the joint rows as a table: ``(n_joints, per_joint)``."""
        return (self.n_joints, self.per_joint)

    # --- the free (estimated) subset ---------------------------------------------------------
    @property
    def free_names(self) -> list[str]:
        return [self.names[i] for i in self.free]

    @property
    def n_free(self) -> int:
        """Estimated geometric parameters (27 for the six-joint robots)."""
        return int(self.free.size)

    @property
    def n_unknowns(self) -> int:
        """Estimated geometric plus effect parameters."""
        return self.n_free + self.n_effects

    def in_free(self, segment: slice) -> np.ndarray:
        """Positions in the free vector of the free parameters of a segment of the full vector."""
        idx = np.arange(self.size)[segment]
        return np.flatnonzero(np.isin(self.free, idx))

    @property
    def free_tracker_position(self) -> np.ndarray:
        """Positions of ``p_WT`` in the free vector."""
        return self.in_free(self.tracker_position)

    @property
    def free_tracker_rotation(self) -> np.ndarray:
        """Positions of the tracker's small rotations in the free vector."""
        return self.in_free(self.tracker_rotation)

    def free_target(self, t: int = 0) -> np.ndarray:
        """Positions of target ``t``'s offset in the free vector."""
        return self.in_free(self.target(t))

    @property
    def effects(self) -> slice:
        """The effect parameters in the unknown vector (after the free geometric ones)."""
        return slice(self.n_free, self.n_free + self.n_effects)

    @property
    def free_robot_side(self) -> np.ndarray:
        """Full-vector indices of the free joint and target parameters (the tracker and the
        contact parameters excluded)."""
        idx = np.arange(self.size)
        return self.free[~np.isin(self.free, np.concatenate([idx[self.tracker], idx[self.contact]]))]

    def with_effects(self, n_effects: int) -> ParameterLayout:
        """The same layout with ``n_effects`` effect parameters after the free ones."""
        return dataclasses.replace(self, n_effects=int(n_effects))

    def scale(self, reach: float) -> np.ndarray:
        """(n_free,) SPEC's scaling to millimetres at the tool: lengths 1, angles times the reach [mm]."""
        return np.where(self.is_angle[self.free], reach, 1.0)


def default_fixed(robot: Robot, *, probe: bool = False) -> tuple[str, ...]:
    """The robot's gauge: SPEC's :data:`FIXED_NAMES` for the six-joint tables, the automatic gauge
    (:func:`kpioed_drake.robot.chain.auto_gauge`) of a chain robot (``robot.gauge``; with a
    probe's orientations ``robot.pose_gauge``, chosen on positions and orientations)."""
    if robot.gauge is None:
        return FIXED_NAMES
    return tuple(robot.pose_gauge) if probe else tuple(robot.gauge)


def parameter_layout(
    robot: Robot,
    *,
    fixed: tuple[str, ...] | None = None,
    n_targets: int | None = None,
    n_effects: int = 0,
    probe: bool = False,
    contacts: ContactLayout | None = None,
) -> ParameterLayout:
    """The layout of ``robot``'s parameter vector and the indices of the estimated parameters.

    Args:
        robot: the robot; its model file's ``extra_gauge`` names are held at nominal too (e.g. a
            target on joint 6's axis makes theta5 and alpha5 trade against the others).
        fixed: the gauge, the parameters held at nominal (default :func:`default_fixed`).
        n_targets: targets (reflectors) per pose (default: the robot's, ``robot.n_targets``; the
            same gauge holds for any number: the joint-6 parameters trade against all target
            offsets together); n_effects: effect parameters appended.
        probe: append the probe's three small rotations (data with a 6-DoF probe's orientations);
            the model file's ``extra_gauge`` is then not applied (the orientations determine what a
            point on joint 6's axis leaves undetermined) and a chain robot's default gauge is its
            :attr:`~kpioed_drake.robot.models.Robot.pose_gauge`.
        contacts: append the parameters of distance and plane-contact systems (:class:`ContactLayout`).

    Raises:
        ValueError: a fixed name that is not a parameter of the model.
    """
    fixed = (default_fixed(robot, probe=probe) if fixed is None else tuple(fixed)) + (
        () if probe else tuple(robot.extra_gauge)
    )
    n_targets = robot.n_targets if n_targets is None else int(n_targets)
    n_joints = robot.n_joints
    contacts = ContactLayout() if contacts is None else contacts
    names = (
        tuple(robot.param_names()) + TRACKER_NAMES + _target_names(n_targets) + (PROBE_NAMES if probe else ())
    )
    tail = [n.startswith(ANGLE_PREFIXES) for n in names[len(robot.param_names()) :]]
    is_angle = np.array(list(robot.param_is_angle()) + tail + list(contacts.is_angle), dtype=bool)
    names += contacts.names
    unknown = set(fixed) - set(names)
    if unknown:
        raise ValueError(f"fixed parameters not in the model: {sorted(unknown)}")
    free = np.array([i for i, n in enumerate(names) if n not in fixed])
    return ParameterLayout(
        names=names,
        is_angle=is_angle,
        free=free,
        n_joints=n_joints,
        per_joint=robot.per_joint,
        n_targets=n_targets,
        n_effects=n_effects,
        probe=bool(probe),
        contacts=contacts,
    )


_JOINT_PARAMETER = re.compile(r"(?:theta|d|a|alpha|beta|off|px|py|pz|rx|ry|rz)(\d+)")


def parameter_joint(name: str) -> int | None:
    """The 1-based joint of a joint parameter's name (``theta2``, ``px5``), else None (tracker,
    reflector, target and probe parameters)."""
    m = _JOINT_PARAMETER.fullmatch(name)
    return int(m.group(1)) if m else None


def joint_label(robot: Robot, joint: int | None) -> str:
    """The robot's name of joint ``joint`` (1-based) with its index second, e.g. ``A2 (joint 2)`` or
    ``dsr_joint1 (joint 2)``; "" for None."""
    if joint is None or not 1 <= joint <= len(robot.joint_names):
        return ""
    return f"{robot.joint_names[joint - 1]} (joint {joint})"
