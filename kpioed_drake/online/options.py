"""The settings of one online step (:class:`NextOptions`)."""

from __future__ import annotations

import dataclasses
import math

from kpioed_drake.arguments import check_count, check_positive, check_seed
from kpioed_drake.errors import InputError, check_sigma


@dataclasses.dataclass(frozen=True)
class NextOptions:
    """The settings of one online step (:func:`next_poses`)."""

    target_var_mm2: float = 0.1
    """The TCP precision to reach: tr(Cs)/3 at the working pose [mm^2]."""
    n: int = 5
    """Poses to design when the precision is not reached yet."""
    sigma_mm: float = 0.02
    """The tracker's noise per coordinate [mm]; the a-posteriori noise replaces it when the fit
    rejects."""
    collision: bool = True
    """Avoid collisions of the robot, the cell and the laser beam."""
    seed: int = 0
    """Seed of the design's starts and of the certificate's search."""
    certify: bool = True
    """Add the certificate of the combined design (``bound_mm2``, ``efficiency``)."""
    max_plan: int = 60
    """Most poses planned ahead: the step designs the poses still needed to reach the target (at
    least ``n``, at most this many) and returns the ``n`` of them that help most now; ``n`` may not
    exceed it."""
    force: bool = False
    """Go on with data that fails the plausibility checks (warned in the summary)."""
    sigma_deg: float = 0.01
    """Data with a 6-DoF probe's orientations: their noise per tracker axis [deg] where the rows
    give none (as ``kpioed calibrate``'s); the next poses are designed at the median of the noise
    the fit weighted the orientations with."""
    kpi_orientation_mm: float = 0.0
    """Data with orientations: L [mm] >= 0, the TCP's orientation counts in the KPI as the
    displacement ``L * angle`` (tr(Cs)/3 = position variance + L^2 orientation variance [rad^2],
    as ``design --kpi-orientation-mm``); 0: the position alone (unless ``target_deg``)."""
    target_deg: float | None = None
    """Data with orientations: the TCP orientation's precision to reach with the position's, the
    RMS standard deviation per axis [deg]. The KPI is then the position's variance plus ``L^2``
    times the orientation's with ``L = sqrt(target_var_mm2) / target_deg [rad]``, so that it is at
    most ``target_var_mm2`` exactly when ``v_pos / V + v_rot / target_deg^2 <= 1``: both
    precisions reached (each at most its target) and the design, its bound and the plan all on one
    criterion. Not with ``kpi_orientation_mm``."""

    def __post_init__(self):
        check_positive("target_var_mm2", self.target_var_mm2)
        check_count("n", self.n)
        check_count("max_plan", self.max_plan)
        if self.n > self.max_plan:
            raise InputError(
                f"n {self.n}: expected at most max_plan ({self.max_plan}), the most poses a step plans ahead",
                fields=("n", "max_plan"),
            )
        check_sigma(self.sigma_mm)
        check_seed(self.seed)
        check_positive("sigma_deg", self.sigma_deg)
        check_positive("kpi_orientation_mm", self.kpi_orientation_mm, zero_ok=True)
        check_positive("target_deg", self.target_deg, allow_none=True)
        if self.target_deg is not None and self.kpi_orientation_mm > 0:
            raise InputError(
                "target_deg sets the orientation's weight L in the KPI itself: give it or "
                "kpi_orientation_mm, not both",
                fields=("target_deg", "kpi_orientation_mm"),
            )

    @property
    def orientation_weight_mm(self) -> float:
        """L [mm]: ``kpi_orientation_mm``, or ``sqrt(target_var_mm2) / target_deg [rad]``, or 0."""
        if self.target_deg is not None:
            return math.sqrt(self.target_var_mm2) / math.radians(self.target_deg)
        return float(self.kpi_orientation_mm)

    @property
    def with_orientation(self) -> bool:
        """An orientation target or weight was given (data with orientations needed)."""
        return self.target_deg is not None or self.kpi_orientation_mm > 0
