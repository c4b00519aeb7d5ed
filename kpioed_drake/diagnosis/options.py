"""Settings of the diagnosis: the levels, folds and limits its modules share, and the options of one
run (:class:`DiagnosisOptions`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from kpioed_drake import options

ALPHA = 0.01
"""Level of the goodness-of-fit test and family-wise level of each selection step."""
MIN_REMAINING = 0.05
"""A candidate whose columns keep less than this fraction outside the model's span is 'absorbed'."""
K_FOLDS = 5
"""Folds of the cross-validation over poses."""
MAX_SWAPS = 4
"""Most swaps of a named cause for a competing candidate (:func:`~.alternatives.settle`)."""
GAIN_STANDARD_ERRORS = 2.0
"""A candidate joins when its held-out gain exceeds this many standard errors: its uncertainty, the
half-width of about a 95 % interval (:func:`~kpioed_drake.diagnosis.fit.held_out_gain`)."""
FOLD_SEED = 0
"""Seed of the random assignment of poses to folds."""
NESTED_REMAINING = 0.1
"""A significant candidate of which no direction keeps more than this fraction outside the span of the
named causes and the geometry is reported as a nested alternative of the cause that holds it ..."""
NESTED_SHARE = 1.0 / 3.0
"""... and at most this share of what it keeps outside the span of the other causes (the cause holds it)."""
MAX_ALTERNATIVES = 3
"""Most competing explanations listed per cause."""
DEFAULT_SIGMA_MM = 0.02
"""The tracker's noise per coordinate [mm]: the sigma when none is given and the data repeat no pose
(checked against the residuals, :mod:`kpioed_drake.estimation.noise`)."""
PARALLEL_MIN_ENTRIES = 200_000
"""A step's independent fits run in worker processes (:func:`~.fit.independent`) when the problem's
weighted Jacobian (3 rows a measured point, a column a parameter) has at least this many entries:
about where one fit takes longer than starting the workers."""
BACKLASH_MIN_SIDE = 3
"""Poses a backlash candidate needs on each side of the gravity torque (as ``calibrate --extend``)."""
PAIR_CORRELATION = 0.5
"""Two candidates whose projected columns have a canonical correlation of at least this can cancel
each other; when no single candidate qualifies they are tested together (:mod:`.pairs`)."""
PAIR_ALPHA_SHARE = 0.1
"""The pair step's family-wise level is this share of ``alpha``: it runs once per diagnosis, after the
last single step, and spends a tenth of the level the single steps have (a false alarm on clean data
needs the goodness-of-fit test, a single step or the pair step: at most 2.1 alpha)."""


@dataclasses.dataclass(frozen=True)
class DiagnosisOptions:
    """The settings of one diagnosis (:func:`~kpioed_drake.diagnosis.diagnose`); read from YAML
    with :func:`load_options`."""

    sigma_mm: float | None = None
    """The known noise standard deviation per coordinate [mm]; None: measured on the data's repeated
    poses, else :data:`DEFAULT_SIGMA_MM`. The goodness-of-fit test and every likelihood ratio are
    taken against it, unless the residuals of the model with every candidate lie far above it
    (:mod:`kpioed_drake.estimation.noise`; the report's ``noise`` says which sigma and why)."""
    alpha: float = ALPHA
    """Level of the goodness-of-fit test and family-wise level of each selection step."""
    k_folds: int = K_FOLDS
    """Folds of the cross-validation over poses (the held-out error)."""
    max_effects: int | None = None
    """Most effects the stepwise selection adds; None: as many as predict the held-out poses better
    by more than their uncertainty (:func:`~kpioed_drake.diagnosis.fit.held_out_gain`)."""
    candidates: tuple[str, ...] | None = None
    """The candidate effects as texts (``gear_cyclic:2:1``, ``backlash:3``; docs/diagnosis.md, "Effect
    models"); None: the candidates these data can reveal
    (:func:`~kpioed_drake.diagnosis.selection.candidate_effects`)."""
    force: bool = False
    """Go on with implausible data
    (:func:`~kpioed_drake.estimation.plausibility.check_data`), noted in the report."""


def load_options(*, filename: str | Path | None = None, data: str | None = None) -> DiagnosisOptions:
    """:class:`DiagnosisOptions` from a YAML file or text (:func:`kpioed_drake.options.load_options`)."""
    return options.load_options(DiagnosisOptions, filename=filename, data=data)
