"""A calibration from plane contacts and distances, alone or with laser-tracker points:
:func:`calibrate_contacts` (one :func:`~kpioed_drake.estimation.estimator.estimate` on every row)
and its :class:`ContactCalibrationReport` (the fit's figures per system, the gauge and why, the
estimated planes, pivots and bars).

Units: millimetres and radians inside; the report prints millimetres and degrees.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.calibration.contacts.environment import environment_of, figures_line, residual_figures
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import Conditions, EstimationResult, estimate
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model


@dataclasses.dataclass(frozen=True)
class ContactCalibrationReport:
    """The outcome of :func:`calibrate_contacts`.

    Attributes:
        robot: the nominal robot; result: the estimate (``result.contacts``: rows, residuals, gauge).
        data: the tracker rows (None: none); sigma_mm: their noise per coordinate [mm].
        sources: the files read, for the model file's note.
    """

    robot: Robot
    result: EstimationResult
    data: Measurements | None
    sigma_mm: float
    sources: tuple[str, ...] = ()

    @property
    def model(self) -> TrackerModel:
        return self.result.model

    def figures(self) -> dict:
        """The fit's residual figures per system (:func:`residual_figures`): ``planes`` (signed
        distances [mm]), ``distances`` (length errors [mm]), ``points`` (3-D errors [mm])."""
        c = self.result.contacts
        out = {}
        if c.planes is not None:
            out["planes"] = residual_figures(c.plane_residuals)
        if c.distances is not None:
            out["distances"] = residual_figures(c.distance_residuals)
        if self.data is not None:
            out["points"] = residual_figures(np.linalg.norm(self.result.residuals, axis=1))
        return out

    def to_dict(self) -> dict:
        res, env = self.result, environment_of(self.model)
        gauge = res.contacts.gauge
        return {
            "label": "fit",
            "figures": self.figures(),
            "chi2_per_dof": float(res.chi2_per_dof),
            "n_params": int(res.n_params),
            "gauge": {
                "held": list(gauge.names),
                "reasons": dict(zip(gauge.held, gauge.reasons, strict=True)),
                "tracker_rows": gauge.tracker_rows,
            },
            "parameters": [
                {"name": n, "value": float(v), "std": float(s)}
                for n, v, s in zip(res.free_names, self.model.p[res.free], res.std, strict=True)
            ],
            "planes": [{"normal": p.normal, "offset_mm": p.offset_mm} for p in env.planes],
            "pivots_mm": env.pivots_mm,
            "bars_dL_mm": env.bars_dL_mm,
        }

    def summary(self) -> str:
        res, env = self.result, environment_of(self.model)
        names = {"planes": "plane distances", "distances": "length errors", "points": "tracker 3-D errors"}
        lines = [
            f"Calibration of {self.robot.name} from {' + '.join(self.sources) or 'contacts'}: "
            f"{res.n_params} parameters, chi2/dof {res.chi2_per_dof:.3g}",
            "Residuals (fit, in-sample):",
            *(figures_line(f"{names[k]} [fit]", f) for k, f in self.figures().items()),
            "Held by the gauge:",
            *("  " + line for line in res.contacts.gauge.describe().splitlines()),
        ]
        for k, p in enumerate(env.planes):
            n = np.round(p.normal, 6).tolist()
            lines.append(f"plane {k + 1}: normal {n}, offset {p.offset_mm:.4f} mm")
        lines += [f"pivot {k + 1}: {np.round(v, 4).tolist()} mm" for k, v in enumerate(env.pivots_mm)]
        lines += [f"bar {k + 1}: length correction {v:.4f} mm" for k, v in enumerate(env.bars_dL_mm)]
        return "\n".join(lines)


def calibrate_contacts(
    robot: Robot,
    cell: Cell,
    *,
    planes: PlaneData | None = None,
    distances: DistanceData | None = None,
    data: Measurements | None = None,
    sigma_mm: float = 0.02,
    max_iter: int = 100,
    sources: tuple[str, ...] = (),
) -> ContactCalibrationReport:
    """Fit the robot (and the planes, pivots, bars; with ``data`` the tracker pose) to every row.

    Args:
        robot, cell: the nominal model and its cell.
        planes, distances: contact rows (at least one of them).
        data: laser-tracker rows fitted with them (positions only), or None.
        sigma_mm: the tracker rows' noise per coordinate [mm] (the contact rows carry their own).
        max_iter: most Levenberg-Marquardt iterations.

    Raises:
        InputError: no contact rows; tracker data with a probe's orientations or effects; rows that
            do not determine a plane or pivot; fewer rows than parameters.
    """
    if planes is None and distances is None:
        raise InputError("calibrate: give planes or distances (contact rows) for a contact calibration")
    if data is not None and data.R_TP is not None:
        raise InputError(
            f"{data.path}: orientations of a 6-DoF probe are not modelled with planes or distances"
        )
    model = nominal_model(robot, cell)
    q, eta, cond = (None, None, None) if data is None else (data.q, data.eta, Conditions(target=data.target))
    res = estimate(
        model, q, eta, sigma=sigma_mm, max_iter=max_iter, conditions=cond, distances=distances, planes=planes
    )
    return ContactCalibrationReport(robot, res, data, float(sigma_mm), sources)
