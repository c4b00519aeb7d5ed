"""The options of a calibration (:class:`CalibrationOptions`), shared by the plain and the extended
fit, ``kpioed calibrate``, ``kpioed diagnose`` and ``kpioed next``."""

from __future__ import annotations

import dataclasses

from kpioed_drake.arguments import require
from kpioed_drake.errors import check_sigma


@dataclasses.dataclass(frozen=True)
class CalibrationOptions:
    """The settings of one calibration (:func:`~kpioed_drake.calibration.fit.calibrate`); read from
    YAML with :func:`kpioed_drake.options.load_options`."""

    sigma_mm: float = 0.02
    """Noise standard deviation per coordinate [mm]: the weight of the fit, its goodness-of-fit test
    and the a-priori covariance."""
    sigma_deg: float = 0.01
    """Noise standard deviation of a 6-DoF probe's orientation about each tracker axis [deg], for
    data with orientations whose rows give none (``sigma_rot_rad``): the weight of the orientation
    rows. 0.01 deg is about a T-Mac probe's stated orientation accuracy and above the public UR10
    set's per-row values (medians 0.002-0.0035 deg, 95th percentiles up to 0.008 deg)."""
    effects: tuple[str, ...] = ()
    """Non-geometric effects estimated with the geometry (texts such as ``joint_elasticity:2``,
    joints 1..n_joints, or :class:`~kpioed_drake.effects.Effect` objects; their starting values the
    given ones, 0 when unknown): the extended model."""
    outlier_alpha: float = 0.01
    """Family-wise false-alarm level of the outlier test (Bonferroni: each pose at alpha / n), in
    [0, 1); 0: no test."""
    max_outlier_fraction: float = 0.1
    """The outlier test removes at most this fraction of the poses."""
    max_iter: int = 100
    """Most Levenberg-Marquardt iterations of one fit."""
    force: bool = False
    """Go on with implausible data (:func:`kpioed_drake.estimation.plausibility.check_data`), with a
    warning."""
    strict: bool = False
    """Refuse poses that do not determine every free parameter instead of holding the undetermined
    ones at nominal with a warning."""

    def __post_init__(self):
        check_sigma(self.sigma_mm)
        d = self.sigma_deg
        ok = isinstance(d, int | float) and not isinstance(d, bool) and 0 < d < 180
        require(ok, f"sigma_deg: expected a number of degrees in (0, 180), got {d!r}", fields=("sigma_deg",))
        a = self.outlier_alpha
        ok = isinstance(a, int | float) and not isinstance(a, bool) and 0 <= a < 1
        require(ok, f"outlier_alpha: expected a number in [0, 1), got {a!r}", fields=("outlier_alpha",))
        f = self.max_outlier_fraction
        ok = isinstance(f, int | float) and 0 <= f < 1
        what = f"max_outlier_fraction: expected a number in [0, 1), got {f!r}"
        require(ok, what, fields=("max_outlier_fraction",))
        require(
            isinstance(self.max_iter, int) and self.max_iter >= 1,
            f"max_iter: expected a positive integer, got {self.max_iter!r}",
            fields=("max_iter",),
        )
        if isinstance(self.effects, str):
            object.__setattr__(self, "effects", (self.effects,))
        object.__setattr__(self, "effects", tuple(self.effects or ()))
