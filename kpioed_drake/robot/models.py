"""Robot and cell descriptions: typed dataclasses loaded from the YAML files under ``models/``.

The single source of truth for geometry: the numpy kinematics (:mod:`kpioed_drake.robot.kinematics`)
and the Drake MultibodyPlant (:mod:`kpioed_drake.robot.plant`) are both built from a :class:`Robot`
and a :class:`Cell`; nothing else holds link lengths or obstacle positions.

Files use millimetres and degrees (``models/README.md``); loaded objects hold millimetres and radians.

Conventions (SPEC): classic Denavit-Hartenberg
``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; Hayati for nearly parallel joints
``T_i = Rz(theta_i + q_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``.
"""

import dataclasses
import functools
from collections.abc import Iterable

import numpy as np
from pydrake.math import RollPitchYaw

from kpioed_drake.errors import InputError
from kpioed_drake.robot import chain as chainmod
from kpioed_drake.robot.cell import Cell, Obstacle, cell_from_spec, load_cell, vec3  # noqa: F401 (re-exported)
from kpioed_drake.robot.jointmap import JointMap, joint_map_from_spec
from kpioed_drake.robot.modelspec import (  # noqa: F401 (the file schemas and locations, re-exported)
    MODELS_DIR,
    CapsuleSpec,
    CellSpec,
    EffectSpec,
    JointSpec,
    LinkSpec,
    ObstacleSpec,
    RobotSpec,
    checked_effects,
    list_robots,
    load_yaml_typed,
    rated_payload,
    robot_path,
    shared_fields,
    spec_joint_names,
)
from kpioed_drake.robot.reference import Reference, estimated_errors, reference_of
from kpioed_drake.robot.urdf import UrdfSource, read_urdf_robot

N_JOINTS = 6
"""Joints of the DH/Hayati YAML robots (a URDF robot has its own count: ``robot.n_joints``)."""


# Loaded, typed objects (millimetres and radians)
@dataclasses.dataclass(frozen=True)
class Capsule:
    """A capsule attached to ``frame`` (-1 = world, 0 = base, i = link i) [mm]."""

    name: str
    """The capsule's name (collision reports name it)."""
    frame: int
    """The frame it is fixed in: -1 world, 0 base, i link i."""
    radius: float
    """[mm]"""
    a: np.ndarray  # (3,) [mm] in the frame
    b: np.ndarray  # (3,) [mm]


def joint_param_names(conventions: Iterable[str]) -> list[str]:
    """Names of the joint parameters of rows of these conventions, e.g. ``theta1, d1, a1, alpha1``."""
    names = []
    for i, conv in enumerate(conventions, start=1):
        kinds = ("theta", "d", "a", "alpha") if conv == "dh" else ("theta", "a", "alpha", "beta")
        names += [f"{k}{i}" for k in kinds]
    return names


@dataclasses.dataclass(frozen=True)
class Robot:
    """A serial robot (internal units: mm, rad): a six-joint DH/Hayati table or a URDF chain.

    Attributes:
        name: model name, e.g. ``kr16`` or ``notional-850-800``.
        conventions: (n_joints,) ``"dh"`` or ``"hayati"`` per joint of a table robot;
            ``"revolute"`` or ``"prismatic"`` per joint of a chain (URDF) robot.
        geometry: (n_joints, per_joint) nominal kinematic parameters per joint, in the joint's own
            order: DH ``(theta, d, a, alpha)``, Hayati ``(theta, a, alpha, beta)`` [rad, mm]; a
            chain's seven error parameters (:mod:`kpioed_drake.robot.chain`), nominally 0.
        lower, upper: (n_joints,) joint limits [rad] (prismatic joints: [mm]).
        capsules: link collision capsules (frames 0..n_joints).
        masses: (n_joints + 1,) link masses [kg] (index 0 = base).
        coms: (n_joints + 1, 3) centres of mass in the link frames [mm].
        self_pairs: link index pairs checked against each other.
        beam_links: links the laser beam must not touch.
        q_work: (n_joints,) working configuration [rad, mm], or None.
        car_shift_x: moves the car obstacles along x [mm].
        joint_names: the joints' names.
        source: the model file.
        p_FQ: (3,) reflector offset in the flange frame [mm] overriding the cell's, or None.
        targets: (T, 3) offsets of several targets in the flange frame [mm] (target 1 = ``p_FQ``),
            or None (one target: the reflector).
        target_links: (T,) the link frame each target is fixed in (1..n_joints; a tree robot's
            targets on several links, :attr:`chain` ``.parent``), or None (all on the flange).
        X_WT: tracker pose ``(p_WT (3,) [mm], R_WT (3, 3))`` overriding the cell's, or None.
        joint_map: controller angles to model angles, or None (identity).
        extra_gauge: parameter names held at nominal besides SPEC's gauge.
        chain: the nominal joint frames of a chain (URDF) robot, None for a table robot.
        gauge: the parameters held at nominal (None: SPEC's gauge of the six-joint tables; a
            chain robot's is chosen by :func:`kpioed_drake.robot.chain.auto_gauge`).
        urdf: for a URDF robot, what :mod:`kpioed_drake.robot.plant` needs to parse it (None otherwise).
        compliant_base: the model file says the base or floor is compliant (``compliant_base:
            true``): ``base_compliance`` is a diagnosis candidate.
        rated_payload_kg: the payload the robot may carry [kg] (``rated_payload_kg``), or None.
        drives: per joint its drive type (``drive``, ``drives``: gear, harmonic, cable, belt;
            :mod:`kpioed_drake.robot.drivetrain`); empty: every joint a gear.
        effects: an extended model file's effects (``effects:``; :func:`kpioed_drake.effects.model_effects`).
        effects_where: the file holding ``effects`` (for messages).
        gravity_bases: ``((effect name, D, V), ...)`` mass-free gravity bases sized on a data set's
            poses (:func:`kpioed_drake.effects.gravity_basis.size_on_poses`), else the reference one.
        estimated_errors: (n_joints, per_joint) a calibrated file's errors of its rows against the
            model its calibration started from [rad, mm], or None (:mod:`kpioed_drake.robot.reference`).
        payload_point: (3,) where a payload acts in the flange frame [mm] for the effects' gravity
            torques (``payload_point_mm``), or None: at the reflector.
        R_FP: (3, 3) a 6-DoF probe's orientation on the flange (``probe_rpy_deg``), or None.
    """

    name: str
    conventions: tuple[str, ...]
    geometry: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    capsules: tuple[Capsule, ...]
    masses: np.ndarray
    coms: np.ndarray
    self_pairs: tuple[tuple[int, int], ...]
    beam_links: tuple[int, ...]
    q_work: np.ndarray | None
    car_shift_x: float = 0.0
    joint_names: tuple[str, ...] = ("A1", "A2", "A3", "A4", "A5", "A6")
    source: str = ""
    p_FQ: np.ndarray | None = None
    X_WT: tuple[np.ndarray, np.ndarray] | None = None
    joint_map: JointMap | None = None
    extra_gauge: tuple[str, ...] = ()
    chain: chainmod.Chain | None = None
    gauge: tuple[str, ...] | None = None
    urdf: UrdfSource | None = None
    targets: np.ndarray | None = None
    compliant_base: bool = False
    rated_payload_kg: float | None = None
    effects: tuple[EffectSpec, ...] = ()
    effects_where: str = ""
    gravity_bases: tuple = ()
    target_links: np.ndarray | None = None
    drives: tuple[str, ...] = ()
    estimated_errors: np.ndarray | None = None
    payload_point: np.ndarray | None = None
    R_FP: np.ndarray | None = None

    @functools.cached_property
    def reference(self) -> Reference | None:
        """The geometry an extended model's effects are evaluated on, the model its calibration
        started from (:func:`kpioed_drake.robot.reference.reference_of`); None: this robot's own."""
        return reference_of(self)

    @functools.cached_property
    def pose_gauge(self) -> tuple[str, ...] | None:
        """The gauge of a chain robot whose data hold a 6-DoF probe's orientations too
        (:func:`kpioed_drake.robot.chain.auto_gauge` with ``orientation``), chosen as its
        :attr:`gauge` is; None for a table robot (SPEC's gauge holds for points and poses alike).

        Raises:
            InputError: the chain is degenerate (the rank test's tracker or target columns dependent).
        """
        if self.chain is None:
            return None
        p = chainmod.GENERIC_REFLECTOR if self.targets is None and self.p_FQ is None else self.target_points
        try:
            return chainmod.auto_gauge(
                self.chain,
                self.lower,
                self.upper,
                p,
                joint_map=self.joint_map,
                links=self.target_links,
                orientation=True,
            )
        except ValueError as exc:
            raise InputError(
                f"{self.source or self.name}: automatic gauge with orientations: {exc}"
            ) from None

    @property
    def target_points(self) -> np.ndarray:
        """(T, 3) the targets' offsets [mm] (:attr:`targets`, else the reflector :attr:`p_FQ`)."""
        return np.atleast_2d(self.targets if self.targets is not None else self.p_FQ)

    @property
    def n_targets(self) -> int:
        """Targets (reflectors) per pose: the model file's ``targets_mm``, else 1."""
        return 1 if self.targets is None else int(self.targets.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return len(self.conventions)

    @property
    def target_frames(self) -> np.ndarray:
        """(T,) the link frame of every target: :attr:`target_links`, or all on the flange."""
        return np.full(self.n_targets, self.n_joints) if self.target_links is None else self.target_links

    @property
    def tip(self) -> int:
        """The flange's frame: the link of target 1 (the reflector); n_joints for a serial robot."""
        return self.n_joints if self.target_links is None else int(self.target_links[0])

    @property
    def per_joint(self) -> int:
        """Kinematic parameters per joint: 4 (DH/Hayati) or 7 (chain)."""
        return chainmod.PER_JOINT if self.chain is not None else 4

    @property
    def prismatic(self) -> np.ndarray:
        """(n_joints,) True for prismatic joints (their q in mm)."""
        return np.array([c == "prismatic" for c in self.conventions], dtype=bool)

    def param_names(self) -> list[str]:
        """Names of the joint parameters in storage order, e.g. ``theta1, d1, a1, alpha1``."""
        if self.chain is not None:
            return chainmod.param_names(self.n_joints)
        return joint_param_names(self.conventions)

    def param_is_angle(self) -> list[bool]:
        """Per joint parameter: True for an angle [rad], False for a length [mm]."""
        if self.chain is not None:
            return chainmod.param_is_angle(self.chain)
        return [n.startswith(("theta", "alpha", "beta")) for n in self.param_names()]

    @property
    def reach(self) -> float:
        """Nominal reach [mm]: a1 + a2 + sqrt(d4^2 + a3^2) (SPEC's check); for a chain the sum of
        the distances between successive joint frames (joint 1's placement, the base, excluded)."""
        if self.chain is not None:
            return float(np.sum(np.linalg.norm(self.chain.p_PJ[1:], axis=1)))
        g = self.geometry
        a = [g[i, 2] if c == "dh" else g[i, 1] for i, c in enumerate(self.conventions)]
        d4 = g[3, 1] if self.conventions[3] == "dh" else 0.0
        return float(abs(a[0]) + abs(a[1]) + np.hypot(d4, a[2]))


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------
def _joint_table(spec: RobotSpec, where: str):
    """The joint rows' conventions, geometry (6, 4) [rad, mm] and limits lower, upper (6,) [rad]."""
    if len(spec.joints) != N_JOINTS:
        raise InputError(f"{where}: 'joints' must have {N_JOINTS} rows, got {len(spec.joints)}")
    conv, geom, lo, up = [], np.zeros((N_JOINTS, 4)), np.zeros(N_JOINTS), np.zeros(N_JOINTS)
    for i, j in enumerate(spec.joints):
        w = f"{where}: joints[{i}]"
        if j.convention not in ("dh", "hayati"):
            raise InputError(f"{w}: convention must be 'dh' or 'hayati', got {j.convention!r}")
        conv.append(j.convention)
        th, al, be = np.deg2rad([j.theta_deg, j.alpha_deg, j.beta_deg])
        geom[i] = (th, j.d_mm, j.a_mm, al) if j.convention == "dh" else (th, j.a_mm, al, be)
        if not (np.isfinite(j.lower_deg) and np.isfinite(j.upper_deg) and j.lower_deg < j.upper_deg):
            raise InputError(
                f"{w}: lower_deg and upper_deg must be finite with lower_deg < upper_deg, "
                f"got {j.lower_deg!r}, {j.upper_deg!r}"
            )
        lo[i], up[i] = np.deg2rad([j.lower_deg, j.upper_deg])
    if conv[0] != "dh":
        raise InputError(f"{where}: joint 1 must use the 'dh' convention")
    if not np.all(np.isfinite(geom)):
        raise InputError(f"{where}: kinematic table has a non-finite value")
    return conv, geom, lo, up


def _links(spec: RobotSpec, where: str):
    """The links' capsules (list of :class:`Capsule`), masses (7,) [kg], centres of mass (7, 3) [mm]."""
    caps, masses, coms = [], np.zeros(N_JOINTS + 1), np.zeros((N_JOINTS + 1, 3))
    seen = set()
    for k, link in enumerate(spec.links):
        w = f"{where}: links[{k}]"
        if not 0 <= link.index <= N_JOINTS or link.index in seen:
            raise InputError(f"{w}: index must be a unique integer in 0..6, got {link.index}")
        seen.add(link.index)
        if not (np.isfinite(link.mass_kg) and link.mass_kg >= 0):
            raise InputError(f"{w}: mass_kg must be a finite number >= 0, got {link.mass_kg!r}")
        masses[link.index] = link.mass_kg
        coms[link.index] = vec3(link.com_mm, f"{w}.com_mm")
        for c, cap in enumerate(link.capsules):
            wc = f"{w}.capsules[{c}]"
            if not (np.isfinite(cap.radius_mm) and cap.radius_mm > 0):
                raise InputError(f"{wc}: radius_mm must be a finite number > 0, got {cap.radius_mm!r}")
            a, b = vec3(cap.a_mm, f"{wc}.a_mm"), vec3(cap.b_mm, f"{wc}.b_mm")
            name = cap.name or f"link{link.index}_{c}"
            caps.append(Capsule(name, link.index, float(cap.radius_mm), a, b))
    return caps, masses, coms


def _link_pairs(spec: RobotSpec, where: str) -> list[tuple[int, int]]:
    """The self-collision pairs (lower link first), after checking them and the beam links."""
    pairs = []
    for pr in spec.self_collision_pairs:
        if len(pr) != 2 or not all(0 <= x <= N_JOINTS for x in pr) or abs(pr[0] - pr[1]) < 2:
            raise InputError(f"{where}: self_collision_pairs entry {pr} must be two non-neighbour links")
        pairs.append((int(min(pr)), int(max(pr))))
    bad_beam = [x for x in spec.beam_links if not 0 <= x <= N_JOINTS]
    if bad_beam:
        raise InputError(f"{where}: beam_links must be link indices in 0..{N_JOINTS}, got {bad_beam}")
    return pairs


def _q_work(spec: RobotSpec, where: str, lo: np.ndarray, up: np.ndarray) -> np.ndarray | None:
    """The working configuration (6,) [rad] within the limits ``lo``, ``up`` [rad], or None."""
    q_work = None
    if spec.q_work_deg:
        qw = np.asarray(spec.q_work_deg, dtype=float)
        if qw.shape != (N_JOINTS,) or not np.all(np.isfinite(qw)):
            raise InputError(
                f"{where}: q_work_deg must have {N_JOINTS} finite values, got {spec.q_work_deg!r}"
            )
        q_work = np.deg2rad(qw)
        outside = np.flatnonzero((q_work < lo) | (q_work > up))
        if outside.size:
            i = int(outside[0])
            raise InputError(
                f"{where}: q_work_deg[{i}] = {qw[i]:g} deg is outside joint {i + 1}'s limits "
                f"[{np.rad2deg(lo[i]):g}, {np.rad2deg(up[i]):g}] deg"
            )
    return q_work


def robot_from_spec(spec: RobotSpec, where: str = "robot") -> Robot:
    """Validate a :class:`RobotSpec` and convert it to a :class:`Robot` (mm, rad)."""
    conv, geom, lo, up = _joint_table(spec, where)
    caps, masses, coms = _links(spec, where)
    pairs = _link_pairs(spec, where)
    q_work = _q_work(spec, where, lo, up)
    if not np.isfinite(spec.car_shift_x_mm):
        raise InputError(f"{where}: car_shift_x_mm must be finite, got {spec.car_shift_x_mm!r}")
    p_FQ = (
        vec3(spec.reflector_position_mm, f"{where}: reflector_position_mm")
        if spec.reflector_position_mm
        else None
    )
    targets = _targets(spec, where, p_FQ)
    p_FQ = p_FQ if targets is None else targets[0]
    X_WT = None
    if spec.tracker_position_mm or spec.tracker_rpy_deg:
        if not spec.tracker_position_mm:
            raise InputError(f"{where}: tracker_rpy_deg needs tracker_position_mm")
        rpy = np.deg2rad(vec3(spec.tracker_rpy_deg or [0.0, 0.0, 0.0], f"{where}: tracker_rpy_deg"))
        X_WT = (
            vec3(spec.tracker_position_mm, f"{where}: tracker_position_mm"),
            RollPitchYaw(rpy).ToRotationMatrix().matrix(),
        )
    bad = sorted(set(spec.extra_gauge) - set(joint_param_names(conv)))
    if bad:
        raise InputError(f"{where}: extra_gauge names {bad} that are not joint parameters of this table")
    names = spec_joint_names(spec)
    joint_map = joint_map_from_spec(spec.joint_map, where, joint_names=names)
    table = dict(name=spec.name, conventions=tuple(conv), geometry=geom, lower=lo, upper=up)
    links = dict(capsules=tuple(caps), masses=masses, coms=coms, self_pairs=tuple(pairs), q_work=q_work)
    frames = dict(p_FQ=p_FQ, X_WT=X_WT, targets=targets, joint_names=names, joint_map=joint_map)
    return Robot(**table, **links, **frames, source=where, **shared_fields(spec, where, names))


def _targets(spec: RobotSpec, where: str, p_FQ: np.ndarray | None) -> np.ndarray | None:
    """(T, 3) target offsets of ``targets_mm`` [mm], or None when the file has none.

    Raises:
        InputError: a target that is not three finite numbers, or a ``reflector_position_mm`` that
            differs from target 1.
    """
    if not spec.targets_mm:
        return None
    targets = np.array([vec3(t, f"{where}: targets_mm[{k}]") for k, t in enumerate(spec.targets_mm)])
    if p_FQ is not None and not np.allclose(p_FQ, targets[0], rtol=0.0, atol=1e-9):
        raise InputError(
            f"{where}: reflector_position_mm {p_FQ.tolist()} differs from targets_mm[0] "
            f"{targets[0].tolist()}: target 1 is the reflector (give one of them, or equal values)"
        )
    return targets


def load_robot(name: str) -> Robot:
    """Load a robot by model name (``kr16``, ``notional-850-800``) or from a YAML or URDF file path
    (a URDF with its optional sidecar ``<name>.kpioed.yaml``, :mod:`kpioed_drake.robot.urdf`).

    Raises:
        InputError: unknown robot, or a malformed file (the message names the file and field).
    """
    path = robot_path(name)
    if path.suffix == ".urdf":
        fields = read_urdf_robot(path, load_yaml=load_yaml_typed)
        caps = tuple(Capsule(*c) for c in fields.pop("capsules"))
        rows, where = fields.pop("estimated_errors"), fields["effects_where"]
        robot = Robot(capsules=caps, **fields)
        return dataclasses.replace(robot, estimated_errors=estimated_errors(robot, rows, where))
    if not path.is_file():
        known = ", ".join(n for n in list_robots() if not n.startswith("notional-"))
        raise InputError(
            f"unknown robot {name!r}: no file {path} (known: {known}, notional-<lambda>-<mu> with "
            "lambda in 650..1100 and mu in 600..1000 in steps of 50, or a path to a .yaml file)"
        )
    spec = load_yaml_typed(path, RobotSpec)
    robot = robot_from_spec(spec, where=str(path))
    if not robot.name:
        robot = dataclasses.replace(robot, name=path.stem)
    return dataclasses.replace(
        robot, estimated_errors=estimated_errors(robot, spec.estimated_errors, str(path))
    )
