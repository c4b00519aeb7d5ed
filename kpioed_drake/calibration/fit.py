"""Calibration from measured data (SPEC "Measured data and model discrepancy").

:func:`calibrate`: rigid registration of the tracker, Levenberg-Marquardt on the free geometric
parameters and the values of the given non-geometric effects (an extended model,
:func:`kpioed_drake.estimation.estimator.estimate` with ``effects``), robust outlier handling,
goodness of fit and the KPI (TCP at ``q_work`` in W, no payload, reference temperature) with its
covariance ``Js Cp Js^T`` (paper eq. 19, 24e). The same steps run with and without effects.

Outlier test (normalised residuals): for every used pose i the studentised statistic
``t_i = r_i^T (sigma^2 (I - H_ii))^-1 r_i`` (``H_ii`` the 3x3 block of the hat matrix) is chi^2(3)
distributed if the model is right (with a 6-DoF probe's orientations a second one of its
orientation rows, both tested at ``alpha / 2n``). The largest ``t_i`` is compared with the chi^2(3)
quantile at level ``alpha / n`` (Bonferroni; ``alpha`` = family-wise false-alarm probability, default 0.01),
at the effective noise ``max(sigma, robust scale of the residuals)`` so that the non-geometric rest
of a real robot is not taken for gross errors (:mod:`kpioed_drake.calibration.robust`); if it
exceeds it, that pose is removed and the fit repeated, until no pose exceeds the threshold, at
most ``max_outlier_fraction`` of the poses are removed, or removing one more would leave fewer than
10 poses. The report warns when the cap is reached.

Identifiability: before the fit, the Jacobian of the registered nominal model over the poses is
tested (:func:`kpioed_drake.estimation.identifiability.undetermined_parameters`: near-rank of the
column-scaled Jacobian and correlations above 0.999); the parameters these poses do not determine
are held at nominal, with a warning naming them (``strict``: refused). After the fit the same test
runs on the Jacobian at the estimated parameters (:func:`hold_at_solution`): what the nominal check
missed (e.g. a reflector the data place on joint 6's axis, away from the nominal offset) is held at
nominal the same way and the fit repeated. An extended fit's effects are tested there too, each
beside the determined geometry and the effects before it
(:func:`kpioed_drake.calibration.extended.undetermined_effects`): an effect the poses cannot tell from
them is dropped from the model, with a warning naming it and what it trades against (``strict``:
refused).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from kpioed_drake.calibration.extended import resolve_extension, undetermined_effects
from kpioed_drake.calibration.kpi import kpi_and_covariance, working_pose
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.calibration.robust import (
    MIN_POSES_FOR_OUTLIER_TEST,
    Screening,
    non_geometric_warning,
    screen_outliers,
)
from kpioed_drake.errors import InputError, param
from kpioed_drake.estimation.estimator import (
    Conditions,
    EstimationResult,
    covariance,
    estimate,
    registered_model,
)
from kpioed_drake.estimation.identifiability import undetermined_parameters
from kpioed_drake.estimation.plausibility import check_data, check_fitted
from kpioed_drake.estimation.residuals import pose_statistics
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.tracker.data import Measurements, counted_rows
from kpioed_drake.tracker.measurement import (
    TrackerModel,
    hold_unused_targets,
    kpi_jacobian,
    measurement_jacobian,
    nominal_model,
)
from kpioed_drake.tracker.orientation import orientation_jacobian, with_probe

__all__ = ["MIN_POSES_FOR_OUTLIER_TEST", "calibrate", "hold_at_solution", "hold_undetermined"]

MAX_HELD_SHARE = 1.0 / 3.0
"""Poses leaving more than this share of the free parameters undetermined are refused: holding a
few (a reflector on joint 6's axis: 2) is a gauge; holding more (60 poses moving only joints 1 and
2: 17 of 27) means the poses do not exercise the robot."""


def hold_undetermined(
    nominal: TrackerModel,
    data: Measurements,
    strict: bool,
    warnings: list[str],
    sigma_deg: float = 0.01,
    sigma_mm: float = 1.0,
) -> TrackerModel:
    """``nominal`` with the parameters the poses do not determine held at nominal (not estimated).

    Tested on the Jacobian of the registered nominal model over every pose (with fewer coordinates
    than parameters the estimator refuses anyway); with a probe's orientations on the whitened
    stack of its position and orientation rows (:func:`_test_rows`, ``sigma_deg`` the orientation
    noise of rows without their own, relative to the positions' ``sigma_mm`` as in the fit: the
    column-scaled test sees only the ratio). Raises InputError with ``strict`` or when more
    than ``MAX_HELD_SHARE`` of the free parameters are undetermined.

    A tracker-pose parameter found only through its correlation with another (not rank deficient)
    is not held, with a warning: the value it would be held at is the rigid registration, which the
    robot's own errors bias (by millimetres on a compliant lift, docs/design.md). It is estimated
    with the others; ``calibrate`` tests it
    again at the solution (:func:`hold_at_solution` keeps a tracker parameter's estimate).
    """
    lay = nominal.layout
    if 3 * data.n < lay.n_free:
        return nominal
    registered = registered_model(nominal, data.q, data.eta, target=data.target, R_TP=data.R_TP)
    found = undetermined_parameters(_test_rows(registered, data, sigma_deg, sigma_mm), lay.free_names)
    loose = [c for c in found.correlated if c.held in lay.tracker_names]
    if loose and not strict:  # the registration is biased by the robot's errors: estimate it
        found = dataclasses.replace(found, correlated=tuple(c for c in found.correlated if c not in loose))
        warnings.append(
            f"these {counted_rows(data.q)} barely separate "
            + "; ".join(c.text() for c in loose)
            + ": estimated with the others rather than held at the tracker registration (which the "
            "robot's own errors bias)"
        )
    return _hold(nominal, found, f"these {counted_rows(data.q)} do not determine", data, strict, warnings)


def _test_rows(model: TrackerModel, data: Measurements, sigma_deg: float, sigma_mm: float) -> np.ndarray:
    """(3 n [+ 3 n], n_free) the rows the identifiability test sees: the positions' Jacobian, and
    with orientations their Jacobian whitened by their noise relative to the positions'
    (``sigma_mm``), the weights of the fit up to one factor."""
    lay = model.layout
    _, H = measurement_jacobian(model, data.q, target=data.target)
    A = H[:, :, lay.free].reshape(3 * data.n, -1)
    if data.R_TP is None:
        return A
    _, Hr = orientation_jacobian(model, data.q, data.R_TP)
    w = sigma_mm / orientation_sigma(data, sigma_deg)
    return np.concatenate([A, (Hr[:, :, lay.free] * w[:, :, None]).reshape(3 * data.n, -1)])


def orientation_sigma(data: Measurements, sigma_deg: float) -> np.ndarray:
    """(n, 3) the orientations' noise [rad]: the rows' own (``sigma_rot_rad``), else ``sigma_deg``."""
    if data.sigma_rot_rad is not None:
        return data.sigma_rot_rad
    return np.full((data.n, 3), np.deg2rad(sigma_deg))


def _hold(
    model: TrackerModel, found, what: str, data: Measurements, strict: bool, warnings, *, at_estimate=()
) -> TrackerModel:
    """``model`` with the parameters ``found``
    (:class:`~kpioed_drake.estimation.identifiability.Undetermined`) no longer estimated, with a
    warning naming them and, for a pair, both members (``at_estimate``: those of them held at
    ``model``'s value, an estimate, not at nominal); InputError with ``strict`` or too many."""
    if not found.names:
        return model
    lay = model.layout
    what = f"{what} {found.describe()}"
    if len(found.names) > MAX_HELD_SHARE * lay.n_free:
        raise InputError(
            f"{data.path}: {what}: {len(found.names)} of the {lay.n_free} parameters, too many to hold "
            "at nominal; use more varied poses (move every joint over its range)"
        )
    if strict:
        raise InputError(
            f"{data.path}: {what}; use more varied poses (a reflector on joint 6's axis leaves wrist "
            "parameters undetermined); without strict they are held at nominal",
            fields=("strict",),
        )
    kept = [n for n in found.names if n in at_estimate]
    nominal = [n for n in found.names if n not in at_estimate]
    if nominal:
        warnings.append(
            f"{what}: held at nominal (not estimated); the values written for them are the nominal ones"
            + (f" ({', '.join(kept)} keeps its estimate)" if kept else "")
        )
    else:
        warnings.append(f"{what}: held at the estimate (the tracker pose's value from the first fit)")
    held = tuple(n for i, n in enumerate(lay.names) if i not in set(lay.free.tolist()))
    layout = parameter_layout(model.robot, fixed=held + found.names, n_targets=lay.n_targets, probe=lay.probe)
    return dataclasses.replace(model, layout=layout)


def hold_at_solution(
    res: EstimationResult, nominal: TrackerModel, data: Measurements, strict: bool, warnings: list[str]
) -> tuple[TrackerModel | None, tuple[str, ...]]:
    """The identifiability test on the Jacobian at the estimated parameters.

    The nominal check (:func:`hold_undetermined`) sees the poses through the nominal model; the
    estimate can lie where the poses determine less (a reflector the data place on joint 6's axis
    while the nominal one is off it). Same test, same thresholds, on ``res.J``.

    Returns:
        (model, names): the estimated model with the undetermined parameters held and set to their
        nominal values (tracker ones keep their estimate) to refit from, and their names; (None, ())
        when every parameter is determined.

    Raises:
        InputError: with ``strict``, or more than ``MAX_HELD_SHARE`` of the parameters undetermined.
    """
    lay = res.model.layout
    found = undetermined_parameters(res.J[:, : lay.n_free], lay.free_names)
    if not found.names:
        return None, ()
    what = f"at the estimated parameters these {counted_rows(data.q[res.mask])} do not determine"
    model = _hold(res.model, found, what, data, strict, warnings, at_estimate=lay.tracker_names)
    idx = [lay.names.index(n) for n in found.names if n not in lay.tracker_names]
    p = model.p.copy()
    p[idx] = nominal.p[idx]
    return dataclasses.replace(model, p=p), found.names


def calibrate(
    robot: Robot,
    data: Measurements,
    options: CalibrationOptions | None = None,
    *,
    q_work: np.ndarray | None = None,
    cell: Cell | None = None,
) -> CalibrationReport:
    """Calibrate the free geometric parameters (27 for six joints), and the values of
    ``options.effects`` if any, from measured data.

    Args:
        robot: the nominal model to start from.
        data: :class:`~kpioed_drake.tracker.data.Measurements` (e.g. from
            :func:`~kpioed_drake.tracker.data.read_data`).
        options: :class:`CalibrationOptions` (noise, effects, outlier test, holds; default: its
            defaults).
        q_work: (n_joints,) working pose [rad] for the KPI; default: the model file's.
        cell: the measuring cell (nominal tracker position, reflector offset); default
            ``models/cell.yaml``.

    Returns:
        :class:`CalibrationReport`.

    Raises:
        InputError: bad q_work, too few poses (no degree of freedom), implausible data (unless
            ``options.force``), or poses that do not determine the parameters (exactly singular,
            or with ``options.strict`` near-singular).
    """
    options = options or CalibrationOptions()
    q_work, work_note = working_pose(robot, q_work, poses=data.q)
    nominal = _start_model(robot, data, cell)
    effects, cond, nominal = resolve_extension(list(options.effects), nominal, data)
    if data.R_TP is not None and effects:
        raise InputError(
            f"{data.path}: the data hold a 6-DoF probe's orientations, and non-geometric effects "
            "(extend, or an extended model file's) do not model orientation rows yet; calibrate the "
            "geometric model, or the positions only",
            fields=("effects",),
        )
    rob = nominal.robot  # with the gravity bases sized on these poses, where an effect needs them
    n_effect = sum(e.n_params for e in effects)
    warnings = (
        check_data(nominal, data, n_params=nominal.layout.n_free + n_effect, force=options.force) + work_note
    )
    before = nominal.layout.free_names
    nominal = hold_undetermined(nominal, data, options.strict, warnings, options.sigma_deg, options.sigma_mm)
    at_nominal = [name for name in before if name not in nominal.layout.free_names]
    fit = _fitter(data, options, effects, cond)
    res, screen, statistics, at_solution, dropped = _fit_and_screen(fit, nominal, data, options, warnings)
    check_fitted(res, nominal, data, force=options.force, warnings=warnings)
    if not res.converged:
        warnings.append(f"the least-squares iteration did not converge ({res.message})")

    s, kpi_cov = kpi_and_covariance(res, q_work)
    report = CalibrationReport(
        robot=rob,
        nominal=nominal,
        kpi_nominal=kpi_jacobian(nominal, q_work)[0],
        result=res,
        outliers=screen.outliers,
        data=data,
        q_work=q_work,
        outlier_threshold=screen.threshold,
        normalized=statistics[0],
        normalized_rot=statistics[1] if len(statistics) > 1 else None,
        outlier_alpha=screen.alpha,
        kpi=s,
        kpi_cov=kpi_cov,
        robust=screen.to_dict(),
        warnings=warnings,
        identifiability={
            "at_nominal": at_nominal,
            "at_solution": list(at_solution),
            "effects_dropped": dropped,
        },
    )
    _fit_warnings(report, screen, options.sigma_mm, warnings)
    return report


def _start_model(robot: Robot, data: Measurements, cell: Cell | None) -> TrackerModel:
    """The nominal model of ``robot`` in ``cell`` (default ``models/cell.yaml``) to start from: the
    tracker frame at the identity for positions given in W, the targets the data do not measure held,
    and with a probe's orientations the probe's three rotations (registered in the fit)."""
    cell = load_cell(robot=robot) if cell is None else cell
    nominal = nominal_model(robot, cell)
    if data.frame == "base":  # positions given in W: the tracker frame starts at the identity
        p0 = nominal.p.copy()
        p0[nominal.layout.tracker_position] = 0.0
        p0[nominal.layout.tracker_rotation] = 0.0
        nominal = dataclasses.replace(nominal, p=p0, R_WT_ref=np.eye(3))
    if data.R_TP is not None:
        nominal = with_probe(nominal)
    return hold_unused_targets(nominal, data.target)


def _fitter(data: Measurements, options: CalibrationOptions, effects: list, cond: Conditions) -> Callable:
    """``fit(model, mask, *, start, register, singular_ok)``: :func:`estimate` on ``data`` with the
    options' noise and iterations, its InputError naming the file (and the effects fitted together)."""

    def fit(model, mask, *, start=effects, register=False, singular_ok=False) -> EstimationResult:
        try:
            return estimate(
                model,
                data.q,
                data.eta,
                sigma=options.sigma_mm,
                mask=mask,
                register=register,
                max_iter=options.max_iter,
                conditions=cond,
                singular_ok=singular_ok,
                effects=start,
                R_TP=data.R_TP,
                sigma_rot=None if data.R_TP is None else orientation_sigma(data, options.sigma_deg),
            )
        except InputError as exc:
            names = f" and {', '.join(e.name for e in effects)} together" if effects else ""
            raise InputError(
                f"{data.path}: the geometry{names}: {str(exc).removeprefix('estimate: ')}"
                if names
                else f"{data.path}: {str(exc).removeprefix('estimate: ')}"
            ) from None

    return fit


def _fit_and_screen(
    fit: Callable, nominal: TrackerModel, data: Measurements, options: CalibrationOptions, warnings: list[str]
) -> tuple[EstimationResult, Screening, np.ndarray, tuple[str, ...], list[str]]:
    """The fit of every pose, what the solution does not determine held or dropped, the outliers
    screened (and the final solution tested again): (result, screening, the final studentised
    statistics (parts, n), names held at the solution, effects dropped)."""
    strict = options.strict
    res = fit(nominal, np.ones(data.n, dtype=bool), register=True, singular_ok=True)
    dropped: list[str] = []
    res, at_solution = _determined_at_solution(res, nominal, data, strict, warnings, fit, dropped)
    screen = screen_outliers(
        res,
        data,
        lambda mask, prev: fit(prev.model, mask, start=prev.effects),
        alpha=float(options.outlier_alpha) or None,
        max_outlier_fraction=options.max_outlier_fraction,
        force=options.force,
        warnings=warnings,
    )
    res, statistics = screen.result, screen.statistics
    if screen.outliers:  # the final solution is tested too
        res, more = _determined_at_solution(res, nominal, data, strict, warnings, fit, dropped)
        if more:
            at_solution += more
            statistics = pose_statistics(res)
    return res, screen, statistics, at_solution, dropped


def _fit_warnings(report: CalibrationReport, screen: Screening, sigma_mm: float, warnings: list[str]) -> None:
    """The warnings of a goodness of fit the noise does not explain (chi2/dof far from 1)."""
    p = report.p_value
    if p is not None and p < 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g} (p = {p:.2g}): the residuals are larger than a noise of "
            f"{sigma_mm:g} mm{_and_orientation(report)} explains; the noise is larger than given or the "
            "geometric model misses an effect (see `kpioed diagnose`); the a-posteriori covariance scales "
            "by chi2/dof"
        )
        rest = non_geometric_warning(screen)
        if rest:
            warnings.append(rest)
    elif p is not None and p > 1 - 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g}: the residuals are smaller than a noise of "
            f"{sigma_mm:g} mm predicts; {param('sigma_mm')} is probably too large (the reported "
            "uncertainties are then pessimistic)"
        )


def _and_orientation(report: CalibrationReport) -> str:
    """`` (and the orientations' noise)`` of a fit with a probe's orientation rows, else ``""``."""
    return "" if report.result.R_TP is None else " (and the orientations' given noise)"


def _determined_at_solution(res, nominal, data, strict, warnings, fit, dropped: list[str]):
    """``res``, refitted (same rows) without the effects the poses do not determine beside the
    geometry (:func:`~kpioed_drake.calibration.extended.undetermined_effects`, their names appended
    to ``dropped``) and with what :func:`hold_at_solution` finds held; and the names held.

    Raises:
        InputError: with ``strict``, an effect or parameter not determined; the information matrix
            is singular at the solution and nothing can be held.
    """
    if res.effects:
        lay = res.model.layout
        geometric = undetermined_parameters(res.J[:, : lay.n_free], lay.free_names)
        lost = undetermined_effects(res.J, lay.free_names, geometric.names, res.effects)
        if lost:
            res = _drop_effects(res, lost, data, strict, warnings, fit)
            dropped += [u.effect.name for u in lost]
    model, names = hold_at_solution(res, nominal, data, strict, warnings)
    if model is not None:
        return fit(model, res.mask, start=res.effects), names
    try:
        covariance(res.J)
    except np.linalg.LinAlgError:
        raise InputError(
            f"{data.path}: the {counted_rows(data.q[res.mask])} do not determine the {res.n_params} "
            "parameters (information matrix singular); use more or more varied poses"
        ) from None
    return res, ()


def _drop_effects(res, lost, data, strict, warnings, fit):
    """``res`` refitted without the effects ``lost``, with a warning naming each and what it trades
    against; InputError with ``strict``."""
    s = "s" if len(lost) > 1 else ""
    what = f"these {counted_rows(data.q[res.mask])} do not determine the effect{s} " + "; ".join(
        u.text() for u in lost
    )
    if strict:
        raise InputError(
            f"{data.path}: {what}; use poses that vary what the effect{s} depend{'' if s else 's'} on, "
            "or leave it out; without strict undetermined effects are dropped from the model",
            fields=("strict",),
        )
    warnings.append(f"{what}: dropped from the model (not estimated, not written to the model file)")
    gone = {u.effect.name for u in lost}
    kept = tuple(e for e in res.effects if e.name not in gone)
    return fit(res.model, res.mask, start=kept, singular_ok=True)
