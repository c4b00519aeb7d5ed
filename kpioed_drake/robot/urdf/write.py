"""A calibrated URDF robot as a URDF file plus its sidecar (``kpioed calibrate --out NAME.urdf``).

The estimated errors of joint i (:mod:`kpioed_drake.robot.chain`: offset, three translations, three small
rotations) are folded into the URDF joint's ``<origin>``:
``X' = X Trans(px, py, pz) Rx(rx) Ry(ry) Rz(rz) M(off)``, with ``M(off)`` the joint's own motion
by its offset (a rotation about, or a translation along, its axis), so that the new file's link i
frame at ``q`` is the calibrated model's. Everything else of the URDF (links, inertias, collision
and visual geometry, the root weld) is copied unchanged. The sidecar ``NAME.kpioed.yaml`` gets the
original sidecar's fields plus the estimated reflector offset and tracker pose, so ``--robot
NAME.urdf`` carries the whole calibrated model (as a calibrated YAML file does).
"""

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.math import RollPitchYaw, RotationMatrix

from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Robot, load_yaml_typed
from kpioed_drake.robot.modelspec import ContactEnvironmentSpec, EffectSpec
from kpioed_drake.robot.urdf.origins import moved_origins
from kpioed_drake.robot.urdf.read import SidecarSpec, sidecar_path

URDF_SUFFIX = ".urdf"


def check_out_path(robot: Robot, out: Path | str) -> None:
    """A URDF robot's calibrated model must be written as ``.urdf``, a table robot's as YAML.

    Raises:
        InputError: a mismatching suffix.
    """
    if out is None:
        return
    is_urdf = Path(str(out)).suffix == URDF_SUFFIX
    if robot.urdf is not None and not is_urdf:
        raise InputError(
            f"out: {robot.name} is a URDF robot; its calibrated model is a URDF file: expected "
            f"NAME{URDF_SUFFIX} (its sidecar NAME.kpioed.yaml is written beside it), got {str(out)!r}",
            fields=("out",),
        )
    if robot.urdf is None and is_urdf:
        raise InputError(
            f"out: {robot.name} is a YAML robot; expected a .yaml file for its calibrated model, "
            f"got {str(out)!r}",
            fields=("out",),
        )


def calibrated_urdf(robot: Robot, geometry: np.ndarray, note: str = "") -> str:
    """URDF text of ``robot`` with the errors ``geometry`` (n_joints, 7) [rad, mm] in its joints.

    A reference robot (:class:`~kpioed_drake.robot.models.Reference`: a calibrated file with its
    errors folded out) gets its errors folded into the reference placements, not into the file's."""
    src = Path(robot.urdf.path)
    root = ET.fromstring(src.read_text(encoding="utf-8"))
    if robot.urdf.unfolded is not None:
        moved_origins(root, robot.urdf.joints, robot.chain, robot.urdf.unfolded, out=True)
    moved_origins(root, robot.urdf.joints, robot.chain, geometry, out=False)
    text = ET.tostring(root, encoding="unicode")
    comment = f"<!-- {note} -->\n" if note else ""
    return '<?xml version="1.0"?>\n' + comment + text + "\n"


def calibrated_sidecar(
    robot: Robot,
    *,
    p_FQ: np.ndarray,
    p_WT: np.ndarray,
    R_WT: np.ndarray,
    targets: np.ndarray | None = None,
    note: str = "",
    effects: Sequence[EffectSpec] = (),
    estimated_errors: Sequence[Sequence[float]] = (),
    payload_point: Sequence[float] = (),
    R_FP: np.ndarray | None = None,
    environment: ContactEnvironmentSpec | None = None,
) -> str:
    """Sidecar text: the original's fields, the estimated reflector offset, tracker pose and (with
    ``R_FP``) a 6-DoF probe's orientation on the flange, the
    estimated effects (``effects``: :class:`~kpioed_drake.robot.modelspec.EffectSpec` entries) and
    the nominal robot's gauge (the calibrated errors make its exact dependencies only nearly exact);
    a contact calibration's planes, pivots and bars (``environment``)."""
    src = sidecar_path(Path(robot.urdf.path))
    side = load_yaml_typed(src, SidecarSpec) if src.is_file() else SidecarSpec()
    if side.targets:  # targets on links: each back in its named link's frame
        offsets = np.atleast_2d(np.asarray(p_FQ if targets is None else targets, dtype=float))
        placed = [
            dataclasses.replace(t, position_mm=(R.T @ (d - p)).tolist())
            for t, d, (R, p) in zip(side.targets, offsets, robot.urdf.target_placements, strict=True)
        ]
        side = dataclasses.replace(side, targets=placed)
        p_FQ, targets = [], None
    side = dataclasses.replace(
        side,
        name=f"{robot.name}-calibrated",
        reflector_position_mm=np.asarray(p_FQ, dtype=float).tolist(),  # [] with targets on links
        tracker_position_mm=np.asarray(p_WT, dtype=float).tolist(),
        tracker_rpy_deg=np.rad2deg(RollPitchYaw(RotationMatrix(R_WT)).vector()).tolist(),
        gauge=list(robot.gauge),
        targets_mm=[] if targets is None else np.asarray(targets, dtype=float).tolist(),
        notes=(side.notes + " " if side.notes else "") + note,
        effects=list(effects),
        estimated_errors=list(estimated_errors),
        payload_point_mm=list(payload_point),
        probe_rpy_deg=[]
        if R_FP is None
        else np.rad2deg(RollPitchYaw(RotationMatrix(R_FP)).vector()).tolist(),
        contact_environment=environment,
    )
    header = "# Sidecar of a calibrated URDF robot (kpioed-drake). Units: mm, deg. Format: models/README.md\n"
    return header + yaml_dump_typed(side)


def sidecar_of(out: Path | str) -> Path:
    """The sidecar path written beside ``out`` (``NAME.urdf`` -> ``NAME.kpioed.yaml``)."""
    return sidecar_path(Path(str(out)))
