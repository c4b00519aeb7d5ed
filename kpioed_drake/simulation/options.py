"""The settings of one simulation (:class:`SimulationOptions`)."""

from __future__ import annotations

import dataclasses

from kpioed_drake.arguments import check_seed, require
from kpioed_drake.errors import check_sigma


@dataclasses.dataclass(frozen=True)
class SimulationOptions:
    """The settings of one simulation (:func:`simulate`); read from YAML with
    :func:`kpioed_drake.options.load_options`."""

    sigma_mm: float = 0.02
    """Measurement noise per coordinate [mm] (0: noise free)."""
    seed: int = 0
    """Seed of ``numpy.random.default_rng``: geometric errors, tracker frame, effects and noise."""
    effects: tuple[str, ...] = ()
    """Non-geometric effects of the truth (texts parsed by ``effects.parse_effect``, or effect
    objects); empty: the geometric model (and an extended model file's own effects)."""
    geometric_errors: bool = True
    """Draw random geometric errors (False: the true robot is the nominal one)."""
    n_targets: int | None = None
    """Targets measured at every pose, the first of the model file's ``targets_mm`` (None: all)."""

    orientation_sigma_deg: float | None = None
    """Also a 6-DoF probe's orientations, with this noise about each tracker axis [deg] (0: noise
    free); None: points only."""

    def __post_init__(self):
        check_sigma(self.sigma_mm, zero_ok=True)
        s = self.orientation_sigma_deg
        ok = s is None or (isinstance(s, int | float) and not isinstance(s, bool) and 0 <= s < 180)
        what = f"orientation_sigma_deg: expected a number of degrees in [0, 180) or None, got {s!r}"
        require(ok, what, fields=("orientation_sigma_deg",))
        check_seed(self.seed)
        if isinstance(self.effects, str):
            object.__setattr__(self, "effects", (self.effects,))
        object.__setattr__(self, "effects", tuple(self.effects or ()))
