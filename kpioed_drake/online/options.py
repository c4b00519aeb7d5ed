"""The settings of one online step (:class:`NextOptions`)."""

from __future__ import annotations

import dataclasses

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
