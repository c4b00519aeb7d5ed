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
COUPLING_PAIRS = ((3, 2), (5, 4), (6, 4), (6, 5))
"""(i, j) of the ``joint_coupling:i:j`` candidates: joint i errs with the angle of a joint j whose axis
its drive train crosses (joint 3's drive through joint 2 on parallelogram arms; the wrist drives of
joints 5 and 6 through joint 4, and of joint 6 through joint 5)."""
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

    sigma_mm: float = 0.02
    """The known noise standard deviation per coordinate [mm]: the goodness-of-fit test and every
    likelihood ratio are taken against it."""
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
