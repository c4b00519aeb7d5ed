"""Calibration from measured data (SPEC "Measured data and model discrepancy").

:func:`calibrate`: rigid registration of the tracker, Levenberg-Marquardt on the free geometric
parameters (:func:`kpioed_drake.estimation.estimate`), robust outlier handling, goodness of fit and
the KPI (TCP at ``q_work`` in W) with its covariance ``Js Cp Js^T`` (paper eq. 19, 24e).

Outlier test (normalised residuals): for every used pose i the studentised statistic
``t_i = r_i^T (sigma^2 (I - H_ii))^-1 r_i`` (``H_ii`` the 3x3 block of the hat matrix) is chi^2(3)
distributed if the model is right. The largest ``t_i`` is compared with the chi^2(3) quantile at
level ``alpha / n`` (Bonferroni; ``alpha`` = family-wise false-alarm probability, default 0.01); if
it exceeds it, that pose is removed and the fit repeated, until no pose exceeds the threshold, at
most ``max_outlier_fraction`` of the poses are removed, or removing one more would leave fewer than
10 poses. Many "outliers" are a sign of model discrepancy rather than of bad points (see
``kpioed diagnose``); the report warns when the cap is reached.

Identifiability: before the fit, the Jacobian of the registered nominal model over the poses is
tested (:func:`kpioed_drake.identifiability.undetermined_parameters`: near-rank of the
column-scaled Jacobian and correlations above 0.999); the parameters these poses do not determine
are held at nominal, with a warning naming them (``strict``: refused).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import chi2 as chi2_dist

from kpioed_drake.calibration.common import kpi_and_covariance, working_pose
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import estimate, normalized_residuals, registered_model
from kpioed_drake.identifiability import undetermined_parameters
from kpioed_drake.measurement import TrackerModel, kpi_jacobian, measurement_jacobian, nominal_model
from kpioed_drake.measurements import Measurements
from kpioed_drake.models import Robot, load_cell, load_robot
from kpioed_drake.parameters import default_fixed, parameter_layout
from kpioed_drake.plausibility import check_data

MIN_POSES_FOR_OUTLIER_TEST = 10
MAX_OUTLIER_SHARE = 1.0 / 3.0
"""More poses than this share failing the outlier test at once is refused (sigma or model wrong)."""
MAX_HELD_SHARE = 1.0 / 3.0
"""Poses leaving more than this share of the free parameters undetermined are refused: holding a
few (a reflector on joint 6's axis: 2) is a gauge; holding more (60 poses moving only joints 1 and
2: 17 of 27) means the poses do not exercise the robot."""


def _few_outliers(t, res, data: Measurements, alpha: float, force: bool, warnings: list[str]) -> bool:
    """False (forced) or an InputError when over a third of the poses fail the outlier test at once.

    So many "outliers" are not single bad points: the noise is larger than the given sigma, or the
    model misses an effect; removing them would throw good poses away. ``t``: the normalised
    residuals of ``res`` (:func:`~kpioed_drake.estimation.normalized_residuals`).
    """
    n = data.n
    n_fail = int(np.count_nonzero(t > chi2_dist.isf(alpha / n, 3)))
    if n_fail <= MAX_OUTLIER_SHARE * n:
        return True
    ratio = res.chi2_per_dof
    message = (
        f"{data.path}: {n_fail} of {n} poses fail the outlier test at sigma {res.sigma:g} mm: not single "
        f"bad points. The residuals are sqrt(chi2/dof) = {np.sqrt(ratio):.3g} times the noise: the noise "
        f"is larger than --sigma-mm (about {res.sigma * np.sqrt(ratio):.3g} mm) or the model misses an "
        "effect (run `kpioed diagnose`)"
    )
    if not force:
        raise InputError(message + "; use --force to calibrate anyway without removing outliers")
    warnings.append(f"forced: {message}; no pose was removed")
    return False


def hold_undetermined(
    nominal: TrackerModel, data: Measurements, strict: bool, warnings: list[str]
) -> TrackerModel:
    """``nominal`` with the parameters the poses do not determine held at nominal (not estimated).

    Tested on the Jacobian of the registered nominal model over every pose (with fewer coordinates
    than parameters the estimator refuses anyway). Raises InputError with ``strict`` or when more
    than ``MAX_HELD_SHARE`` of the free parameters are undetermined.
    """
    lay = nominal.layout
    if 3 * data.n < lay.n_free:
        return nominal
    _, H = measurement_jacobian(registered_model(nominal, data.q, data.eta), data.q)
    found = undetermined_parameters(H[:, :, lay.free].reshape(3 * data.n, -1), lay.free_names)
    if not found.names:
        return nominal
    what = f"these {data.n} poses do not determine {found.describe()}"
    if len(found.names) > MAX_HELD_SHARE * lay.n_free:
        raise InputError(
            f"{data.path}: {what}: {len(found.names)} of the {lay.n_free} parameters, too many to hold "
            "at nominal; use more varied poses (move every joint over its range)"
        )
    if strict:
        raise InputError(
            f"{data.path}: {what}; use more varied poses (a reflector on joint 6's axis leaves wrist "
            "parameters undetermined); without --strict they are held at nominal"
        )
    warnings.append(
        f"{what}: held at nominal (not estimated); the values written for them are the nominal ones"
    )
    layout = parameter_layout(nominal.robot, fixed=default_fixed(nominal.robot) + found.names)
    return dataclasses.replace(nominal, layout=layout)


def calibrate(
    robot: str | Robot,
    data: Measurements,
    *,
    sigma_mm: float = 0.02,
    q_work=None,
    outlier_threshold: float | None = 0.01,
    max_outlier_fraction: float = 0.1,
    cell_path=None,
    max_iter: int = 100,
    force: bool = False,
    strict: bool = False,
) -> CalibrationReport:
    """Calibrate the free geometric parameters (27 for six joints) from measured data.

    Args:
        robot: model name, YAML path or :class:`Robot` (the nominal model to start from).
        data: :class:`~kpioed_drake.measurements.Measurements` (e.g. from
            :func:`~kpioed_drake.measurements.read_measurements`).
        sigma_mm: noise standard deviation per coordinate [mm].
        q_work: (6,) working pose [rad] for the KPI; default: the model file's.
        outlier_threshold: family-wise false-alarm probability alpha of the outlier test
            (Bonferroni: each pose is tested at alpha / n); None or 0 disables the test.
        max_outlier_fraction: remove at most this fraction of the poses.
        cell_path: cell file (default models/cell.yaml): nominal tracker position, reflector offset.
        force: go on with implausible data (:func:`kpioed_drake.plausibility.check_data`), warning.
        strict: refuse poses that do not determine every free parameter instead of holding the
            undetermined ones at nominal with a warning.

    Returns:
        :class:`CalibrationReport`.

    Raises:
        InputError: bad sigma or q_work, too few poses (no degree of freedom), implausible data
            (unless ``force``), or poses that do not determine the parameters (exactly singular,
            or with ``strict`` near-singular).
    """
    rob = load_robot(robot) if isinstance(robot, str) else robot
    if not (np.isfinite(sigma_mm) and sigma_mm > 0):
        raise InputError(f"--sigma-mm must be a positive number of millimetres, got {sigma_mm!r}")
    q_work = working_pose(rob, q_work)
    alpha = float(outlier_threshold) if outlier_threshold else None
    if alpha is not None and not 0 < alpha < 1:
        raise InputError(
            f"outlier threshold (family-wise level) must be in (0, 1), got {outlier_threshold!r}"
        )
    cell = load_cell(cell_path, robot=rob)
    nominal = nominal_model(rob, cell)
    if data.frame == "base":  # positions given in W: the tracker frame starts at the identity
        p0 = nominal.p.copy()
        p0[nominal.layout.tracker_position] = 0.0
        p0[nominal.layout.tracker_rotation] = 0.0
        nominal = dataclasses.replace(nominal, p=p0, R_WT_ref=np.eye(3))
    n = data.n
    warnings = check_data(nominal, data, n_params=nominal.layout.n_free, force=force)
    nominal = hold_undetermined(nominal, data, strict, warnings)
    mask = np.ones(n, dtype=bool)
    outliers: list[int] = []
    max_out = int(np.floor(max_outlier_fraction * n))
    try:
        res = estimate(nominal, data.q, data.eta, sigma=sigma_mm, mask=mask, max_iter=max_iter)
    except InputError as exc:
        raise InputError(f"{data.path}: {str(exc).removeprefix('estimate: ')}") from None
    t = normalized_residuals(res)
    if alpha is not None and not _few_outliers(t, res, data, alpha, force, warnings):
        alpha = None  # forced: keep every pose
    threshold = None
    while True:
        n_used = int(np.count_nonzero(mask))
        if alpha is None or n_used - 1 < MIN_POSES_FOR_OUTLIER_TEST:
            break
        threshold = float(chi2_dist.isf(alpha / n_used, 3))
        used = np.flatnonzero(mask)
        worst = int(used[np.argmax(t[used])])
        if t[worst] <= threshold:
            break
        if len(outliers) >= max_out:
            warnings.append(
                f"outlier removal stopped after {len(outliers)} poses "
                f"(cap {max_outlier_fraction:.0%} of the data); "
                f"row {int(data.rows[worst])} still fails the test: the residuals suggest model discrepancy "
                "or a wrong --sigma-mm rather than single bad points"
            )
            break
        mask[worst] = False
        outliers.append(worst)
        res = estimate(
            res.model, data.q, data.eta, sigma=sigma_mm, mask=mask, register=False, max_iter=max_iter
        )
        t = normalized_residuals(res)
    normalized = t
    if not res.converged:
        warnings.append(f"the least-squares iteration did not converge ({res.message})")

    s, kpi_cov = kpi_and_covariance(res, q_work)
    kpi_nom = kpi_jacobian(nominal, q_work)[0]
    report = CalibrationReport(
        robot=rob,
        nominal=nominal,
        result=res,
        data=data,
        q_work=q_work,
        outliers=outliers,
        normalized=normalized,
        outlier_threshold=threshold,
        outlier_alpha=alpha,
        kpi=s,
        kpi_cov=kpi_cov,
        kpi_nominal=kpi_nom,
        warnings=warnings,
    )
    p = report.p_value
    if p is not None and p < 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g} (p = {p:.2g}): the residuals are larger than a noise of "
            f"{sigma_mm:g} mm explains; the noise is larger than given or the geometric model misses an "
            "effect (see `kpioed diagnose`); the a-posteriori covariance scales by chi2/dof"
        )
    elif p is not None and p > 1 - 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g}: the residuals are smaller than a noise of "
            f"{sigma_mm:g} mm "
            "predicts; --sigma-mm is probably too large (the reported uncertainties are then pessimistic)"
        )
    return report
