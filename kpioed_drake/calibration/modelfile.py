"""The calibrated robot as a model file (same schema as ``models/robots/*.yaml``).

:func:`calibrated_robot_yaml` writes the estimated joint rows, the estimated reflector offset
(``reflector_position_mm``; with several targets all of them, ``targets_mm``, target 1 first),
a 6-DoF probe's estimated orientation on the flange (``probe_rpy_deg``; data with orientations)
and the estimated tracker pose (``tracker_position_mm``,
``tracker_rpy_deg``) into the robot's :class:`~kpioed_drake.robot.models.RobotSpec` (read back from its
source file when available), so that the result is a complete model usable as ``--robot path.yaml``
by every command: the reflector and tracker fields override the cell file's
(:func:`kpioed_drake.robot.models.load_cell`).
"""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.math import RollPitchYaw, RotationMatrix

from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.effects import effect_specs
from kpioed_drake.robot.jointmap import joint_map_spec
from kpioed_drake.robot.models import N_JOINTS, CapsuleSpec, JointSpec, LinkSpec, Robot, RobotSpec
from kpioed_drake.robot.modelspec import ContactEnvironmentSpec
from kpioed_drake.robot.reference import file_rows
from kpioed_drake.robot.urdf.write import calibrated_sidecar, calibrated_urdf
from kpioed_drake.tracker.measurement import TrackerModel


def _spec_from_robot(robot: Robot) -> RobotSpec:
    """A RobotSpec rebuilt from a loaded robot (used when its source file is not available)."""
    joints = []
    for i, conv in enumerate(robot.conventions):
        joints.append(
            JointSpec(
                name=robot.joint_names[i],
                convention=conv,
                lower_deg=float(np.rad2deg(robot.lower[i])),
                upper_deg=float(np.rad2deg(robot.upper[i])),
            )
        )
    links = []
    for k in range(N_JOINTS + 1):
        caps = [
            CapsuleSpec(name=c.name, radius_mm=c.radius, a_mm=c.a.tolist(), b_mm=c.b.tolist())
            for c in robot.capsules
            if c.frame == k
        ]
        links.append(
            LinkSpec(index=k, mass_kg=float(robot.masses[k]), com_mm=robot.coms[k].tolist(), capsules=caps)
        )
    return RobotSpec(
        name=robot.name,
        joints=joints,
        links=links,
        self_collision_pairs=[list(p) for p in robot.self_pairs],
        beam_links=list(robot.beam_links),
        q_work_deg=[] if robot.q_work is None else np.rad2deg(robot.q_work).tolist(),
        car_shift_x_mm=robot.car_shift_x,
        joint_map=joint_map_spec(robot.joint_map),
        extra_gauge=list(robot.extra_gauge),
        targets_mm=[] if robot.targets is None else robot.targets.tolist(),
        compliant_base=robot.compliant_base,
        rated_payload_kg=robot.rated_payload_kg or 0.0,
        drives={str(i + 1): d for i, d in enumerate(robot.drives)},
    )


def _robot_spec(robot: Robot) -> RobotSpec:
    src = Path(robot.source) if robot.source else None
    if src is not None and src.is_file():
        try:
            return yaml_load_typed(filename=str(src), schema=RobotSpec)
        except Exception:  # fall back to the loaded object
            pass
    return _spec_from_robot(robot)


def calibrated_robot_yaml(report: CalibrationReport) -> str:
    """The calibrated robot as model-file text (RobotSpec schema, mm/deg).

    Joint rows hold the estimated values (the gauge parameters theta1, d1, theta6, d6, a6, alpha6
    and the file's ``extra_gauge`` keep their nominal values); ``reflector_position_mm`` the
    estimated reflector offset; ``tracker_position_mm`` and ``tracker_rpy_deg`` the estimated
    tracker pose of the calibration's data; ``effects`` the estimated non-geometric effects (an
    extended model; none for a geometric calibration). Capsules, masses, limits, q_work and the
    joint map are the nominal model's.
    """
    return robot_yaml(
        report.robot,
        report.model,
        note=_note(report),
        effects=_effects(report),
        estimated_errors=_estimated_errors(report),
        payload_point=_payload_point(report),
    )


def robot_yaml(
    rob: Robot,
    model: TrackerModel,
    *,
    note: str,
    effects: list | None = None,
    estimated_errors: list | None = None,
    payload_point: list | None = None,
    environment: ContactEnvironmentSpec | None = None,
) -> str:
    """The model-file text of ``model`` (a fit of ``rob``): :func:`calibrated_robot_yaml`'s fields,
    ``note`` (the calibration's line), and a contact calibration's ``environment``."""
    spec = _robot_spec(rob)
    g = model.geometry
    for i, j in enumerate(spec.joints):
        conv = rob.conventions[i]
        j.convention = conv
        if conv == "dh":
            th, d, a, al = g[i]
            j.theta_deg, j.d_mm, j.a_mm, j.alpha_deg = (
                float(np.rad2deg(th)),
                float(d),
                float(a),
                float(np.rad2deg(al)),
            )
            j.beta_deg = 0.0
        else:
            th, a, al, be = g[i]
            j.theta_deg, j.a_mm, j.alpha_deg = float(np.rad2deg(th)), float(a), float(np.rad2deg(al))
            j.beta_deg, j.d_mm = float(np.rad2deg(be)), 0.0
    spec.name = f"{rob.name}-calibrated"
    spec.reflector_position_mm = model.p_FQ.tolist()
    if spec.targets_mm or model.layout.n_targets > 1:
        spec.targets_mm = model.target_offsets.tolist()
    spec.tracker_position_mm = model.p_WT.tolist()
    spec.tracker_rpy_deg = np.rad2deg(RollPitchYaw(RotationMatrix(model.R_WT)).vector()).tolist()
    spec.effects = effects or []
    spec.estimated_errors = (
        file_rows(rob, model.geometry - rob.geometry) if estimated_errors is None else estimated_errors
    )
    spec.payload_point_mm = payload_point or []
    spec.contact_environment = environment
    R_FP = model.R_FP
    spec.probe_rpy_deg = (
        [] if R_FP is None else np.rad2deg(RollPitchYaw(RotationMatrix(R_FP)).vector()).tolist()
    )
    cal_note = note + (
        " Joint rows hold the estimates (the gauge parameters nominal); reflector_position_mm "
        "(targets_mm: every target) and "
        "tracker_position_mm/tracker_rpy_deg hold the estimated reflector offset and tracker pose "
        "(they override the cell file's)."
    )
    spec.notes = (spec.notes + " " if spec.notes else "") + cal_note
    header = "# Calibrated robot model file (kpioed-drake). Units: mm, deg, kg. Format: models/README.md.\n"
    return header + yaml_dump_typed(spec)


def _effects(report: CalibrationReport) -> list:
    """The model-file entries of the report's effects (display units, a-priori std)."""
    return effect_specs(report.effects, report.effect_std()[0], robot=report.robot)


def _estimated_errors(report: CalibrationReport) -> list[list[float]]:
    """The estimated rows' errors against the robot the fit started from (file units), with which
    a reader rebuilds the geometry the effects were evaluated on (:mod:`kpioed_drake.robot.reference`)."""
    return file_rows(report.robot, report.model.geometry - report.robot.geometry)


def _payload_point(report: CalibrationReport) -> list[float]:
    """The payload point the fit's effects used (:attr:`TrackerModel.p_FP`), for a model with effects."""
    point = report.robot.payload_point
    return [] if point is None or not report.effects else np.asarray(point, dtype=float).tolist()


def _note(report: CalibrationReport) -> str:
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"Calibrated by kpioed calibrate from {report.data.path} ({stamp}): "
        f"{int(np.count_nonzero(report.used))} of {report.data.n} poses, sigma {report.result.sigma:g} mm, "
        f"RMS residual {report.rms_residual_mm:.4g} mm"
        + (f", chi2/dof {report.chi2_per_dof:.3g}" if report.chi2_per_dof is not None else "")
        + "."
    )


def calibrated_urdf_files(report: CalibrationReport) -> tuple[str, str]:
    """A calibrated URDF robot: the URDF text (estimated errors folded into the joint origins) and
    its sidecar text (estimated reflector offset and tracker pose); :mod:`kpioed_drake.robot.urdf.write`."""
    rob, model = report.robot, report.model
    note = _note(report)
    urdf = calibrated_urdf(rob, model.geometry, note.replace("--", "-"))
    side = model_sidecar(
        rob,
        model,
        note=note,
        effects=_effects(report),
        estimated_errors=_estimated_errors(report),
        payload_point=_payload_point(report),
        R_FP=model.R_FP,
    )
    return urdf, side


def model_sidecar(rob: Robot, model: TrackerModel, *, note: str, **fields: Any) -> str:
    """The sidecar text of a calibrated URDF robot: ``model``'s reflector offsets (several targets:
    each) and tracker pose, the ``note`` and ``fields`` (effects, estimated errors, ...) of
    :func:`~kpioed_drake.robot.urdf.write.calibrated_sidecar`."""
    targets = model.target_offsets if model.layout.n_targets > 1 else None
    return calibrated_sidecar(
        rob, p_FQ=model.p_FQ, p_WT=model.p_WT, R_WT=model.R_WT, targets=targets, note=note, **fields
    )
