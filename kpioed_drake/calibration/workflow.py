"""The ``kpioed calibrate`` workflow: read, calibrate (geometric or extended: the same fit and report), write
the outputs.

Outputs are staged while the work runs (:class:`~kpioed_drake.outputs.Outputs`) and written only
after everything succeeded, each atomically; a failing run writes nothing.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.inputs import read_inputs
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml, calibrated_urdf_files
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.plots import plot_calibration
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.effects import model_effects
from kpioed_drake.files.designs import parse_q_work
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.urdf.write import sidecar_of
from kpioed_drake.scene3d import calibration_page, probe_frames


def calibrate_file(
    robot: str,
    data_path: str | Path,
    options: CalibrationOptions | None = None,
    *,
    q_work_deg: str | None = None,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    cell_path: str | os.PathLike | None = None,
    data_format: str | Path | None = None,
) -> CalibrationReport:
    """Calibrate from a measurement file (``kpioed calibrate``): load the robot, cell and data once,
    :func:`~kpioed_drake.calibration.fit.calibrate`, write the outputs after all succeeded.

    Args:
        robot: model name or YAML path.
        data_path: the measurement CSV.
        options: :class:`~kpioed_drake.calibration.options.CalibrationOptions`; without effects, the
            effects of an extended model file are re-estimated.
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        out: calibrated robot model file (YAML; a URDF robot's ``.urdf`` plus sidecar) to write,
            with the estimated ``effects:`` of an extended model.
        json_path: JSON report to write.
        plots_dir: folder for the residual plots (PNG).
        html: 3-D page (Meshcat) of measured vs predicted points and the outliers (with a 6-DoF
            probe's orientations, its measured and predicted frames).
        cell_path: cell file (default ``models/cell.yaml``).
        data_format: format file of a measurement file of another layout (docs/data-formats.md).

    Returns:
        :class:`CalibrationReport` (its ``effects`` the estimated ones of an extended model).
    """
    options = options or CalibrationOptions()
    rob, cell, data = read_inputs(
        robot,
        data_path,
        data_format,
        cell_path=cell_path,
        model_out=out,
        outputs=[json_path],
        folders=[plots_dir],
        html=html,
    )
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    if not options.effects:  # an extended model file: its effects
        options = dataclasses.replace(options, effects=tuple(model_effects(rob)))
    report = calibrate(rob, data, options, q_work=qw, cell=cell)
    with Outputs() as staged:
        if out:
            stage_model(staged, report, out)
        if json_path:
            staged.add_json(json_path, report.to_dict())
        if plots_dir:
            plot_calibration(report, staged.folder(plots_dir))
        if html:
            staged.add_text(html, calibration_html(report, rob, cell))
        staged.commit()
    return report


def calibration_html(report: CalibrationReport, robot: Robot, cell: Cell) -> str:
    """The 3-D page of ``report`` (:func:`~kpioed_drake.scene3d.calibration_page`): measured vs
    predicted points, and with a 6-DoF probe's orientations its measured and predicted frames."""
    res, data, model = report.result, report.data, report.model
    probe = None
    if res.rot_residuals is not None and model.R_FP is not None:
        probe = probe_frames(model, data.q, res.rot_residuals @ model.R_WT.T, data.target)
    h = data.eta - res.residuals
    return calibration_page(robot, cell, model, data.q, data.eta, h, outliers=report.outliers, probe=probe)


def stage_model(staged: Outputs, report: CalibrationReport, out: str | Path) -> None:
    """Stage the calibrated (or extended) model of ``report`` as ``out``: a YAML model file, or for
    a URDF robot the URDF file and its sidecar beside it."""
    if Path(str(out)).suffix == ".urdf":
        urdf_text, side_text = calibrated_urdf_files(report)
        staged.add_text(out, urdf_text)
        staged.add_text(sidecar_of(out), side_text)
    else:
        staged.add_text(out, calibrated_robot_yaml(report))
