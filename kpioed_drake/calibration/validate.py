"""Validation of a model on fresh data: how well does it predict measurements it has not seen?

``kpioed validate --robot MODEL DATA.csv`` predicts every measured reflector position with the
given model (its joint rows and reflector offset, paper eq. 3 ``h(p, q)``) and compares. Nothing
is fitted to the poses scored unless the result says so; the tracker frame (``tracker_frame``,
:data:`METHODS`) is

- ``kept``: the model's tracker pose, as a calibration estimated it (the model file's
  ``tracker_position_mm``, ``tracker_rpy_deg``); for data in the base frame (``frame: base``) and a
  model without one, the identity. The default where the model has a tracker pose or the data are in
  the base frame: the data of the calibration's tracker set-up.
- ``cross``: the tracker has moved (another session): cross-registered. The poses are split in two
  halves (alternate poses in the order of the file, a pose's targets together), the tracker frame
  registered (rigid, 6 DoF, Kabsch/Umeyama: :func:`kpioed_drake.estimation.estimator.register_tracker`)
  on one half and the other half scored, then the halves swapped; the figures pool both halves'
  out-of-sample errors. The default for a model without a tracker pose (a nominal model file):
  keeping the cell file's nominal tracker pose would score the set-up, not the model, and is refused.
- ``in-sample``: registered on the poses scored (6 parameters fitted to them): optimistic, labelled
  so.

With ``kept`` the errors are compared with the cross-registered ones as well: a kept frame that
predicts much worse than one registered on other poses (:data:`MOVED_RATIO`) means the tracker moved
(a warning).

Several targets (a ``target`` column): each row is predicted with its target's offset from the
model file (``targets_mm``); the report gives the errors per target as well.

An extended model (a model file with ``effects:``) predicts with its effects: the per-pose
conditions they need come from the data (``temperature_C`` for thermal expansion and tracker scale,
``time_s`` for tracker drift: an error names a missing column; ``payload_kg`` when given, else no
payload), the tracker-frame prediction is taken to W with the model's tracker pose, then registered
(when the method registers).

Nothing robot-side is fitted, so the errors are prediction errors: for a nominal model they are its
absolute accuracy (the "uncalibrated" error), for a calibrated one its accuracy after calibration.
The figures are those of every report (:mod:`kpioed_drake.estimation.accuracy`).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix

from kpioed_drake import effects as fx
from kpioed_drake.arguments import require
from kpioed_drake.calibration.inputs import read_inputs
from kpioed_drake.calibration.plots import plot_validation
from kpioed_drake.calibration.robust import pose_groups
from kpioed_drake.effects.model import Effect
from kpioed_drake.errors import InputError, param
from kpioed_drake.estimation.accuracy import Figures, OrientationFigures, accuracy, orientation_accuracy
from kpioed_drake.estimation.estimator import register_tracker
from kpioed_drake.estimation.plausibility import check_data
from kpioed_drake.files.tables import ROW_CONVENTION
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.scene3d import probe_frames, validation_page
from kpioed_drake.tracker.data import Measurements, counted, n_poses
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model, reflector_world
from kpioed_drake.tracker.orientation import world_orientation_errors

_NEEDS = {"thermal_expansion": "temperature_C", "tracker_scale": "temperature_C", "tracker_drift": "time_s"}
"""The data column an effect's prediction needs."""
METHODS = {
    "kept": "kept",
    "cross": "cross-registered (2 halves)",
    "in-sample": "registered in-sample",
}
"""The tracker frame of a validation (``tracker_frame``) -> the JSON's ``tracker.method``."""
MOVED_RATIO = 1.5
"""A kept tracker frame whose mean error exceeds this times the cross-registered one's is reported
as moved (a warning): on the calibration's set-up the two agree (the public UR10 set's same session:
0.442 and 0.440 mm), on another one they do not (its other session: 1.600 and 0.851 mm)."""


@dataclasses.dataclass(frozen=True)
class ValidationReport:
    """Prediction errors of a model on measured data.

    Attributes:
        robot: the model's name.
        model_source: the model file.
        data: the measurements.
        residuals_W: (n, 3) measured minus predicted reflector position, in W [mm].
        method: the tracker frame, a key of :data:`METHODS`.
        frames: the tracker frames used, ``(R_WT (3, 3), p_WT (3,) [mm])``: one (kept, in-sample),
            or one per half (cross: the frame registered on the other half scores the half).
        halves: (n,) the half (0, 1) of each row (cross), else None.
        effects: the names of the model's non-geometric effects it predicted with (empty: geometric).
        warnings: the plausibility checks' remarks (``force`` turns a refusal into one), a moved tracker.
        notes: why the method was chosen when it was not given.
        rot_residuals_W: (n, 3) a 6-DoF probe's orientation errors ``log(R_meas R_pred^T)`` in W axes
            with the same tracker frames [rad], or None (no orientations, or a model without a
            probe orientation: a note says so).
    """

    robot: str
    model_source: str
    data: Measurements
    residuals_W: np.ndarray
    method: str
    frames: tuple[tuple[np.ndarray, np.ndarray], ...]
    halves: np.ndarray | None = None
    effects: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    rot_residuals_W: np.ndarray | None = None

    @property
    def registered(self) -> bool:
        """The tracker frame was registered to the data (cross or in-sample), not kept."""
        return self.method != "kept"

    @property
    def R_WT(self) -> np.ndarray:
        """(3, 3) the tracker orientation used (cross: the one registered on the second half)."""
        return self.frames[-1][0]

    @property
    def p_WT(self) -> np.ndarray:
        """(3,) the tracker position used [mm] (cross: the one registered on the second half)."""
        return self.frames[-1][1]

    @property
    def errors_mm(self) -> np.ndarray:
        """(n,) 3-D prediction error of each row [mm]."""
        return np.linalg.norm(self.residuals_W, axis=1)

    def figures(self) -> Figures:
        """The accuracy figures (:func:`kpioed_drake.estimation.accuracy.accuracy`), held-out."""
        return accuracy(
            self.residuals_W, self.data.q, kind="held-out", tracker=self.method, target=self.data.target
        )

    def orientation_figures(self) -> OrientationFigures | None:
        """The orientation figures (held-out, the position figures' tracker frame), or None."""
        if self.rot_residuals_W is None:
            return None
        return orientation_accuracy(self.rot_residuals_W, kind="held-out", tracker=self.method)

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
                    "p95_error_mm": float(np.percentile(e, 95)) if e.size else None,
                    "max_error_mm": float(np.max(e)) if e.size else None,
                }
            )
        return out

    def tracker(self) -> dict:
        """The JSON's ``tracker`` block: the method and the frames used (mm, deg)."""
        frames = [
            {
                "p_WT_mm": p.tolist(),
                "rpy_deg": np.rad2deg(RollPitchYaw(RotationMatrix(R)).vector()).tolist(),
                **({"scores_half": k + 1, "registered_on_half": 2 - k} if self.method == "cross" else {}),
            }
            for k, (R, p) in enumerate(self.frames)
        ]
        return {
            "method": METHODS[self.method],
            "key": self.method,
            "registered": self.registered,
            "frames": frames,
            "p_WT_mm": self.p_WT.tolist(),
            "rpy_deg": frames[-1]["rpy_deg"],
            "halves": None if self.halves is None else [int(h) + 1 for h in self.halves],
            "note": "kept: the model's tracker frame (nothing fitted to these poses); cross-registered: "
            "registered on one half of the poses (alternate poses, a pose's targets together) and "
            "scored on the other, both ways; registered in-sample: fitted to the poses scored "
            "(optimistic)",
        }

    def to_dict(self) -> dict:
        """The JSON report (mm, deg)."""
        fig = self.figures()
        return {
            "robot": self.robot,
            "model": self.model_source,
            "data": self.data.path,
            "frame": self.data.frame,
            "n_poses": n_poses(self.data),
            "n_rows": self.data.n,
            "rms_mm": fig.rms_mm,
            "rms_xyz_mm": list(fig.rms_xyz_mm),
            "mean_error_mm": fig.mean_error_mm,
            "p95_error_mm": fig.p95_error_mm,
            "max_error_mm": fig.max_error_mm,
            "errors_mm": self.errors_mm.tolist(),
            "figures": fig.to_dict(),
            "orientation_figures": None if (o := self.orientation_figures()) is None else o.to_dict(),
            "targets": self.per_target(),
            "rows": [int(r) for r in self.data.rows],
            "row_convention": ROW_CONVENTION,
            "residuals_W_mm": self.residuals_W.tolist(),
            "effects": list(self.effects),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "tracker": self.tracker(),
            "note": "measured minus predicted reflector position in W; rms_mm over all coordinates, "
            "rms_xyz_mm per axis; *_error_mm of the 3-D distance per row; nothing robot-side is fitted; "
            "the tracker frame as tracker.method says",
        }

    def summary(self) -> str:
        """A human-readable summary."""
        return "\n".join(
            [
                f"{self.robot}"
                + (f" (with {', '.join(self.effects)})" if self.effects else "")
                + f": validated on {self.data.path}: {counted(self.data)}",
                *self.figures().lines(),
                *(o.lines() if (o := self.orientation_figures()) is not None else []),
                *(f"  note: {n}" for n in self.notes),
                *(f"  warning: {w}" for w in self.warnings),
            ]
        )


def choose_method(robot: Robot, data: Measurements, tracker_frame: str | None) -> tuple[str, list[str]]:
    """The tracker frame of a validation: ``tracker_frame``, or by default ``kept`` where the model has a
    tracker pose (or the data are in the base frame) and ``cross`` otherwise; and a note saying why
    when it was not given.

    Raises:
        InputError: ``kept`` for tracker-frame data with a model whose tracker pose was never
            estimated (the cell file's nominal pose would score the set-up, not the model).
    """
    own = robot.X_WT is not None or data.frame == "base"
    if tracker_frame is None:
        if own:
            return "kept", []
        return "cross", [
            f"{robot.source or robot.name} has no estimated tracker pose (tracker_position_mm), so the "
            "tracker frame is cross-registered: registered on one half of the poses and scored on the "
            f"other, both ways ({param('tracker_frame')} chooses)"
        ]
    if tracker_frame == "kept" and not own:
        raise InputError(
            f"{robot.source or robot.name}: tracker_frame kept, but the model file has no estimated "
            "tracker pose (tracker_position_mm, tracker_rpy_deg; a calibrated model file has them): the "
            "cell file's nominal tracker pose would score the set-up, not the model (errors of metres); "
            "use tracker_frame 'cross' (registered on other poses than those scored) or validate a "
            "calibrated model file",
            fields=("tracker_frame",),
        )
    return tracker_frame, []


def cross_residuals(p_W: np.ndarray, data: Measurements) -> tuple[np.ndarray, tuple, np.ndarray]:
    """Residuals in W of every row with the tracker frame registered on the other half of the poses.

    Halves: the poses in the order of appearance, alternately (pose 1, 3, 5, ... and 2, 4, 6, ...),
    the rows of one pose's targets together.

    Returns:
        residuals (n, 3) [mm], frames ``((R, p) scoring half 1, (R, p) scoring half 2)``, halves (n,).

    Raises:
        InputError: a half with fewer than 3 points or collinear points.
    """
    halves = pose_groups(data) % 2
    residuals = np.empty_like(p_W)
    frames = []
    for h in (0, 1):
        test, train = halves == h, halves != h
        try:
            R, p = register_tracker(p_W[train], data.eta[train])
        except InputError as exc:
            raise InputError(
                f"{data.path}: cross-registration of the tracker frame needs 3 or more non-collinear points "
                f"in each half of the poses ({counted(data)}): {exc}",
                fields=("tracker_frame",),
            ) from None
        residuals[test] = data.eta[test] @ R.T + p - p_W[test]
        frames.append((R, p))
    return residuals, tuple(frames), halves


def validate(
    robot: Robot,
    data: Measurements,
    *,
    tracker_frame: str | None = None,
    keep_tracker: bool | None = None,
    cell: Cell | None = None,
    force: bool = False,
) -> ValidationReport:
    """Prediction errors of ``robot`` (a nominal or calibrated model) on ``data``.

    Args:
        robot: the model (joint rows; reflector offset, further targets and tracker pose from
            the robot file when it has them, else from the cell file).
        data: the measurements (tracker or base frame).
        tracker_frame: a key of :data:`METHODS` (``kept``, ``cross``, ``in-sample``);
            None: ``kept`` where the model has a tracker pose or the data are in the base frame
            (the identity without one), else ``cross``.
        keep_tracker: True is ``tracker_frame="kept"``, False is ``tracker_frame="cross"``.
        cell: the measuring cell (default ``models/cell.yaml``).
        force: go on with implausible data, with a warning in the result.

    Returns:
        :class:`ValidationReport`.

    Raises:
        InputError: too few poses or collinear points (the tracker frame is undetermined), a kept
            tracker pose never estimated, or implausible data
            (:func:`kpioed_drake.estimation.plausibility.check_data`: other length units, gross
            errors, another robot or a wrong joint map).
    """
    method, notes = choose_method(robot, data, _method(tracker_frame, keep_tracker))
    model = nominal_model(robot, load_cell(robot=robot) if cell is None else cell)
    warnings = check_data(model, data, n_params=6, force=force)
    effects = fx.model_effects(robot)
    p_W = predicted_world(model, data, effects)
    halves = None
    if method == "cross":
        residuals, frames, halves = cross_residuals(p_W, data)
    else:
        if method == "in-sample":
            R_WT, p_WT = register_tracker(p_W, data.eta)
        elif robot.X_WT is None and data.frame == "base":
            R_WT, p_WT = np.eye(3), np.zeros(3)
        else:
            R_WT, p_WT = model.R_WT, model.p_WT
        residuals, frames = data.eta @ R_WT.T + p_WT - p_W, ((R_WT, p_WT),)
        if method == "kept":
            warnings += _moved(residuals, p_W, data)
    rot, more = _orientation_errors(model, data, frames, halves, effects)
    return ValidationReport(
        rot_residuals_W=rot,
        robot=robot.name,
        model_source=robot.source,
        effects=tuple(e.name for e in effects),
        data=data,
        residuals_W=residuals,
        warnings=tuple(warnings),
        method=method,
        frames=frames,
        halves=halves,
        notes=tuple(notes + more),
    )


def _orientation_errors(model: TrackerModel, data: Measurements, frames, halves, effects) -> tuple:
    """A probe's orientation errors in W with the position figures' tracker frames (cross: each
    half's), and the note when the data's orientations are not scored (the model has no probe
    orientation, or effects whose orientations are not modelled)."""
    if data.R_TP is None:
        return None, []
    if model.R_FP is None or effects:
        why = "has effects, whose orientation is not modelled" if effects else "has no probe orientation"
        return None, [
            f"the data's 6-DoF orientations are not scored: the model {why} (probe_rpy_deg: a "
            "calibration from data with orientations writes it)"
        ]
    R_WT = frames[0][0] if halves is None else np.stack([f[0] for f in frames])[halves]
    return world_orientation_errors(model, data.q, data.R_TP, R_WT), []


def _method(tracker_frame, keep_tracker) -> str | None:
    """``tracker_frame`` checked, with the older ``keep_tracker`` (True: kept, False: cross) folded in."""
    require(
        tracker_frame is None or tracker_frame in METHODS,
        f"tracker_frame: expected one of {', '.join(METHODS)} (or None: the default), got {tracker_frame!r}",
        fields=("tracker_frame",),
    )
    require(
        keep_tracker is None or isinstance(keep_tracker, bool),
        f"keep_tracker: expected True or False, got {keep_tracker!r}",
        fields=("keep_tracker",),
    )
    if keep_tracker is None:
        return tracker_frame
    alias = "kept" if keep_tracker else "cross"
    require(
        tracker_frame in (None, alias),
        f"keep_tracker {keep_tracker} and tracker_frame {tracker_frame!r} contradict each other; give one",
        fields=("keep_tracker", "tracker_frame"),
    )
    return alias


def _moved(residuals: np.ndarray, p_W: np.ndarray, data: Measurements) -> list[str]:
    """A warning when the kept tracker frame predicts much worse than a cross-registered one (the
    tracker moved since the calibration); none when it does not, or the halves are too small."""
    try:
        cross = cross_residuals(p_W, data)[0]
    except InputError:
        return []
    kept_mean, cross_mean = np.linalg.norm(residuals, axis=1).mean(), np.linalg.norm(cross, axis=1).mean()
    if kept_mean <= MOVED_RATIO * cross_mean:
        return []
    return [
        f"the kept tracker frame predicts with a mean error of {kept_mean:.4g} mm, the tracker frame "
        f"cross-registered on these poses with {cross_mean:.4g} mm: the tracker has probably moved since "
        f"the calibration (another set-up); {param('tracker_frame')} 'cross' scores the model without it"
    ]


def predicted_world(model: TrackerModel, data: Measurements, effects: Sequence[Effect] = ()) -> np.ndarray:
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


def validate_file(
    robot: str,
    data_path: str | Path,
    *,
    data_format: str | Path | None = None,
    tracker_frame: str | None = None,
    keep_tracker: bool | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    cell_path: str | os.PathLike | None = None,
    force: bool = False,
    html: str | Path | None = None,
) -> ValidationReport:
    """Validate a model on fresh measurements (``kpioed validate``); outputs written after all succeeded.

    Args:
        robot: model name or YAML path (e.g. the file ``kpioed calibrate --out`` wrote).
        data_path: the measurement file (SPEC layout, or another one with ``data_format``).
        data_format: format file of another layout (``docs/data-formats.md``).
        tracker_frame: ``kept`` (the model's tracker frame), ``cross`` (the tracker moved: registered on
            one half of the poses, scored on the other) or ``in-sample`` (registered on the poses
            scored: optimistic); default ``kept`` where the model has an estimated tracker pose or
            the data are in the base frame, else ``cross`` (:func:`validate`).
        keep_tracker: True is ``tracker_frame="kept"``, False ``tracker_frame="cross"``.
        json_path: JSON report; plots_dir: folder for ``validation_errors.png``.
        cell_path: cell file (default ``models/cell.yaml``).
        force: go on with implausible data (a warning in the report).
        html: 3-D page (Meshcat) of the predicted points and the prediction errors (with a 6-DoF
            probe's orientations, its measured and predicted frames).
    """
    require(isinstance(force, bool), f"force: expected True or False, got {force!r}", fields=("force",))
    _method(tracker_frame, keep_tracker)
    files = dict(outputs=[json_path], folders=[plots_dir], html=html)
    rob, cell, data = read_inputs(robot, data_path, data_format, cell_path=cell_path, **files)
    result = validate(
        rob, data, tracker_frame=tracker_frame, keep_tracker=keep_tracker, cell=cell, force=force
    )
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, result.to_dict())
        if plots_dir:
            title = f"{result.robot}: prediction error, tracker frame {METHODS[result.method]}"
            plot_validation(result.errors_mm, result.data.rows, title, staged.folder(plots_dir))
        if html:
            staged.add_text(html, validation_html(result, rob, cell))
        staged.commit()
    return result


def validation_html(result: ValidationReport, robot: Robot, cell: Cell) -> str:
    """The 3-D page of ``result`` (:func:`~kpioed_drake.scene3d.validation_page`): the predicted
    points and the prediction errors, and a 6-DoF probe's measured and predicted frames."""
    model, data, rot = nominal_model(robot, cell), result.data, result.rot_residuals_W
    p_W = predicted_world(model, data, fx.model_effects(robot))
    probe = None if rot is None else probe_frames(model, data.q, rot, data.target)
    shown = dict(q=data.q, predicted_W=p_W, residuals_W=result.residuals_W, label=result.method)
    return validation_page(robot, cell, **shown, probe=probe)
