"""Validation of a model on fresh data: how well does it predict measurements it has not seen?

``kpioed validate --robot MODEL DATA.csv`` predicts every measured reflector position with the
given model (its joint rows and reflector offset, paper eq. 3 ``h(p, q)``) and compares. Only the
tracker frame is re-registered (a rigid 6-DoF fit, Kabsch/Umeyama:
:func:`kpioed_drake.estimation.estimator.register_tracker`), because a tracker is set up anew for every
measurement campaign; ``keep_tracker`` uses the model's tracker pose instead (a calibrated model
file carries it). For data already in the base frame (``frame: base``) the registration estimates
the small residual frame error; kept, the tracker frame is the robot file's (for a model
calibrated on base-frame data: the frame error estimated then) or else the identity.

Several targets (a ``target`` column): each row is predicted with its target's offset from the
model file (``targets_mm``); the report gives the errors per target as well.

An extended model (a model file with ``effects:``) predicts with its effects: the per-pose
conditions they need come from the data (``temperature_C`` for thermal expansion and tracker scale,
``time_s`` for tracker drift: an error names a missing column; ``payload_kg`` when given, else no
payload), the tracker-frame prediction is taken to W with the model's tracker pose, then registered.

Nothing robot-side is fitted, so the errors are prediction errors: for a nominal model they are its
absolute accuracy (the "uncalibrated" error), for a calibrated one its accuracy after calibration.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

from kpioed_drake import effects as fx
from kpioed_drake.arguments import require
from kpioed_drake.calibration.common import read_inputs
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import register_tracker
from kpioed_drake.estimation.plausibility import check_data
from kpioed_drake.outputs import Outputs, pyplot
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.tracker.data import ROW_CONVENTION, Measurements, counted, n_poses
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model, reflector_world

_NEEDS = {"thermal_expansion": "temperature_C", "tracker_scale": "temperature_C", "tracker_drift": "time_s"}
"""The data column an effect's prediction needs."""


@dataclasses.dataclass(frozen=True)
class ValidationResult:
    """Prediction errors of a model on measured data.

    Attributes:
        robot: the model's name.
        model_source: the model file.
        data: the measurements.
        residuals_W: (n, 3) measured minus predicted reflector position, in W [mm].
        R_WT: (3, 3) tracker orientation used (registered or kept).
        p_WT: (3,) tracker position used [mm].
        registered: True if the tracker frame was re-registered to these data.
        effects: the names of the model's non-geometric effects it predicted with (empty: geometric).
        warnings: the plausibility checks' remarks (``force`` turns a refusal into one).
    """

    robot: str
    model_source: str
    data: Measurements
    residuals_W: np.ndarray
    R_WT: np.ndarray
    p_WT: np.ndarray
    registered: bool
    effects: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def errors_mm(self) -> np.ndarray:
        """(n,) 3-D prediction error of each pose [mm]."""
        return np.linalg.norm(self.residuals_W, axis=1)

    def per_target(self) -> list[dict]:
        """Errors of each target's rows (target numbers 1..T as in the file) [mm]."""
        target = np.zeros(self.data.n, dtype=int) if self.data.target is None else self.data.target
        out = []
        for t in range(self.data.n_targets):
            rows = target == t
            e, r = self.errors_mm[rows], self.residuals_W[rows]
            out.append(
                {
                    "target": t + 1,
                    "n_rows": int(np.count_nonzero(rows)),
                    "rms_mm": float(np.sqrt(np.mean(r**2))) if e.size else None,
                    "mean_error_mm": float(np.mean(e)) if e.size else None,
                    "max_error_mm": float(np.max(e)) if e.size else None,
                }
            )
        return out

    def to_dict(self) -> dict:
        """The JSON report (mm, deg)."""
        e = self.errors_mm
        return {
            "robot": self.robot,
            "model": self.model_source,
            "data": self.data.path,
            "frame": self.data.frame,
            "n_poses": n_poses(self.data),
            "n_rows": self.data.n,
            "rms_mm": float(np.sqrt(np.mean(self.residuals_W**2))),
            "rms_xyz_mm": np.sqrt(np.mean(self.residuals_W**2, axis=0)).tolist(),
            "mean_error_mm": float(np.mean(e)),
            "p95_error_mm": float(np.percentile(e, 95)),
            "max_error_mm": float(np.max(e)),
            "errors_mm": e.tolist(),
            "targets": self.per_target(),
            "rows": [int(r) for r in self.data.rows],
            "row_convention": ROW_CONVENTION,
            "residuals_W_mm": self.residuals_W.tolist(),
            "effects": list(self.effects),
            "warnings": list(self.warnings),
            "tracker": {
                "registered": self.registered,
                "p_WT_mm": self.p_WT.tolist(),
                "rpy_deg": np.rad2deg(RollPitchYaw(RotationMatrix(self.R_WT)).vector()).tolist(),
            },
            "note": "measured minus predicted reflector position in W; rms_mm over all coordinates, "
            "rms_xyz_mm per axis; *_error_mm of the 3-D distance per pose; only the tracker frame "
            "was fitted (rigid, 6 DoF) unless tracker.registered is false",
        }

    def summary(self) -> str:
        """A human-readable summary."""
        d = self.to_dict()
        how = "re-registered (rigid, 6 DoF)" if self.registered else "kept from the model"
        per_target = [
            f"  target {t['target']}: {t['n_rows']} rows, mean {t['mean_error_mm']:.4f} mm, "
            f"max {t['max_error_mm']:.4f} mm"
            for t in d["targets"]
            if self.data.n_targets > 1 and t["n_rows"]
        ]
        return "\n".join(
            [
                f"{self.robot}"
                + (f" (with {', '.join(self.effects)})" if self.effects else "")
                + f": validated on {self.data.path}: {counted(self.data)}, tracker frame {how}",
                f"  3-D error: mean {d['mean_error_mm']:.4f} mm, 95 % {d['p95_error_mm']:.4f} mm, "
                f"max {d['max_error_mm']:.4f} mm",
                f"  RMS per coordinate {d['rms_mm']:.4f} mm (x, y, z: "
                + ", ".join(f"{v:.4f}" for v in d["rms_xyz_mm"])
                + ")",
                *per_target,
                *(f"  warning: {w}" for w in self.warnings),
            ]
        )


def validate(
    robot: Robot,
    data: Measurements,
    *,
    keep_tracker: bool = False,
    cell: Cell | None = None,
    force: bool = False,
) -> ValidationResult:
    """Prediction errors of ``robot`` (a nominal or calibrated model) on ``data``.

    Args:
        robot: the model (joint rows; reflector offset, further targets and tracker pose from
            the robot file when it has them, else from the cell file).
        data: the measurements (tracker or base frame).
        keep_tracker: use the model's tracker pose instead of re-registering it to the data: the
            robot file's (a calibrated model has one), else the identity for base-frame data,
            else the cell file's.
        cell: the measuring cell (default ``models/cell.yaml``).
        force: go on with implausible data, with a warning in the result.

    Returns:
        :class:`ValidationResult`.

    Raises:
        InputError: too few poses or collinear points (the tracker frame is undetermined), or
            implausible data (:func:`kpioed_drake.estimation.plausibility.check_data`: other length units,
            gross errors, another robot or a wrong joint map).
    """
    model = nominal_model(robot, load_cell(robot=robot) if cell is None else cell)
    warnings = check_data(model, data, n_params=6, force=force)
    effects = fx.model_effects(robot)
    p_W = predicted_world(model, data, effects)
    if keep_tracker and robot.X_WT is None and data.frame == "base":
        R_WT, p_WT = np.eye(3), np.zeros(3)
    elif keep_tracker:
        R_WT, p_WT = model.R_WT, model.p_WT
    else:
        R_WT, p_WT = register_tracker(p_W, data.eta)
    residuals = data.eta @ R_WT.T + p_WT - p_W
    return ValidationResult(
        robot=robot.name,
        model_source=robot.source,
        data=data,
        residuals_W=residuals,
        R_WT=R_WT,
        p_WT=p_WT,
        registered=not keep_tracker,
        effects=tuple(e.name for e in effects),
        warnings=tuple(warnings),
    )


def predicted_world(model: TrackerModel, data: Measurements, effects=()) -> np.ndarray:
    """(n, 3) the reflector positions ``model`` predicts at the data's poses, in W [mm]; with
    ``effects`` under the data's conditions (taken to W with the model's tracker pose).

    Raises:
        InputError: a column an effect needs (``temperature_C``, ``time_s``) is missing.
    """
    if not effects:
        return reflector_world(model, data.q, data.target)
    for e in effects:
        col = _NEEDS.get(e.family)
        if col and getattr(data, col) is None:
            raise InputError(f"{data.path}: the model's {e.name} needs the {col} column, which the data lack")
    h = fx.true_measurements(
        model,
        data.q,
        effects,
        temperature_C=data.temperature_C,
        time_s=data.time_s,
        payload_kg=data.payload_kg,
        target=data.target,
    )
    return h @ model.R_WT.T + model.p_WT


def plot_validation(result: ValidationResult, folder: Path) -> list[Path]:
    """``validation_errors.png``: the 3-D error per pose (file row) and their histogram."""
    plt = pyplot()

    e = result.errors_mm
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
    ax1.plot(result.data.rows, e, ".", ms=4)
    ax1.axhline(np.mean(e), color="k", lw=0.8, label=f"mean {np.mean(e):.3f} mm")
    ax1.set(xlabel="row in the data file", ylabel="3-D error [mm]", title=f"{result.robot}: prediction error")
    ax1.legend()
    ax2.hist(e, bins=min(30, max(5, len(e) // 5)))
    ax2.set(xlabel="3-D error [mm]", ylabel="poses")
    fig.tight_layout()
    path = folder / "validation_errors.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def validate_file(
    robot: str,
    data_path: str | Path,
    *,
    data_format: str | Path | None = None,
    keep_tracker: bool = False,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    cell_path=None,
    force: bool = False,
) -> ValidationResult:
    """Validate a model on fresh measurements (``kpioed validate``); outputs written after all succeeded.

    Args:
        robot: model name or YAML path (e.g. the file ``kpioed calibrate --out`` wrote).
        data_path: the measurement file (SPEC layout, or another one with ``data_format``).
        data_format: format file of another layout (``docs/data-formats.md``).
        keep_tracker: use the model's tracker pose instead of re-registering it.
        json_path: JSON report; plots_dir: folder for ``validation_errors.png``.
        cell_path: cell file (default ``models/cell.yaml``).
        force: go on with implausible data (a warning in the report).
    """
    for name, flag in (("keep_tracker", keep_tracker), ("force", force)):
        require(isinstance(flag, bool), f"{name}: expected True or False, got {flag!r}", fields=(name,))
    rob, cell, data = read_inputs(
        robot, data_path, data_format, cell_path=cell_path, outputs=[json_path], folders=[plots_dir]
    )
    result = validate(rob, data, keep_tracker=keep_tracker, cell=cell, force=force)
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, result.to_dict())
        if plots_dir:
            plot_validation(result, staged.folder(plots_dir))
        staged.commit()
    return result
