"""Calibration of an extended model: the geometric parameters and non-geometric effects together.

What ``kpioed calibrate --extend EFFECT`` runs: registration and least squares
(:func:`kpioed_drake.estimation.estimator.estimate`) on the free geometric parameters plus the parameters of
the given effects (:mod:`kpioed_drake.effects`), goodness of fit, and the KPI (TCP at ``q_work``
in W under KPI conditions: no payload, reference temperature) with its covariance. No outlier
screening (run ``kpioed calibrate`` without ``--extend`` first to find outliers).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.calibration.common import kpi_and_covariance, working_pose
from kpioed_drake.effects.gravity_basis import resolve_all
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import data_conditions, estimate, rms
from kpioed_drake.estimation.plausibility import check_data
from kpioed_drake.robot.models import Robot, load_cell, load_robot
from kpioed_drake.tracker.data import Measurements, as_measurements
from kpioed_drake.tracker.measurement import nominal_model

_MIN_SIDE = 3
"""Poses needed on each side of a backlash (gravity torque positive and negative)."""


def calibrate_extended(
    robot: str | Path | Robot,
    data: str | Path | Measurements,
    extend,
    *,
    sigma_mm: float = 0.02,
    q_work=None,
    cell=None,
    force: bool = False,
) -> dict:
    """Calibration with a model extension: the free geometric parameters and the effects' values.

    Args:
        robot: model name, path or :class:`~kpioed_drake.robot.models.Robot`.
        data: measurement CSV path or :class:`~kpioed_drake.tracker.data.Measurements`.
        extend: effect texts, e.g. ``["joint_elasticity:2"]``.
        sigma_mm: noise standard deviation per coordinate [mm].
        q_work: (6,) working pose [rad] (default: the model's).
        cell: the cell (default: the robot's cell file).
        force: go on with implausible data (:func:`kpioed_drake.estimation.plausibility.check_data`), warning.

    Returns:
        JSON-ready report: ``rms_residual_mm``, ``chi2_per_dof``, ``p_value``, ``kpi_mm`` (TCP at
        q_work in W, no payload, reference temperature), ``kpi_cov_mm2``, ``parameters``
        (geometric, with std) and ``extensions`` (effect values with std, display units).
    """
    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    data = as_measurements(data, robot)
    effects = fx.parse_effects(extend)
    nominal = nominal_model(robot, load_cell(robot=robot) if cell is None else cell)
    effects = resolve_all(effects, nominal, data.payload_kg)  # joint_elasticity_basis: size per robot
    n_params = nominal.layout.n_free + sum(e.n_params for e in effects)
    warnings = check_data(nominal, data, n_params=n_params, force=force)
    conditions = data_conditions(robot, data, p_FP=nominal.p_FQ)
    _check_conditions(effects, data, conditions.tau)
    try:
        fit = estimate(nominal, data.q, data.eta, sigma=sigma_mm, effects=effects, conditions=conditions)
    except InputError as exc:
        names = ", ".join(e.name for e in effects)
        raise InputError(
            f"{data.source}: the geometry and {names} cannot be estimated together: {exc}"
        ) from None
    std = fit.std
    s, Cs = kpi_and_covariance(fit, working_pose(robot, q_work))
    lay = fit.model.layout
    params = []
    for k, i in enumerate(lay.free):
        f = np.rad2deg(1.0) if lay.is_angle[i] else 1.0
        params.append(
            {
                "name": lay.names[i],
                "value": float(fit.model.p[i] * f),
                "std": float(std[k] * f),
                "unit": "deg" if lay.is_angle[i] else "mm",
            }
        )
    exts, c = [], fit.layout.effects.start
    for e in fit.effects:
        d = e.to_dict()
        d["std"] = e.display_values(std[c : c + e.n_params])
        if len(d["std"]) == 1:
            d["std"] = d["std"][0]
        exts.append(d)
        c += e.n_params
    return {
        "robot": robot.name,
        "n_poses": int(data.n),
        "sigma_mm": float(sigma_mm),
        "rms_residual_mm": rms(fit.residuals),
        "max_residual_mm": float(np.max(np.linalg.norm(fit.residuals, axis=1))),
        "chi2_per_dof": float(fit.cost / fit.dof),
        "p_value": float(scipy.stats.chi2.sf(fit.cost, fit.dof)),
        "kpi_mm": s.tolist(),
        "kpi_cov_mm2": Cs.tolist(),
        "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
        "parameters": params,
        "extensions": exts,
        "warnings": warnings,
    }


def _check_conditions(effects, data: Measurements, tau: np.ndarray) -> None:
    """Refuse effects whose variable the data does not vary (their parameter would be arbitrary).

    ``tau``: (n, 6) gravity torques at the commanded angles [N m]; a backlash needs joint i's torque
    to take both signs at >= ``_MIN_SIDE`` poses each (else it is a constant offset: the joint's zero).
    """
    for e in effects:
        if e.family in ("thermal_expansion", "tracker_scale") and (
            data.temperature_C is None or np.ptp(data.temperature_C) <= 0.5
        ):
            raise InputError(
                f"{data.source}: {e.name} cannot be estimated: the temperature_C column is missing or varies "
                "by less than 0.5 K (a constant temperature only rescales lengths: the geometry absorbs it)"
            )
        if e.family == "backlash":
            side = np.sign(tau[:, e.joint - 1])
            if min(np.sum(side > 0), np.sum(side < 0)) < _MIN_SIDE:
                raise InputError(
                    f"{data.source}: {e.name} cannot be estimated: the gravity torque of joint {e.joint} "
                    f"must take both signs at {_MIN_SIDE} poses or more (else the backlash is a constant "
                    "offset that the joint's zero absorbs)"
                )
        if e.family == "tracker_drift" and (data.time_s is None or np.ptp(data.time_s) <= 0):
            raise InputError(
                f"{data.source}: {e.name} cannot be estimated: the time_s column is missing or constant"
            )


def extended_summary(report: dict, extend) -> str:
    """The text summary of :func:`calibrate_extended`'s report (``extend``: the effect texts)."""
    d = report
    rms_mm, chi2, pv = d["rms_residual_mm"], d["chi2_per_dof"], d["p_value"]
    lines = [
        f"{d['robot']}: {d['n_poses']} poses, geometric model + {', '.join(extend)}",
        f"  rms residual {rms_mm:.4f} mm, chi2/dof {chi2:.3f} (p {pv:.3g})",
    ]
    for e in d["extensions"]:
        on = f"{e.get('joint', '')}" + (f" (by joint {e['coupled_joint']})" if "coupled_joint" in e else "")
        lines.append(f"  {e['effect']} {on}: {e['value']} +- {e['std']} {e['unit']}")
    kpi = ", ".join(f"{x:.4f}" for x in d["kpi_mm"])
    lines.append(f"  KPI at q_work: ({kpi}) mm, tr(Cs)/3 = {d['kpi_avg_var_mm2']:.3g} mm^2")
    lines += [f"  warning: {w}" for w in d.get("warnings", [])]
    return "\n".join(lines)
