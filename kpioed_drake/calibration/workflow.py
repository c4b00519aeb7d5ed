"""The ``kpioed calibrate`` workflow: read, calibrate (geometric or extended: the same fit and report), write
the outputs.

Outputs are staged while the work runs (:class:`~kpioed_drake.outputs.Outputs`) and written only
after everything succeeded, each atomically; a failing run writes nothing.
"""

from __future__ import annotations

from pathlib import Path

from kpioed_drake.arguments import check_paths, require
from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml, calibrated_urdf_files
from kpioed_drake.calibration.plots import plot_calibration
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.effects import model_effects
from kpioed_drake.errors import check_sigma
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.robot.urdfwrite import check_out_path, sidecar_of
from kpioed_drake.scene3d import calibration_page
from kpioed_drake.tracker.csvio import parse_q_work
from kpioed_drake.tracker.formats import read_data


def calibrate_file(
    robot: str,
    data_path: str | Path,
    *,
    sigma_mm: float = 0.02,
    q_work_deg: str | None = None,
    extend=(),
    outlier_alpha: float = 0.01,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    cell_path=None,
    force: bool = False,
    data_format: str | Path | None = None,
    strict: bool = False,
) -> CalibrationReport:
    """Calibrate from a measurement file (``kpioed calibrate``); outputs written after all succeeded.

    Args:
        robot: model name or YAML path.
        data_path: the measurement CSV.
        sigma_mm: noise standard deviation per coordinate [mm].
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        extend: effect texts (e.g. ``["joint_elasticity:2"]``, joints 1..n_joints): calibrate the
            geometry and these effects together (the extended model; ``out`` writes it with its
            ``effects:``); without it, the effects of an extended model file are re-estimated.
        outlier_alpha: family-wise false-alarm level of the outlier test, in [0, 1) (0: no test).
        out: calibrated robot model file (YAML; a URDF robot's ``.urdf`` plus sidecar) to write.
        json_path: JSON report to write.
        plots_dir: folder for the residual plots (PNG).
        html: 3-D page (Meshcat) of measured vs predicted points and the outliers.
        force: go on with implausible data (:mod:`kpioed_drake.estimation.plausibility`), with a warning.
        data_format: format file of a measurement file of another layout (docs/data-formats.md).
        strict: refuse poses that do not determine every parameter (InputError) instead of holding
            the undetermined ones at nominal with a warning (geometric calibration only).

    Returns:
        :class:`CalibrationReport` (its ``effects`` the estimated ones with ``extend``).
    """
    check_sigma(sigma_mm)
    ok = isinstance(outlier_alpha, int | float) and 0 <= outlier_alpha < 1
    require(ok, f"outlier_alpha: expected a number in [0, 1), got {outlier_alpha!r}")
    side_out = sidecar_of(out) if out is not None and Path(str(out)).suffix == ".urdf" else None
    check_paths(
        robot=robot,
        inputs=[data_path, data_format],
        outputs=[out, side_out, json_path],
        folders=[plots_dir],
        html=html,
    )
    rob = load_robot(robot)
    check_out_path(rob, out)
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    data = read_data(data_path, rob, data_format)
    effects = list(extend) if extend else model_effects(rob)  # an extended model file: its effects
    options = dict(q_work=qw, outlier_threshold=outlier_alpha, force=force, strict=strict, effects=effects)
    report = calibrate(rob, data, sigma_mm=sigma_mm, cell_path=cell_path, **options)
    with Outputs() as staged:
        if out:
            stage_model(staged, report, out)
        if json_path:
            staged.add_json(json_path, report.to_dict())
        if plots_dir:
            plot_calibration(report, staged.folder(plots_dir))
        if html:
            res = report.result
            page = calibration_page(
                rob,
                load_cell(cell_path, robot=rob),
                report.model,
                data.q,
                data.eta,
                data.eta - res.residuals,
                outliers=report.outliers,
            )
            staged.add_text(html, page)
        staged.commit()
    return report


def stage_model(staged: Outputs, report: CalibrationReport, out: str | Path) -> None:
    """Stage the calibrated (or extended) model of ``report`` as ``out``: a YAML model file, or for
    a URDF robot the URDF file and its sidecar beside it."""
    if Path(str(out)).suffix == ".urdf":
        urdf_text, side_text = calibrated_urdf_files(report)
        staged.add_text(out, urdf_text)
        staged.add_text(sidecar_of(out), side_text)
    else:
        staged.add_text(out, calibrated_robot_yaml(report))
