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
- **A 6-DoF probe's orientations**: a pose has a second statistic, its orientation residual's
  (:func:`kpioed_drake.estimation.residuals.orientation_normalized_residuals`), with its own robust
  scale ``s_rot = sqrt(median(u_i) / m3)`` [rad], ``u_i`` the statistic at a unit noise on every
  axis; each axis is tested at ``max(sigma_rot_i, s_rot)`` (rows may state their own sigmas, and a
  real robot's orientation rest is the same on every row, so a row whose stated sigma is small is
  not a gross error for that alone; with equal sigmas this is the positions' rule). Both parts are
  tested at the Bonferroni level ``alpha / (2 n_used)``, a pose is removed when either fails and
  its reason names the part (``position`` or ``orientation``).
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
from kpioed_drake.estimation.residuals import (
    leverage_blocks,
    normalized_residuals,
    orientation_normalized_residuals,
)
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


PARTS = ("position", "orientation")
"""The statistics of a pose, in :func:`~kpioed_drake.estimation.residuals.pose_statistics`' order
(the orientation's only with a 6-DoF probe's orientations)."""


@dataclasses.dataclass(frozen=True)
class Statistics:
    """The statistics of one fit the test compares (parts: :data:`PARTS`).

    Attributes:
        statistics: (parts, n) studentised statistics at the given noise (chi^2(3) under H0).
        effective: (parts, n) the same at the effective noise (each row's given noise, or the
            robust scale where that is larger), what the threshold is compared with.
        scales: (parts,) the robust scales [mm per coordinate, rad per axis] (nan: no used pose).
        noise: (parts, n) each row's effective noise [mm; rad, the RMS over its three axes].
    """

    statistics: np.ndarray
    effective: np.ndarray
    scales: np.ndarray
    noise: np.ndarray


def effective_statistics(res: EstimationResult, mask: np.ndarray) -> Statistics:
    """The statistics of ``res`` and, with the robust scales over the rows ``mask``, at the effective
    noise: positions ``t_i / max(1, s / sigma)^2``; orientations per axis at ``max(sigma_rot_i, s)``
    with ``s = sqrt(median(u_i) / 2.366)``, ``u_i`` the statistic at a unit noise on every axis [rad^2]
    (the same rule as the positions' when every row has the same noise)."""
    blocks = leverage_blocks(res.J)
    t = normalized_residuals(res, blocks=blocks)
    s = res.sigma * robust_scale_factor(t[mask])
    inflation = max(1.0, s / res.sigma) ** 2 if np.isfinite(s) else 1.0
    pos_noise = np.full(t.shape, res.sigma * np.sqrt(inflation))
    if res.sigma_rot is None:
        return Statistics(t[None], t[None] / inflation, np.array([s]), pos_noise[None])
    u = orientation_normalized_residuals(res, blocks=blocks, noise=np.ones_like(res.sigma_rot))
    s_rot = robust_scale_factor(np.asarray(u)[mask])
    given = res.sigma_rot / np.sqrt(res.weights)[:, None]
    noise = np.maximum(given, s_rot) if np.isfinite(s_rot) else given
    t_rot = orientation_normalized_residuals(res, blocks=blocks)
    t_eff = orientation_normalized_residuals(res, blocks=blocks, noise=noise)
    rot_noise = np.sqrt(np.mean(noise**2, axis=1))
    return Statistics(
        np.stack([t, t_rot]),
        np.stack([t / inflation, t_eff]),
        np.array([s, s_rot]),
        np.stack([pos_noise, rot_noise]),
    )


@dataclasses.dataclass
class Screening:
    """Outcome of :func:`screen_outliers`.

    Attributes:
        result: the final estimation (outliers excluded).
        outliers: indices (0-based) of the removed poses, in removal order.
        final: the statistics of ``result`` (:class:`Statistics`).
        threshold: chi^2(3) quantile of the last test (None: not tested).
        alpha: family-wise level (None: no test, or forced past a refusal).
        reasons: one record per removed pose: row, the part that failed, its statistic at the
            effective noise, the threshold, the effective noise and its residual's size.
        capped: the removal stopped at ``max_outlier_fraction`` with poses still failing.
    """

    result: EstimationResult
    outliers: list[int]
    final: Statistics
    threshold: float | None
    alpha: float | None
    reasons: list[dict]
    capped: bool = False

    @property
    def statistics(self) -> np.ndarray:
        """(parts, n) the final fit's statistics at the given noise."""
        return self.final.statistics

    @property
    def normalized(self) -> np.ndarray:
        """(n,) the position statistics."""
        return self.statistics[0]

    @property
    def scale_factor(self) -> float:
        """The positions' robust scale / sigma."""
        return float(self.final.scales[0] / self.sigma)

    @property
    def sigma(self) -> float:
        return self.result.sigma

    @property
    def scale_mm(self) -> float:
        """Robust scale of the residuals per coordinate [mm]."""
        return float(self.final.scales[0])

    @property
    def sigma_effective_mm(self) -> float:
        """The noise the outlier test used: ``max(sigma, scale)`` [mm]."""
        return float(self.final.noise[0, 0]) if self.final.noise.shape[1] else self.sigma

    def to_dict(self) -> dict:
        """The ``robust`` block of the JSON report (millimetres; an orientation block in degrees)."""
        out = {
            "scale_mm": None if not np.isfinite(self.scale_mm) else self.scale_mm,
            "sigma_mm": float(self.sigma),
            "sigma_effective_mm": self.sigma_effective_mm,
            "n_downweighted": 0,
            "n_removed": len(self.outliers),
            "capped": bool(self.capped),
            "reasons": list(self.reasons),
            "rule": "robust scale s = sigma sqrt(median(t_i) / 2.366) over the used poses (t_i the "
            "studentised residual at sigma, chi2(3)); a pose is a gross error when t_i / max(1, s/sigma)^2 "
            "exceeds the chi2(3) quantile at alpha / n_used; removed one at a time (the worst, then refit); "
            "rows are removed, never down-weighted",
        }
        if len(self.statistics) > 1:
            out["orientation"] = _orientation_block(self)
        return out


def _orientation_block(screen: Screening) -> dict:
    """The ``robust`` block's ``orientation`` entry of a fit with a probe's orientations [deg]."""
    s, used = float(screen.final.scales[1]), screen.result.mask
    return {
        "scale_deg": float(np.rad2deg(s)) if np.isfinite(s) else None,
        "sigma_deg_median": float(np.rad2deg(np.median(np.asarray(screen.result.sigma_rot)))),
        "sigma_effective_deg_median": float(np.rad2deg(np.median(screen.final.noise[1, used]))),
        "rule": "a pose has two statistics, its position's and its orientation's (e = log(R_meas R_model^T), "
        "studentised by its three orientation rows' leverage); the orientation's robust scale s = "
        "sqrt(median(u_i) / 2.366), u_i its statistic at a unit noise, and each axis tested at "
        "max(its sigma, s); both parts are tested at the chi2(3) quantile at alpha / (2 n_used) and a "
        "pose is removed when either fails (its reason's part)",
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

    With a 6-DoF probe's orientations each pose has a position and an orientation statistic, each
    tested at its own effective noise (:func:`effective_statistics`), both at the Bonferroni level
    ``alpha / (2 n_used)``: the pose whose larger one fails most is removed, its reason naming the part.

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
    mask = res.mask.copy()
    now = effective_statistics(res, mask)
    if alpha is None or not _few_fail(now, mask, res, data, alpha, force, warnings):
        return Screening(res, [], now, None, None, [])
    outliers: list[int] = []
    reasons: list[dict] = []
    max_out = int(np.floor(max_outlier_fraction * n))
    threshold, capped = None, False
    poses, kept = pose_groups(data), np.zeros(n, dtype=bool)
    while True:
        n_used = int(np.count_nonzero(mask))
        used = np.flatnonzero(mask & ~kept)
        if n_used - 1 < MIN_POSES_FOR_OUTLIER_TEST or used.size == 0:
            break
        threshold = float(chi2_dist.isf(alpha / (n_used * len(now.effective)), 3))
        part, k = np.unravel_index(int(np.argmax(now.effective[:, used])), (len(now.effective), used.size))
        worst = int(used[k])
        if now.effective[part, worst] <= threshold:
            break
        inflation = (now.noise[0, worst] / res.sigma) ** 2
        if part == 0 and _consistent_pose(
            res, data, np.flatnonzero(poses == poses[worst]), inflation, alpha, kept, warnings
        ):
            continue
        if len(outliers) >= max_out:
            capped = True
            warnings.append(
                f"outlier removal stopped after {len(outliers)} rows (cap {max_outlier_fraction:.0%} of the "
                f"data); row {int(data.rows[worst])} still fails the test ({PARTS[part]}) at "
                f"{_noise_text(now, int(part), worst)}: the residuals suggest model discrepancy rather "
                "than single bad points"
            )
            break
        reasons.append(_reason(res, data, now, worst, int(part), threshold))
        mask[worst] = False
        outliers.append(worst)
        res = refit(mask, res)
        now = effective_statistics(res, mask)
    return Screening(res, outliers, now, threshold, alpha, reasons, capped)


def _noise_text(now: Statistics, part: int, i: int) -> str:
    """Row ``i``'s effective noise of ``part``: ``0.02 mm``, or ``0.01 deg`` (RMS over the axes)."""
    return f"{now.noise[0, i]:.3g} mm" if part == 0 else f"{np.rad2deg(now.noise[1, i]):.3g} deg"


def _reason(res, data: Measurements, now: Statistics, i: int, part: int, threshold: float) -> dict:
    """The record of pose ``i`` removed for ``part`` (0 position, 1 orientation)."""
    out = {
        "row": int(data.rows[i]),
        "part": PARTS[part],
        "statistic": float(now.effective[part, i]),
        "threshold": threshold,
        "sigma_effective_mm": float(now.noise[0, i]),
        "residual_norm_mm": float(np.linalg.norm(res.residuals[i])),
        "why": f"gross error: its studentised {PARTS[part]} residual at the effective noise exceeds the "
        "threshold",
    }
    if res.rot_residuals is not None:
        out["sigma_effective_deg"] = float(np.rad2deg(now.noise[1, i]))
        out["residual_angle_deg"] = float(np.rad2deg(np.linalg.norm(res.rot_residuals[i])))
    return out


def removed_text(robust: dict, rows: list[int]) -> str:
    """``rows 5, 12`` of the removed rows (sorted), each with the part that failed
    (``rows 5 (orientation), 12 (position)``) when the screening had orientations."""
    if "orientation" not in robust:
        return f"rows {', '.join(map(str, rows))}"
    part = {r["row"]: r["part"] for r in robust.get("reasons", [])}
    return "rows " + ", ".join(f"{r} ({part.get(r, 'position')})" for r in rows)


def orientation_scale_line(robust: dict, tested: bool) -> str | None:
    """The summary's line on the orientation residuals' robust scale (None without orientations)."""
    o = robust.get("orientation")
    if o is None or o["scale_deg"] is None:
        return None
    how = (
        f"gross errors tested at {o['sigma_effective_deg_median']:.4g} deg (median)"
        if tested
        else "no outlier test"
    )
    return (
        f"  robust scale of the orientation residuals {o['scale_deg']:.4g} deg per axis "
        f"(sigma {o['sigma_deg_median']:.3g} deg, median): {how}"
    )


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


def _few_fail(now: Statistics, mask, res, data: Measurements, alpha: float, force: bool, warnings) -> bool:
    """False (forced) or an InputError when over a third of the poses fail at the effective noise
    (either part)."""
    n = data.n
    limit = chi2_dist.isf(alpha / (n * len(now.effective)), 3)
    n_fail = int(np.count_nonzero(np.any(now.effective[:, mask] > limit, axis=0)))
    if n_fail <= MAX_OUTLIER_SHARE * n:
        return True
    used = np.flatnonzero(mask)
    where = f"{np.median(now.noise[0, used]):.3g} mm (sigma {res.sigma:g} mm"
    if len(now.effective) > 1:
        where += f"; orientations {np.rad2deg(np.median(now.noise[1, used])):.3g} deg, median"
    message = (
        f"{data.path}: {n_fail} of {n} rows fail the outlier test even at the residuals' own scale "
        f"{where}): not single bad points but a heavy-tailed spread; the model misses an effect (run "
        "`kpioed diagnose`) or the file mixes data of different set-ups"
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
