"""The measuring cell: tracker, reflector, noise and obstacles, a typed :class:`Cell` loaded from
``models/cell.yaml`` (mm, deg in the file; mm, rad loaded), with a robot file's overrides."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw

from kpioed_drake.errors import InputError
from kpioed_drake.robot.modelspec import MODELS_DIR, CellSpec, load_yaml_typed, vec3


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


def cell_from_spec(spec: CellSpec, where: str = "cell") -> Cell:
    """Validate a :class:`CellSpec` and convert it to a :class:`Cell` (mm, rad)."""
    p_WT = vec3(spec.tracker_position_mm, f"{where}: tracker_position_mm")
    rpy = np.deg2rad(vec3(spec.tracker_rpy_deg, f"{where}: tracker_rpy_deg"))
    R_WT = RollPitchYaw(rpy).ToRotationMatrix().matrix()
    if not (np.isfinite(spec.noise_sigma_mm) and spec.noise_sigma_mm > 0):
        raise InputError(f"{where}: noise_sigma_mm must be a finite number > 0, got {spec.noise_sigma_mm!r}")
    if not (np.isfinite(spec.beam_radius_mm) and spec.beam_radius_mm >= 0):
        raise InputError(f"{where}: beam_radius_mm must be a finite number >= 0, got {spec.beam_radius_mm!r}")
    if not 0 < spec.max_incidence_deg < 90:
        raise InputError(f"{where}: max_incidence_deg must be in (0, 90), got {spec.max_incidence_deg!r}")
    for field in ("floor_z_mm", "wall_x_mm", "work_height_above_cabin_mm"):
        if not np.isfinite(getattr(spec, field)):
            raise InputError(f"{where}: {field} must be finite, got {getattr(spec, field)!r}")
    for k, o in enumerate(spec.obstacles):
        if not (np.isfinite(o.radius_mm) and o.radius_mm >= 0):
            raise InputError(
                f"{where}: obstacles[{k}].radius_mm must be a finite number >= 0, got {o.radius_mm!r}"
            )
    obstacles = tuple(
        Obstacle(
            o.name or f"obstacle{k}",
            float(o.radius_mm),
            vec3(o.a_mm, f"{where}: obstacles[{k}].a_mm"),
            vec3(o.b_mm, f"{where}: obstacles[{k}].b_mm"),
            bool(o.moves_with_car),
        )
        for k, o in enumerate(spec.obstacles)
    )
    return Cell(
        p_WT=p_WT,
        R_WT=R_WT,
        p_FQ=vec3(spec.reflector_position_mm, f"{where}: reflector_position_mm"),
        max_incidence=float(np.deg2rad(spec.max_incidence_deg)),
        sigma=float(spec.noise_sigma_mm),
        beam_radius=float(spec.beam_radius_mm),
        floor_z=float(spec.floor_z_mm),
        wall_x=float(spec.wall_x_mm),
        obstacles=obstacles,
        work_height_above_cabin=float(spec.work_height_above_cabin_mm),
        work_cabin_obstacle=spec.work_cabin_obstacle,
    )


def load_cell(path: str | Path | None = None, *, robot=None) -> Cell:
    """Load the measuring cell (default ``models/cell.yaml``).

    If ``robot`` is given, the car obstacles are shifted along x by the robot's ``car_shift_x_mm``
    (SPEC: move the car for a robot that cannot reach a feasible region in the default cell), and
    the robot file's optional ``reflector_position_mm`` and tracker pose replace the cell's (a
    robot- or data-specific target, or a calibrated model's tracker frame).
    """
    path = Path(path) if path is not None else MODELS_DIR / "cell.yaml"
    spec = load_yaml_typed(path, CellSpec)
    cell = cell_from_spec(spec, where=str(path))
    if robot is not None and robot.car_shift_x:
        shift = np.array([robot.car_shift_x, 0.0, 0.0])
        obs = tuple(
            dataclasses.replace(o, a=o.a + shift, b=o.b + shift) if o.moves_with_car else o
            for o in cell.obstacles
        )
        cell = dataclasses.replace(cell, obstacles=obs)
    if robot is not None and robot.p_FQ is not None:
        cell = dataclasses.replace(cell, p_FQ=robot.p_FQ)
    if robot is not None and robot.X_WT is not None:
        cell = dataclasses.replace(cell, p_WT=robot.X_WT[0], R_WT=robot.X_WT[1])
    return cell
