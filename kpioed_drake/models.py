"""Robot and cell descriptions: typed dataclasses loaded from the YAML files under ``models/``.

This module is the single source of truth for geometry. The numpy kinematics
(:mod:`kpioed_drake.kinematics`) and the Drake MultibodyPlant (:mod:`kpioed_drake.plant`) are both
built from a :class:`Robot` and a :class:`Cell`; nothing else holds link lengths or obstacle
positions.

Files use millimetres and degrees (see ``models/README.md``). The loaded objects hold millimetres and
radians (numpy arrays), the units used everywhere inside the code.

Conventions (SPEC): classic Denavit-Hartenberg
``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; Hayati for nearly parallel joints
``T_i = Rz(theta_i + q_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``.
"""

import dataclasses
import os
import re
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_load_typed

from kpioed_drake.errors import InputError

MODELS_DIR = Path(os.environ.get("KPIOED_MODELS", Path(__file__).resolve().parents[1] / "models"))
"""Folder holding ``cell.yaml`` and ``robots/*.yaml`` (override with ``KPIOED_MODELS``)."""

N_JOINTS = 6


# ----------------------------------------------------------------------------------------------
# File schemas (what the YAML holds, millimetres and degrees)
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class JointSpec:
    """One row of the kinematic table [mm, deg]."""

    name: str = ""
    convention: str = "dh"  # "dh" or "hayati"
    theta_deg: float = 0.0
    d_mm: float = 0.0  # DH only
    a_mm: float = 0.0
    alpha_deg: float = 0.0
    beta_deg: float = 0.0  # Hayati only
    lower_deg: float = -180.0
    upper_deg: float = 180.0


@dataclasses.dataclass
class CapsuleSpec:
    """A capsule: segment ``a_mm``-``b_mm`` in the owning frame, swept by a sphere of ``radius_mm``."""

    name: str = ""
    radius_mm: float = 0.0
    a_mm: list[float] = dataclasses.field(default_factory=list)
    b_mm: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class LinkSpec:
    """Link ``index`` (0 = base fixed to the world, i = moved by joint i), in DH frame ``index``."""

    index: int = 0
    mass_kg: float = 0.0
    com_mm: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    capsules: list[CapsuleSpec] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class RobotSpec:
    """A robot model file."""

    name: str = ""
    description: str = ""
    sources: str = ""
    joints: list[JointSpec] = dataclasses.field(default_factory=list)
    links: list[LinkSpec] = dataclasses.field(default_factory=list)
    self_collision_pairs: list[list[int]] = dataclasses.field(default_factory=list)
    beam_links: list[int] = dataclasses.field(default_factory=list)
    q_work_deg: list[float] = dataclasses.field(default_factory=list)
    car_shift_x_mm: float = 0.0
    notes: str = ""


@dataclasses.dataclass
class ObstacleSpec:
    """A fixed obstacle capsule in the world frame W [mm]."""

    name: str = ""
    radius_mm: float = 0.0
    a_mm: list[float] = dataclasses.field(default_factory=list)
    b_mm: list[float] = dataclasses.field(default_factory=list)
    moves_with_car: bool = False


@dataclasses.dataclass
class CellSpec:
    """The measuring cell file."""

    description: str = ""
    tracker_position_mm: list[float] = dataclasses.field(default_factory=list)
    tracker_rpy_deg: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    reflector_position_mm: list[float] = dataclasses.field(default_factory=list)
    max_incidence_deg: float = 30.0
    noise_sigma_mm: float = 1.0
    beam_radius_mm: float = 5.0
    floor_z_mm: float = 0.0
    wall_x_mm: float = -450.0
    obstacles: list[ObstacleSpec] = dataclasses.field(default_factory=list)
    work_height_above_cabin_mm: float = 100.0
    work_cabin_obstacle: str = "car_cabin"


# ----------------------------------------------------------------------------------------------
# Loaded, typed objects (millimetres and radians)
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Capsule:
    """A capsule attached to ``frame`` (-1 = world, 0 = base, i = link i) [mm]."""

    name: str
    frame: int
    radius: float
    a: np.ndarray  # (3,) [mm] in the frame
    b: np.ndarray  # (3,) [mm]


@dataclasses.dataclass(frozen=True)
class Robot:
    """A six-axis serial robot (internal units: mm, rad).

    Attributes:
        name: model name, e.g. ``kr16`` or ``notional-850-800``.
        conventions: (6,) ``"dh"`` or ``"hayati"`` per joint.
        geometry: (6, 4) nominal kinematic parameters per joint, in the joint's own order:
            DH ``(theta, d, a, alpha)``, Hayati ``(theta, a, alpha, beta)`` [rad, mm].
        lower, upper: (6,) joint limits [rad].
        capsules: link collision capsules (frames 0..6).
        masses: (7,) link masses [kg] (index 0 = base).
        coms: (7, 3) centres of mass in the link frames [mm].
        self_pairs: link index pairs checked against each other.
        beam_links: links the laser beam must not touch.
        q_work: (6,) working configuration [rad], or None.
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

    def param_names(self) -> list[str]:
        """Names of the 24 joint parameters in storage order, e.g. ``theta1, d1, a1, alpha1``."""
        names = []
        for i, conv in enumerate(self.conventions, start=1):
            kinds = ("theta", "d", "a", "alpha") if conv == "dh" else ("theta", "a", "alpha", "beta")
            names += [f"{k}{i}" for k in kinds]
        return names

    @property
    def reach(self) -> float:
        """Nominal reach [mm]: a1 + a2 + sqrt(d4^2 + a3^2) (SPEC's check)."""
        g = self.geometry
        a = [g[i, 2] if c == "dh" else g[i, 1] for i, c in enumerate(self.conventions)]
        d4 = g[3, 1] if self.conventions[3] == "dh" else 0.0
        return float(abs(a[0]) + abs(a[1]) + np.hypot(d4, a[2]))


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A world-fixed obstacle capsule [mm]."""

    name: str
    radius: float
    a: np.ndarray
    b: np.ndarray
    moves_with_car: bool = False


@dataclasses.dataclass(frozen=True)
class Cell:
    """The measuring cell (internal units: mm, rad).

    Attributes:
        p_WT: (3,) laser tracker position in W [mm].
        R_WT: (3, 3) nominal tracker orientation.
        p_FQ: (3,) reflector (SMR) position in the flange frame [mm].
        max_incidence: largest admitted incidence angle [rad] (paper eq. 4).
        sigma: measurement noise standard deviation per coordinate [mm].
        beam_radius: radius of the laser-beam capsule [mm].
        floor_z, wall_x: floor height and wall position [mm].
        obstacles: fixed capsules (mount, car body, car cabin).
    """

    p_WT: np.ndarray
    R_WT: np.ndarray
    p_FQ: np.ndarray
    max_incidence: float
    sigma: float
    beam_radius: float
    floor_z: float
    wall_x: float
    obstacles: tuple[Obstacle, ...]
    work_height_above_cabin: float = 100.0
    work_cabin_obstacle: str = "car_cabin"


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------
_NOTIONAL = re.compile(r"^notional-(\d+)-(\d+)$")


def _load_yaml(path: Path, schema):
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        return yaml_load_typed(filename=str(path), schema=schema)
    except AssertionError:
        raise InputError(f"{path}: a field that must be a mapping (key: value) is not") from None
    except Exception as exc:  # pydrake raises RuntimeError/ValueError with a terse text
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: {msg}") from None


def _vec3(values, where: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: expected 3 finite numbers, got {values!r}")
    return arr


def robot_path(name: str) -> Path:
    """Path of the model file for ``name`` (a model name or a path to a YAML file)."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        return p
    m = _NOTIONAL.match(name)
    if m:
        return MODELS_DIR / "robots" / "notional" / f"{name}.yaml"
    return MODELS_DIR / "robots" / f"{name}.yaml"


def list_robots() -> list[str]:
    """Names of all robots shipped under ``models/robots``."""
    root = MODELS_DIR / "robots"
    names = sorted(p.stem for p in root.glob("*.yaml"))
    names += sorted(p.stem for p in (root / "notional").glob("notional-*.yaml"))
    return names


def robot_from_spec(spec: RobotSpec, where: str = "robot") -> Robot:
    """Validate a :class:`RobotSpec` and convert it to a :class:`Robot` (mm, rad)."""
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
        if not j.lower_deg < j.upper_deg:
            raise InputError(f"{w}: lower_deg must be below upper_deg")
        lo[i], up[i] = np.deg2rad([j.lower_deg, j.upper_deg])
    if conv[0] != "dh":
        raise InputError(f"{where}: joint 1 must use the 'dh' convention")
    if not np.all(np.isfinite(geom)):
        raise InputError(f"{where}: kinematic table has a non-finite value")
    caps, masses, coms = [], np.zeros(N_JOINTS + 1), np.zeros((N_JOINTS + 1, 3))
    seen = set()
    for k, link in enumerate(spec.links):
        w = f"{where}: links[{k}]"
        if not 0 <= link.index <= N_JOINTS or link.index in seen:
            raise InputError(f"{w}: index must be a unique integer in 0..6, got {link.index}")
        seen.add(link.index)
        if link.mass_kg < 0:
            raise InputError(f"{w}: mass_kg must be >= 0")
        masses[link.index] = link.mass_kg
        coms[link.index] = _vec3(link.com_mm, f"{w}.com_mm")
        for c, cap in enumerate(link.capsules):
            wc = f"{w}.capsules[{c}]"
            if cap.radius_mm <= 0:
                raise InputError(f"{wc}: radius_mm must be > 0")
            a, b = _vec3(cap.a_mm, f"{wc}.a_mm"), _vec3(cap.b_mm, f"{wc}.b_mm")
            name = cap.name or f"link{link.index}_{c}"
            caps.append(Capsule(name, link.index, float(cap.radius_mm), a, b))
    pairs = []
    for pr in spec.self_collision_pairs:
        if len(pr) != 2 or not all(0 <= x <= N_JOINTS for x in pr) or abs(pr[0] - pr[1]) < 2:
            raise InputError(f"{where}: self_collision_pairs entry {pr} must be two non-neighbour links")
        pairs.append((int(min(pr)), int(max(pr))))
    q_work = None
    if spec.q_work_deg:
        if len(spec.q_work_deg) != N_JOINTS:
            raise InputError(f"{where}: q_work_deg must have 6 values")
        q_work = np.deg2rad(np.asarray(spec.q_work_deg, dtype=float))
    return Robot(
        name=spec.name,
        conventions=tuple(conv),
        geometry=geom,
        lower=lo,
        upper=up,
        capsules=tuple(caps),
        masses=masses,
        coms=coms,
        self_pairs=tuple(pairs),
        beam_links=tuple(int(x) for x in spec.beam_links),
        q_work=q_work,
        car_shift_x=float(spec.car_shift_x_mm),
        joint_names=tuple(j.name or f"A{i + 1}" for i, j in enumerate(spec.joints)),
        source=where,
    )


def load_robot(name: str) -> Robot:
    """Load a robot by model name (``kr16``, ``notional-850-800``) or from a YAML file path.

    Raises:
        InputError: unknown robot, or a malformed file (the message names the file and field).
    """
    path = robot_path(name)
    if not path.is_file():
        known = ", ".join(n for n in list_robots() if not n.startswith("notional-"))
        raise InputError(
            f"unknown robot {name!r}: no file {path} (known: {known}, notional-<lambda>-<mu> with "
            "lambda in 650..1100 and mu in 600..1000 in steps of 50, or a path to a .yaml file)"
        )
    spec = _load_yaml(path, RobotSpec)
    robot = robot_from_spec(spec, where=str(path))
    if not robot.name:
        robot = dataclasses.replace(robot, name=path.stem)
    return robot


def cell_from_spec(spec: CellSpec, where: str = "cell") -> Cell:
    """Validate a :class:`CellSpec` and convert it to a :class:`Cell` (mm, rad)."""
    from pydrake.math import RollPitchYaw

    p_WT = _vec3(spec.tracker_position_mm, f"{where}: tracker_position_mm")
    rpy = np.deg2rad(_vec3(spec.tracker_rpy_deg, f"{where}: tracker_rpy_deg"))
    R_WT = RollPitchYaw(rpy).ToRotationMatrix().matrix()
    if spec.noise_sigma_mm <= 0 or spec.beam_radius_mm < 0:
        raise InputError(f"{where}: noise_sigma_mm must be > 0 and beam_radius_mm >= 0")
    if not 0 < spec.max_incidence_deg < 90:
        raise InputError(f"{where}: max_incidence_deg must be in (0, 90)")
    obstacles = tuple(
        Obstacle(
            o.name or f"obstacle{k}",
            float(o.radius_mm),
            _vec3(o.a_mm, f"{where}: obstacles[{k}].a_mm"),
            _vec3(o.b_mm, f"{where}: obstacles[{k}].b_mm"),
            bool(o.moves_with_car),
        )
        for k, o in enumerate(spec.obstacles)
    )
    return Cell(
        p_WT=p_WT,
        R_WT=R_WT,
        p_FQ=_vec3(spec.reflector_position_mm, f"{where}: reflector_position_mm"),
        max_incidence=float(np.deg2rad(spec.max_incidence_deg)),
        sigma=float(spec.noise_sigma_mm),
        beam_radius=float(spec.beam_radius_mm),
        floor_z=float(spec.floor_z_mm),
        wall_x=float(spec.wall_x_mm),
        obstacles=obstacles,
        work_height_above_cabin=float(spec.work_height_above_cabin_mm),
        work_cabin_obstacle=spec.work_cabin_obstacle,
    )


def load_cell(path: str | Path | None = None, *, robot: Robot | None = None) -> Cell:
    """Load the measuring cell (default ``models/cell.yaml``).

    If ``robot`` is given, the car obstacles are shifted along x by the robot's ``car_shift_x_mm``
    (SPEC: move the car for a robot that cannot reach a feasible region in the default cell).
    """
    path = Path(path) if path is not None else MODELS_DIR / "cell.yaml"
    spec = _load_yaml(path, CellSpec)
    cell = cell_from_spec(spec, where=str(path))
    if robot is not None and robot.car_shift_x:
        shift = np.array([robot.car_shift_x, 0.0, 0.0])
        obs = tuple(
            dataclasses.replace(o, a=o.a + shift, b=o.b + shift) if o.moves_with_car else o
            for o in cell.obstacles
        )
        cell = dataclasses.replace(cell, obstacles=obs)
    return cell
