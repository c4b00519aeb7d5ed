"""``kpioed validate`` with plane contacts or distances: a model's prediction errors on held-out
contacts (:func:`validate_contacts_file`, :class:`ContactValidationReport`).

A calibrated model file carries the planes, pivots and bars its calibration estimated
(``contact_environment``): the held-out rows are scored with them and nothing is fitted. A model
without them (a nominal model) has no planes: then the planes, pivots and bars alone are fitted to
the rows scored, the robot held (:func:`~kpioed_drake.calibration.contacts.environment.fit_environment`),
and the report says so: those figures are in-sample for the environment, the robot's errors
held-out. Units: millimetres.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from kpioed_drake.arguments import check_paths, require
from kpioed_drake.calibration.contacts.environment import (
    figures_line,
    fit_environment,
    model_environment,
    residual_figures,
    spec_model,
)
from kpioed_drake.calibration.validate import ValidationReport, predicted_world, validate
from kpioed_drake.effects import model_effects
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.scene3d import contact_page
from kpioed_drake.tracker.contactdata import read_distances, read_planes
from kpioed_drake.tracker.contacts import ContactRows
from kpioed_drake.tracker.data import read_data
from kpioed_drake.tracker.measurement import nominal_model

MODEL_ENVIRONMENT = "held-out: the model file's planes, pivots and bars; nothing fitted"
FITTED_ENVIRONMENT = (
    "the model has no planes (a nominal model): the planes, pivots and bars were fitted to these rows "
    "with the robot held; the robot held-out, the environment in-sample"
)


@dataclasses.dataclass(frozen=True)
class ContactValidationReport:
    """Prediction errors of held-out contacts.

    Attributes:
        robot: the model's name; environment: :data:`MODEL_ENVIRONMENT` or :data:`FITTED_ENVIRONMENT`.
        fitted: the environment was fitted to the rows scored (the model has none).
        plane_residuals: (n_p,) signed distance minus the measured one [mm].
        distance_residuals: (n_d,) model minus measured length [mm].
        points: the tracker points' validation (a measurement file given too), or None.
    """

    robot: str
    environment: str
    fitted: bool
    plane_residuals: object
    distance_residuals: object
    has_planes: bool
    has_distances: bool
    points: ValidationReport | None = None

    def figures(self) -> dict:
        """``planes`` and ``distances``: ``n``, ``rms_mm``, ``mean_mm`` (of |r|), ``p95_mm``, ``max_mm``."""
        out = {}
        if self.has_planes:
            out["planes"] = residual_figures(self.plane_residuals)
        if self.has_distances:
            out["distances"] = residual_figures(self.distance_residuals)
        return out

    @property
    def label(self) -> str:
        return "held-out, planes fitted (robot held)" if self.fitted else "held-out"

    def to_dict(self) -> dict:
        out = {
            "robot": self.robot,
            "label": self.label,
            "environment": self.environment,
            "environment_fitted": self.fitted,
            "figures": self.figures(),
        }
        if self.points is not None:
            out["points"] = self.points.to_dict()
        return out

    def summary(self) -> str:
        names = {"planes": "plane distances", "distances": "length errors"}
        lines = [f"Validation of {self.robot} on contacts ({self.environment}):"]
        lines += [figures_line(f"{names[k]} [{self.label}]", f) for k, f in self.figures().items()]
        if self.points is not None:
            lines += ["", self.points.summary()]
        return "\n".join(lines)


def validate_contacts_file(
    robot: str,
    data_path: str | Path | None = None,
    *,
    planes: str | Path | None = None,
    distances: str | Path | None = None,
    json_path: str | Path | None = None,
    cell_path: str | Path | None = None,
    data_format: str | Path | None = None,
    tracker_frame: str | None = None,
    keep_tracker: bool | None = None,
    force: bool = False,
    html: str | Path | None = None,
) -> ContactValidationReport:
    """Score held-out plane contacts and distances (module docstring), and a measurement file's
    points if given (:func:`kpioed_drake.calibration.validate.validate`, with ``data_format``,
    ``tracker_frame``, ``keep_tracker``, ``force``); ``html``: a 3-D page of the rows scored, the
    model's (or the fitted) planes, pivots and bars and the residuals
    (:func:`~kpioed_drake.scene3d.contact_page`).

    Raises:
        InputError: a bad path or file (naming the file, row and column: a plane, pivot or bar id
            beyond the model file's), or rows that do not determine a fitted plane or pivot.
    """
    check_paths(
        robot=robot, inputs=[data_path, data_format, planes, distances], outputs=[json_path], html=html
    )
    rob = load_robot(robot)
    cell = load_cell(cell_path, robot=rob)
    env = model_environment(rob)
    base = nominal_model(rob, cell)
    counts = (
        {}
        if env is None
        else {"planes": len(env.planes), "pivots": len(env.pivots_mm), "bars": len(env.bars_dL_mm)}
    )
    fit = env is None  # a nominal model: the planes, pivots, bars the rows use are fitted to them
    p_rows = None if planes is None else read_planes(planes, rob, n_planes=counts.get("planes"), renumber=fit)
    d_rows = (
        None
        if distances is None
        else read_distances(
            distances, rob, n_pivots=counts.get("pivots"), n_bars=counts.get("bars"), renumber=fit
        )
    )
    model = fit_environment(base, d_rows, p_rows) if env is None else spec_model(base, env)
    d_res, p_res = ContactRows(d_rows, p_rows).residuals(model)
    points = None
    if data_path is not None:
        data = read_data(data_path, rob, data_format)
        points = validate(
            rob, data, tracker_frame=tracker_frame, keep_tracker=keep_tracker, cell=cell, force=force
        )
    report = ContactValidationReport(
        rob.name,
        FITTED_ENVIRONMENT if env is None else MODEL_ENVIRONMENT,
        env is None,
        p_res,
        d_res,
        p_rows is not None,
        d_rows is not None,
        points,
    )
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, report.to_dict())
        if html:
            rows = dict(planes=(p_rows, p_res), distances=(d_rows, d_res), points=_points(points, rob, cell))
            page = contact_page(rob, cell, model, **rows, kind="validation")
            staged.add_text(html, page)
        staged.commit()
    return report


def _points(points: ValidationReport | None, robot, cell) -> tuple | None:
    """(q, predicted (n, 3), residuals (n, 3)) in W [mm] of a validation's tracker points, or None."""
    if points is None:
        return None
    model = nominal_model(robot, cell)
    return points.data.q, predicted_world(model, points.data, model_effects(robot)), points.residuals_W


def contact_validation(
    robot: str, data_path: str | Path | None, planes, distances, arguments: dict
) -> ContactValidationReport:
    """:func:`validate_contacts_file` with the arguments of :func:`kpioed_drake.api.validate` (its
    ``locals()``); plots, or no file at all, are errors naming the argument."""
    require(
        planes is not None or distances is not None,
        "data_path: give a measurement file, planes or distances",
        fields=("data_path",),
    )
    require(not arguments.get("plots_dir"), "plots_dir: no plots of contacts", fields=("plots_dir",))
    names = ("json_path", "cell_path", "data_format", "tracker_frame", "keep_tracker", "force", "html")
    return validate_contacts_file(
        robot, data_path, planes=planes, distances=distances, **{n: arguments[n] for n in names}
    )
