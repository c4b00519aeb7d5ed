"""``kpioed calibrate`` with plane contacts or distances: read the robot, cell and files once,
:func:`~kpioed_drake.calibration.contacts.fit.calibrate_contacts`, write the model file (the
estimated planes, pivots and bars in its ``contact_environment`` block), the JSON report and the
3-D page (:func:`calibration_page`) after all succeeded."""

from __future__ import annotations

import datetime
from pathlib import Path

from kpioed_drake.arguments import check_paths, require
from kpioed_drake.calibration.contacts.environment import environment_of
from kpioed_drake.calibration.contacts.fit import ContactCalibrationReport, calibrate_contacts
from kpioed_drake.calibration.modelfile import model_sidecar, robot_yaml
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Cell, load_cell, load_robot
from kpioed_drake.robot.reference import file_rows
from kpioed_drake.robot.urdf.write import calibrated_urdf, check_out_path, sidecar_of
from kpioed_drake.scene3d import contact_page
from kpioed_drake.tracker.contactdata import read_distances, read_planes
from kpioed_drake.tracker.data import read_data
from kpioed_drake.tracker.measurement import reflector_world


def calibrate_contacts_file(
    robot: str,
    data_path: str | Path | None = None,
    *,
    planes: str | Path | None = None,
    distances: str | Path | None = None,
    sigma_mm: float = 0.02,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    cell_path: str | Path | None = None,
    data_format: str | Path | None = None,
    max_iter: int = 100,
    html: str | Path | None = None,
) -> ContactCalibrationReport:
    """Calibrate from a plane-contact file, a distance file, or both, with an optional measurement
    file of tracker points (docs/contacts.md).

    Args:
        robot: model name or file; data_path: tracker points (None: none).
        planes, distances: the contact files (:mod:`kpioed_drake.files.contacts`).
        sigma_mm: the tracker points' noise per coordinate [mm].
        out: the calibrated model file (YAML; a URDF robot's ``.urdf`` and sidecar).
        json_path: the JSON report; cell_path: the cell file; data_format: the points' format file.
        html: a 3-D page (Meshcat) of the estimated planes, pivots and bars, the touch points and
            the distance rows coloured by their residuals (:func:`~kpioed_drake.scene3d.contact_page`).

    Raises:
        InputError: a bad path or file (naming the file, row and column), or data the fit refuses.
    """
    side = sidecar_of(out) if out is not None and Path(str(out)).suffix == ".urdf" else None
    check_paths(
        robot=robot,
        inputs=[data_path, data_format, planes, distances],
        outputs=[out, side, json_path],
        html=html,
    )
    rob = load_robot(robot)
    check_out_path(rob, out)
    cell = load_cell(cell_path, robot=rob)
    data = None if data_path is None else read_data(data_path, rob, data_format)
    plane_rows = None if planes is None else read_planes(planes, rob)
    distance_rows = None if distances is None else read_distances(distances, rob)
    sources = tuple(str(p) for p in (data_path, planes, distances) if p is not None)
    report = calibrate_contacts(
        rob,
        cell,
        planes=plane_rows,
        distances=distance_rows,
        data=data,
        sigma_mm=sigma_mm,
        max_iter=max_iter,
        sources=sources,
    )
    with Outputs() as staged:
        if out:
            for path, text in model_files(report, out):
                staged.add_text(path, text)
        if json_path:
            staged.add_json(json_path, report.to_dict())
        if html:
            staged.add_text(html, calibration_page(report, cell))
        staged.commit()
    return report


def calibration_page(report: ContactCalibrationReport, cell: Cell) -> str:
    """The 3-D page of a contact calibration: the fitted rows and the estimated environment, and the
    tracker points with their residuals (in W) if any."""
    c, model, data = report.result.contacts, report.model, report.data
    points = None
    if data is not None:
        p_pred = reflector_world(model, data.q, data.target)
        points = (data.q, p_pred, report.result.residuals @ model.R_WT.T)
    rows = dict(planes=(c.planes, c.plane_residuals), distances=(c.distances, c.distance_residuals))
    return contact_page(report.robot, cell, model, **rows, points=points)


def model_files(report: ContactCalibrationReport, out: str | Path) -> list[tuple[str | Path, str]]:
    """(path, text) of the calibrated model: a YAML model file, or a URDF and its sidecar; the
    estimated planes, pivots and bars in ``contact_environment``."""
    rob, model = report.robot, report.model
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    note = (
        f"Calibrated by kpioed calibrate from {', '.join(report.sources)} ({stamp}): "
        f"chi2/dof {report.result.chi2_per_dof:.3g}; contact_environment: the estimated planes, pivots, bars."
    )
    env = environment_of(model)
    errors = file_rows(rob, model.geometry - rob.geometry)
    if Path(str(out)).suffix != ".urdf":
        return [(out, robot_yaml(rob, model, note=note, estimated_errors=errors, environment=env))]
    side = model_sidecar(rob, model, note=note, estimated_errors=errors, environment=env)
    return [(out, calibrated_urdf(rob, model.geometry, note.replace("--", "-"))), (sidecar_of(out), side)]


UNSUPPORTED = ("extend", "plots_dir", "q_work_deg")
""":func:`kpioed_drake.api.calibrate` arguments a contact calibration does not take."""


def contact_calibration(
    robot: str, data_path: str | Path | None, planes, distances, arguments: dict
) -> ContactCalibrationReport:
    """:func:`calibrate_contacts_file` with the arguments of :func:`kpioed_drake.api.calibrate` (its
    ``locals()``); one it does not take (:data:`UNSUPPORTED`) given is an error naming it, and so
    are no files at all."""
    require(
        planes is not None or distances is not None,
        "data_path: give a measurement file, planes or distances",
        fields=("data_path",),
    )
    for name in UNSUPPORTED:
        require(not arguments.get(name), f"{name}: not taken with planes or distances", fields=(name,))
    return calibrate_contacts_file(
        robot,
        data_path,
        planes=planes,
        distances=distances,
        sigma_mm=arguments["sigma_mm"],
        out=arguments["out"],
        json_path=arguments["json_path"],
        cell_path=arguments["cell_path"],
        data_format=arguments["data_format"],
        html=arguments["html"],
    )
