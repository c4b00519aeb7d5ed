"""The model files: where they are and their schemas, what a robot or cell YAML file or a URDF
robot's sidecar holds (millimetres, degrees).

Drake's ``yaml_load_typed`` reads ``models/robots/*.yaml`` into :class:`RobotSpec`,
``models/cell.yaml`` into :class:`CellSpec` and a URDF's ``<name>.kpioed.yaml`` into
:class:`SidecarSpec`; an unknown or misspelled field is an error. :mod:`kpioed_drake.robot.models`
(and :mod:`kpioed_drake.robot.urdf` for the sidecar) validates them and turns them into the typed
objects (millimetres, radians) the rest of the package uses. Field meanings: ``models/README.md``.
"""

import dataclasses
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RollPitchYaw

from kpioed_drake.errors import InputError
from kpioed_drake.options import yaml_mismatch
from kpioed_drake.robot.drivetrain import drive_types
from kpioed_drake.robot.jointmap import JointMapSpec

MODELS_DIR = Path(os.environ.get("KPIOED_MODELS", Path(__file__).resolve().parents[2] / "models"))
"""Folder holding ``cell.yaml`` and ``robots/*.yaml`` (override with ``KPIOED_MODELS``)."""

_NOTIONAL = re.compile(r"^notional-(\d+)-(\d+)$")


def robot_path(name: str) -> Path:
    """Path of the model file for ``name`` (a model name or a path to a YAML or URDF file); a
    shipped name without a YAML file but with a URDF file (e.g. ``lift7``) names the URDF."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml", ".urdf"):
        return p
    m = _NOTIONAL.match(name)
    if m:
        return MODELS_DIR / "robots" / "notional" / f"{name}.yaml"
    path = MODELS_DIR / "robots" / f"{name}.yaml"
    urdf = path.with_suffix(".urdf")
    return urdf if not path.is_file() and urdf.is_file() else path


def list_robots() -> list[str]:
    """Names of all robots shipped under ``models/robots``."""
    root = MODELS_DIR / "robots"
    yamls = {p.stem for p in root.glob("*.yaml") if not p.name.endswith(".kpioed.yaml")}  # not sidecars
    names = sorted(yamls | {p.stem for p in root.glob("*.urdf")})
    names += sorted(p.stem for p in (root / "notional").glob("notional-*.yaml"))
    return names


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
class EffectSpec:
    """One non-geometric effect of an extended model file (an entry of ``effects:``), as a
    calibration estimated it; :func:`kpioed_drake.effects.model_effects` turns it into an effect
    with values."""

    name: str = ""
    """The effect text without values (:func:`kpioed_drake.effects.parse_effect` syntax), e.g.
    ``joint_elasticity:2``, ``gear_cyclic:4:2``, ``tracker_drift``."""
    values: list[float] = dataclasses.field(default_factory=list)
    """Its values in display units, as after ``=`` in the effect text (elasticity rad/(N m), gear
    deg, drift mm/min, scale ppm, ...)."""
    std: list[float] = dataclasses.field(default_factory=list)
    """Their standard deviations from the calibration (same units; empty: not known)."""
    unit: str = ""
    """The display unit of ``values`` (e.g. ``rad/(N m)``); must be the family's when given."""
    basis_rms: list[float] = dataclasses.field(default_factory=list)
    """``joint_elasticity_basis`` only: the RMS ``D_j`` of each full gravity-regressor column of
    joint j over the reference poses (:class:`kpioed_drake.effects.gravity_basis.JointBasis`)."""
    basis_directions: list[list[float]] = dataclasses.field(default_factory=list)
    """``joint_elasticity_basis`` only: the identifiable directions ``V_j``, one row per full
    regressor column (p rows of r_j numbers), so that the file's values multiply the same columns."""


def checked_effects(specs: Iterable[EffectSpec], where: str) -> tuple[EffectSpec, ...]:
    """The ``effects:`` entries of a model file, with finite numbers and consistent sizes.

    Raises:
        InputError: ``where`` (the file), the field (``effects[k].values`` ...) and what was expected.
    """
    out = []
    for k, e in enumerate(specs):
        at = f"{where}: effects[{k}]"
        if not str(e.name).strip() or "=" in e.name:
            raise InputError(f"{at}.name: expected an effect text without values, got {e.name!r}")
        for field in ("values", "std", "basis_rms", "basis_directions"):
            v = np.concatenate([np.ravel(np.asarray(x, dtype=float)) for x in getattr(e, field)] + [[]])
            if not np.all(np.isfinite(v)):
                raise InputError(f"{at}.{field}: expected finite numbers, got {getattr(e, field)!r}")
        if not e.values:
            raise InputError(
                f"{at}.values: {e.name} has no values (an extended model's effects are estimated)"
            )
        if e.std and len(e.std) != len(e.values):
            raise InputError(f"{at}.std: expected {len(e.values)} numbers (one per value), got {len(e.std)}")
        rows = [len(r) for r in e.basis_directions]
        if (e.basis_rms or rows) and (len(rows) != len(e.basis_rms) or len(set(rows)) > 1):
            raise InputError(
                f"{at}.basis_directions: expected one row of equal length per basis_rms entry "
                f"({len(e.basis_rms)}), got rows of {rows}"
            )
        out.append(e)
    return tuple(out)


@dataclasses.dataclass
class PlaneSpec:
    """A plane of a contact calibration in W: ``normal . x = offset_mm`` (unit normal)."""

    normal: list[float] = dataclasses.field(default_factory=list)
    offset_mm: float = 0.0


@dataclasses.dataclass
class ContactEnvironmentSpec:
    """What a calibration with plane contacts or distances estimated besides the robot
    (docs/contacts.md): the planes (id k = entry k), pivots (position in W [mm]) and bars' length
    corrections [mm], in the order of the files' ids 1, 2, ...; ``kpioed validate`` scores held-out
    contacts with them."""

    planes: list[PlaneSpec] = dataclasses.field(default_factory=list)
    pivots_mm: list[list[float]] = dataclasses.field(default_factory=list)
    bars_dL_mm: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class ModelFileSpec:
    """The fields a robot file (:class:`RobotSpec`) and a URDF's sidecar (:class:`SidecarSpec`) share:
    the measuring setup's overrides, the drives, and what a calibration writes (every field optional;
    mm, deg). :func:`shared_fields` checks them, the same for both kinds of file."""

    name: str = ""
    description: str = ""
    self_collision_pairs: list[list[int]] = dataclasses.field(default_factory=list)
    """Link pairs checked against each other (link indices 0..n)."""
    beam_links: list[int] = dataclasses.field(default_factory=list)
    """Links the laser beam must not touch."""
    car_shift_x_mm: float = 0.0
    """Moves the car obstacles along x [mm]."""
    reflector_position_mm: list[float] = dataclasses.field(default_factory=list)
    """Optional: the reflector (target) offset in the flange frame; overrides the cell's."""
    targets_mm: list[list[float]] = dataclasses.field(default_factory=list)
    """Optional: several targets (SMRs), one flange-frame offset each, target 1 first; target 1
    is the reflector (``reflector_position_mm``, if also given, must equal it)."""
    tracker_position_mm: list[float] = dataclasses.field(default_factory=list)
    """Optional: the tracker position in W (e.g. as calibrated); overrides the cell's."""
    tracker_rpy_deg: list[float] = dataclasses.field(default_factory=list)
    """Optional, with ``tracker_position_mm``: the tracker orientation (roll, pitch, yaw)."""
    joint_map: JointMapSpec | None = None
    """Optional: controller angles to model angles (:mod:`kpioed_drake.robot.jointmap`; a URDF's
    default: its ``<mimic>`` joints')."""
    extra_gauge: list[str] = dataclasses.field(default_factory=list)
    """Optional: parameters held at nominal besides SPEC's gauge (e.g. ``theta5, alpha5`` when the
    reflector lies on joint 6's axis and joint 6 cannot move it)."""
    compliant_base: bool = False
    """Optional: the base or floor is compliant (``base_compliance`` becomes a diagnosis candidate)."""
    rated_payload_kg: float = 0.0
    """Optional: the payload the robot may carry [kg] (0: not given); a discrimination design's payload
    plan may not exceed it."""
    drive: str = ""
    """Optional: how every joint is driven, ``gear`` (default), ``harmonic``, ``cable`` or ``belt``
    (:mod:`kpioed_drake.robot.drivetrain`): sets the plausibility bounds of the joints' effects."""
    drives: dict[str, str] = dataclasses.field(default_factory=dict)
    """Optional: the drive type per joint (name or 1-based number), overriding ``drive``."""
    effects: list[EffectSpec] = dataclasses.field(default_factory=list)
    """Optional: the non-geometric effects of an extended model (``calibrate`` with ``extend``)."""
    payload_point_mm: list[float] = dataclasses.field(default_factory=list)
    """Optional: where a payload's weight acts in the flange frame, for the effects' gravity torques
    (default: the reflector offset); a calibration with effects writes the point its fit used."""
    probe_rpy_deg: list[float] = dataclasses.field(default_factory=list)
    """Optional: the orientation (roll, pitch, yaw) of a 6-DoF probe's frame P on the flange,
    ``R_FP``; a calibration from data with orientations writes its estimate (the probe's origin is
    the reflector offset)."""
    estimated_errors: list[list[float]] = dataclasses.field(default_factory=list)
    """Written by a calibration: the estimated errors of the joint rows against the model the
    calibration started from, a row per joint (a table's four values in its own order [deg, mm]; a
    URDF joint's seven: offset [deg; prismatic mm], x, y, z [mm], rx, ry, rz [deg]). An extended
    model's effects (gravity torques, mass-free bases, pivots) are evaluated on that model's geometry,
    this file's minus these errors, as the fit evaluated them: the file predicts what the fit did."""
    contact_environment: ContactEnvironmentSpec | None = None
    """Written by a calibration with plane contacts or distances: its estimated planes, pivots and
    bars (:class:`ContactEnvironmentSpec`)."""
    notes: str = ""


@dataclasses.dataclass
class RobotSpec(ModelFileSpec):
    """A robot model file."""

    sources: str = ""
    joints: list[JointSpec] = dataclasses.field(default_factory=list)
    links: list[LinkSpec] = dataclasses.field(default_factory=list)
    q_work_deg: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class ObstacleSpec(CapsuleSpec):
    """A fixed obstacle capsule in the world frame W [mm]."""

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


@dataclasses.dataclass
class LimitSpec:
    """A joint limit override: ``joint`` (URDF name), ``lower``, ``upper`` [deg; prismatic mm]."""

    joint: str = ""
    lower: float = 0.0
    upper: float = 0.0


@dataclasses.dataclass
class LinkCapsuleSpec(CapsuleSpec):
    """A capsule on robot link ``link`` (0 = base in W, i = child link of movable joint i) [mm]."""

    link: int = 0


@dataclasses.dataclass
class LinkTargetSpec:
    """A target (SMR, marker) fixed on URDF link ``link`` at ``position_mm`` in that link's frame."""

    link: str = ""
    position_mm: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class LinkMassSpec:
    """A mass override of robot link ``link`` (1..n): ``mass_kg`` and optionally ``com_mm`` (link frame);
    the URDF's inertia tensor is scaled by the mass ratio."""

    link: int = 0
    mass_kg: float = 0.0
    com_mm: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class SidecarSpec(ModelFileSpec):
    """The sidecar YAML of a URDF robot (every field optional; mm, deg)."""

    tip_link: str = ""
    """The measured link: the robot is the chain from the URDF's root to it (other branches
    ignored); empty: the URDF must be a serial chain."""
    targets: list[LinkTargetSpec] = dataclasses.field(default_factory=list)
    """Targets on several links (``{link: NAME, position_mm: [x, y, z]}``, target 1 first, in the
    named link's frame): the robot is the union of the chains from the root to their links (a tree:
    two arms on one torso), each joint estimated once; instead of ``tip_link``/``targets_mm``."""
    base_xyz_mm: list[float] = dataclasses.field(default_factory=list)
    """The root link's position in W when the URDF does not weld it to ``world`` [mm]."""
    base_rpy_deg: list[float] = dataclasses.field(default_factory=list)
    """The root link's orientation in W (roll, pitch, yaw) [deg]."""
    limits: list[LimitSpec] = dataclasses.field(default_factory=list)
    """Joint limits replacing the URDF's (by joint name)."""
    capsules: list[LinkCapsuleSpec] = dataclasses.field(default_factory=list)
    """Collision capsules replacing the URDF's collision geometry."""
    masses: list[LinkMassSpec] = dataclasses.field(default_factory=list)
    """Link masses (and centres of mass) replacing the URDF's."""
    q_work: list[float] = dataclasses.field(default_factory=list)
    """The working pose, one value per joint [deg; prismatic mm]."""
    gauge: list[str] = dataclasses.field(default_factory=list)
    """The parameters held at nominal instead of the automatic choice (a calibrated model keeps its
    nominal robot's: its small errors make the exact dependencies only nearly exact)."""


def rated_payload(value: float, where: str) -> float | None:
    """A model file's ``rated_payload_kg``: None for 0 (not given), else a finite number > 0 [kg].

    Raises:
        InputError: ``where`` (file and field) and what was expected.
    """
    try:
        kg = float(value)
    except (TypeError, ValueError):
        kg = float("nan")
    if not (np.isfinite(kg) and kg >= 0):
        raise InputError(f"{where}: expected the rated payload in kg, a number >= 0, got {value!r}")
    return kg if kg > 0 else None


def vec3(values: object, where: str) -> np.ndarray:
    """(3,) finite numbers from a file field ``where``; InputError otherwise."""
    arr = np.asarray(values, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: expected 3 finite numbers, got {values!r}")
    return arr


def shared_fields(spec: RobotSpec | SidecarSpec, where: str, joint_names: tuple[str, ...]) -> dict:
    """The :class:`~kpioed_drake.robot.models.Robot` fields a robot file and a URDF's sidecar give
    alike (beam links, car shift, extra gauge, compliant base, rated payload, drives, effects,
    payload point and probe orientation), checked in this order; ``where`` names the file in messages.

    Raises:
        InputError: ``where``, the field and what was expected.
    """
    return dict(
        beam_links=tuple(int(x) for x in spec.beam_links),
        car_shift_x=float(spec.car_shift_x_mm),
        extra_gauge=tuple(spec.extra_gauge),
        compliant_base=bool(spec.compliant_base),
        rated_payload_kg=rated_payload(spec.rated_payload_kg, f"{where}: rated_payload_kg"),
        drives=drive_types(spec.drive, spec.drives, joint_names, where),
        effects=checked_effects(spec.effects, where),
        effects_where=where,
        payload_point=vec3(spec.payload_point_mm, f"{where}: payload_point_mm")
        if spec.payload_point_mm
        else None,
        R_FP=RollPitchYaw(np.deg2rad(vec3(spec.probe_rpy_deg, f"{where}: probe_rpy_deg")))
        .ToRotationMatrix()
        .matrix()
        if spec.probe_rpy_deg
        else None,
    )


def spec_joint_names(spec: RobotSpec) -> tuple[str, ...]:
    """The joint names of a robot file (``A1`` .. for a joint without one)."""
    return tuple(j.name or f"A{i + 1}" for i, j in enumerate(spec.joints))


def load_yaml_typed(path: str | Path, schema: type) -> Any:
    """A YAML file loaded into the dataclass ``schema``; errors (InputError) name the file and field."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a YAML file")
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:  # PyYAML first: its syntax errors carry the line and column
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except RecursionError:  # PyYAML builds nested lists by recursion
        raise InputError(f"{path}: lists or mappings nested too deeply; not a model file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        loc = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{path}: YAML syntax error{loc}: {what}") from None
    mismatch = yaml_mismatch(data, schema)  # the field and what it should be, before Drake's loader
    if mismatch:
        raise InputError(f"{path}: {mismatch}")
    try:
        return yaml_load_typed(filename=str(path), schema=schema)
    except AssertionError:
        raise InputError(f"{path}: a field that must be a mapping (key: value) is not") from None
    except Exception as exc:  # pydrake raises RuntimeError/ValueError with a terse text
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: {msg}") from None
