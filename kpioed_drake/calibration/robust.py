"""Outlier screening of a calibration that is robust to the non-geometric rest of a real robot.

Outliers are gross errors (a lost beam, a bumped reflector), not the small non-geometric rest of a
real robot that no geometric model explains. The test therefore compares each pose with the data's
own spread when that exceeds the given noise:

- ``t_i``: the studentised residual of pose i at the given sigma
  (:func:`kpioed_drake.estimation.residuals.normalized_residuals`), chi^2(3) distributed if sigma and the
  model are right.
- **Robust scale** ``s = sigma * sqrt(median(t_used) / m3)`` with ``m3`` = 2.366 the median of
  chi^2(3): the noise level the bulk of the poses shows. The median ignores up to half of the poses,
  so gross errors do not inflate it (10 % of them raise it by about 6 %).
- **Rule**: the test runs at the effective noise ``max(sigma, s)``: pose i fails when
  ``t_i / max(1, s / sigma)^2`` exceeds the chi^2(3) quantile at level ``alpha / n_used``
  (Bonferroni). The worst failing pose is removed and the fit repeated (``s`` re-estimated) until
  none fails, ``max_outlier_fraction`` of the poses are removed, or fewer than
  :data:`MIN_POSES_FOR_OUTLIER_TEST` would remain. Rows are removed, never down-weighted.
- **Several targets per pose**: a failing row whose pose measured two or more targets is a gross
  error only if the pose's targets disagree with each other: their measured distances are compared
  with the model's (a rigid motion keeps them, whatever the model's error at that pose). Targets
  that agree within the noise (chi^2 over the pairs at level ``alpha``) mean the model, not the
  measurement, is off at that pose: its rows are kept, with a warning.
- When more than :data:`MAX_OUTLIER_SHARE` of the poses fail even at the effective noise, they are
  no single bad points: refused (``force``: a warning and no pose removed).
- When ``s`` exceeds sigma and the goodness-of-fit test rejects, the calibration says so: the
  residuals hold a non-geometric rest, and the a-posteriori standard deviations are the ones to use.

:func:`screen_outliers` runs the loop and returns a :class:`Screening` whose :meth:`Screening.to_dict`
is the ``robust`` block of the JSON report.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from scipy.stats import chi2 as chi2_dist

from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import EstimationResult
from kpioed_drake.estimation.residuals import normalized_residuals
from kpioed_drake.tracker.data import Measurements

MIN_POSES_FOR_OUTLIER_TEST = 10
"""No pose is removed when fewer than this many would remain."""
MAX_OUTLIER_SHARE = 1.0 / 3.0
"""More poses than this share failing the test at once (at the effective noise) is refused."""
CHI2_3_MEDIAN = float(chi2_dist.median(3))
"""Median of chi^2(3) (2.366): the robust scale's reference."""


def robust_scale_factor(t: np.ndarray) -> float:
    """``s / sigma = sqrt(median(t) / median(chi^2(3)))`` of studentised residuals ``t`` (m,).

    Returns nan for no poses.
    """
    t = np.asarray(t, dtype=float)
    return float(np.sqrt(np.median(t) / CHI2_3_MEDIAN)) if t.size else float("nan")


@dataclasses.dataclass
class Screening:
    """Outcome of :func:`screen_outliers`.

    Attributes:
        result: the final estimation (outliers excluded).
        outliers: indices (0-based) of the removed poses, in removal order.
        normalized: (n,) studentised residuals of ``result`` at the given sigma.
        threshold: chi^2(3) quantile of the last test (None: not tested).
        alpha: family-wise level (None: no test, or forced past a refusal).
        scale_factor: robust scale / sigma of the final fit.
        reasons: one record per removed pose: row, its statistic at the effective noise, the
            threshold, the effective noise [mm] and its residual norm [mm] when it was removed.
        capped: the removal stopped at ``max_outlier_fraction`` with poses still failing.
    """

    result: EstimationResult
    outliers: list[int]
    normalized: np.ndarray
    threshold: float | None
    alpha: float | None
    scale_factor: float
    reasons: list[dict]
    capped: bool = False

    @property
    def sigma(self) -> float:
        return self.result.sigma

    @property
    def scale_mm(self) -> float:
        """Robust scale of the residuals per coordinate [mm]."""
        return self.sigma * self.scale_factor

    @property
    def sigma_effective_mm(self) -> float:
        """The noise the outlier test used: ``max(sigma, scale)`` [mm]."""
        f = self.scale_factor
        return self.sigma * (max(1.0, f) if np.isfinite(f) else 1.0)

    def to_dict(self) -> dict:
        """The ``robust`` block of the JSON report (millimetres)."""
        return {
            "scale_mm": None if not np.isfinite(self.scale_mm) else float(self.scale_mm),
            "sigma_mm": float(self.sigma),
            "sigma_effective_mm": float(self.sigma_effective_mm),
            "n_downweighted": 0,
            "n_removed": len(self.outliers),
            "capped": bool(self.capped),
            "reasons": list(self.reasons),
            "rule": "robust scale s = sigma sqrt(median(t_i) / 2.366) over the used poses (t_i the "
            "studentised residual at sigma, chi2(3)); a pose is a gross error when t_i / max(1, s/sigma)^2 "
            "exceeds the chi2(3) quantile at alpha / n_used; removed one at a time (the worst, then refit); "
            "rows are removed, never down-weighted",
        }


def screen_outliers(
    res: EstimationResult,
    data: Measurements,
    refit: Callable[[np.ndarray, EstimationResult], EstimationResult],
    *,
    alpha: float | None,
    max_outlier_fraction: float,
    force: bool,
    warnings: list[str],
) -> Screening:
    """Remove gross errors one at a time, testing against ``max(sigma, robust scale)``.

    Args:
        res: the fit on every pose.
        data: the measurements (their rows name the outliers).
        refit: ``refit(mask, previous)`` fits the poses ``mask`` starting from ``previous``.
        alpha: family-wise level of the test (None: no test).
        max_outlier_fraction: remove at most this fraction of the poses.
        force: with too many failing poses, warn and remove none instead of refusing.
        warnings: list the remarks are appended to.

    Raises:
        InputError: more than :data:`MAX_OUTLIER_SHARE` of the poses fail the test at once at the
            effective noise (unless ``force``).
    """
    n = data.n
    t = normalized_residuals(res)
    mask = res.mask.copy()
    factor = robust_scale_factor(t[mask])
    if alpha is None:
        return Screening(res, [], t, None, None, factor, [])
    if not _few_fail(t, mask, factor, res, data, alpha, force, warnings):
        return Screening(res, [], t, None, None, factor, [])
    outliers: list[int] = []
    reasons: list[dict] = []
    max_out = int(np.floor(max_outlier_fraction * n))
    threshold, capped = None, False
    poses, kept = pose_groups(data), np.zeros(n, dtype=bool)
    while True:
        n_used = int(np.count_nonzero(mask))
        if n_used - 1 < MIN_POSES_FOR_OUTLIER_TEST:
            break
        threshold = float(chi2_dist.isf(alpha / n_used, 3))
        inflation = max(1.0, factor) ** 2
        used = np.flatnonzero(mask & ~kept)
        if used.size == 0:
            break
        worst = int(used[np.argmax(t[used])])
        if t[worst] <= threshold * inflation:
            break
        if _consistent_pose(
            res, data, np.flatnonzero(poses == poses[worst]), inflation, alpha, kept, warnings
        ):
            continue
        if len(outliers) >= max_out:
            capped = True
            warnings.append(
                f"outlier removal stopped after {len(outliers)} rows (cap {max_outlier_fraction:.0%} of the "
                f"data); row {int(data.rows[worst])} still fails the test at "
                f"{res.sigma * np.sqrt(inflation):.3g} mm: the residuals suggest model discrepancy rather "
                "than single bad points"
            )
            break
        reasons.append(
            {
                "row": int(data.rows[worst]),
                "statistic": float(t[worst] / inflation),
                "threshold": threshold,
                "sigma_effective_mm": float(res.sigma * np.sqrt(inflation)),
                "residual_norm_mm": float(np.linalg.norm(res.residuals[worst])),
                "why": "gross error: its studentised residual at the effective noise exceeds the threshold",
            }
        )
        mask[worst] = False
        outliers.append(worst)
        res = refit(mask, res)
        t = normalized_residuals(res)
        factor = robust_scale_factor(t[mask])
    return Screening(res, outliers, t, threshold, alpha, factor, reasons, capped)


def _consistent_pose(res, data: Measurements, rows, inflation: float, alpha: float, kept, warnings) -> bool:
    """True (and ``rows`` marked in ``kept``, with a warning) when the failing pose's targets agree
    with each other: the model is off there, not the measurement."""
    spread = targets_disagreement(res, data, rows, res.sigma * np.sqrt(inflation), alpha)
    if spread is None or not spread["consistent"]:
        return False
    kept[rows] = True
    listed = ", ".join(str(int(data.rows[r])) for r in rows)
    warnings.append(
        f"rows {listed} fail the outlier test but their {rows.size} targets agree with each other within "
        f"{spread['max_mm']:.3g} mm: kept (the model, not the measurement, is off at this pose)"
    )
    return True


def pose_groups(data: Measurements) -> np.ndarray:
    """(n,) the pose of each row: rows with the same joint angles (the targets of one pose) share
    it, numbered in order of appearance."""
    _, first, inverse = np.unique(data.q, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return order[np.asarray(inverse).ravel()]


def targets_disagreement(
    res: EstimationResult, data: Measurements, rows: np.ndarray, sigma_mm: float, alpha: float
) -> dict | None:
    """How the measured targets of one pose (``rows``) agree with each other: their pairwise
    distances against the model's distances of the same targets (a rigid motion keeps distances, so
    the model's error at the pose does not enter). None with fewer than two distinct targets.

    Returns:
        ``{"max_mm": largest distance error, "statistic": sum of squared errors / (2 sigma^2),
        "consistent": statistic below the chi^2 quantile (pairs) at level alpha}``.
    """
    if data.target is None or len(set(data.target[rows].tolist())) < 2:
        return None
    offsets = res.model.target_offsets[data.target[rows]]
    a, b = np.triu_indices(rows.size, 1)
    measured = np.linalg.norm(data.eta[rows][a] - data.eta[rows][b], axis=1)
    model = np.linalg.norm(offsets[a] - offsets[b], axis=1)
    err = measured - model
    stat = float(np.sum(err**2) / (2.0 * sigma_mm**2))
    return {
        "max_mm": float(np.max(np.abs(err))),
        "statistic": stat,
        "consistent": stat <= float(chi2_dist.isf(alpha, a.size)),
    }


def _few_fail(t, mask, factor, res, data: Measurements, alpha: float, force: bool, warnings) -> bool:
    """False (forced) or an InputError when over a third of the poses fail at the effective noise."""
    n = data.n
    inflation = max(1.0, factor) ** 2
    n_fail = int(np.count_nonzero(t[mask] > chi2_dist.isf(alpha / n, 3) * inflation))
    if n_fail <= MAX_OUTLIER_SHARE * n:
        return True
    message = (
        f"{data.path}: {n_fail} of {n} rows fail the outlier test even at the residuals' own scale "
        f"{res.sigma * np.sqrt(inflation):.3g} mm (sigma {res.sigma:g} mm): not single bad points but a "
        "heavy-tailed spread; the model misses an effect (run `kpioed diagnose`) or the file mixes data "
        "of different set-ups"
    )
    if not force:
        raise InputError(
            message + "; use force to calibrate anyway without removing outliers", fields=("force",)
        )
    warnings.append(f"forced: {message}; no pose was removed")
    return False


def non_geometric_warning(screen: Screening) -> str | None:
    """The remark (for a fit the goodness-of-fit test rejects) when the residuals' robust scale
    exceeds sigma; None when it does not."""
    f = screen.scale_factor
    if not (np.isfinite(f) and f > 1.0):
        return None
    return (
        f"non-geometric rest, a-posteriori sigmas used: the residuals' robust scale {screen.scale_mm:.3g} mm "
        f"exceeds sigma {screen.sigma:g} mm ({f:.3g} times); gross errors were tested against "
        f"{screen.sigma_effective_mm:.3g} mm, so the poses of this spread are kept; use the a-posteriori "
        "standard deviations (std_aposteriori, kpi_cov_mm2_aposteriori)"
    )
