"""The settings of one simulation (:class:`SimulationOptions`)."""

from __future__ import annotations

import dataclasses

from kpioed_drake.arguments import check_seed
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

    def __post_init__(self):
        check_sigma(self.sigma_mm, zero_ok=True)
        check_seed(self.seed)
        if isinstance(self.effects, str):
            object.__setattr__(self, "effects", (self.effects,))
        object.__setattr__(self, "effects", tuple(self.effects or ()))
