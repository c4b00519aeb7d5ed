"""Model discrepancy: does the geometric model explain the data, and if not, which effect is missing?

One module per concern (method and JSON contract: docs/diagnosis.md):

- :mod:`.workflow`: :func:`diagnose`, the four steps (calibration and goodness of fit, residual
  structure, stepwise selection of the cause, the extended model and its gain);
- :mod:`.fit`: :class:`FitProblem` (immutable), fits of any set of effects on any subset of poses
  with the package's one estimator (:mod:`kpioed_drake.estimation.estimator`), cross-validation, a
  step's independent fits in worker processes (:func:`~.fit.independent`);
- :mod:`.selection`: candidates, identifiability, score tests, stepwise selection; :mod:`.pairs`:
  pairs of candidates that cancel; :mod:`.sides`: the side of a backlash under the mass prior;
- :mod:`.elastic_basis`: elasticity (and backlash) with other link masses than the file's, and how
  far a mass-free basis turns what its joint carries;
- :mod:`.alternatives`: competing explanations of each cause, the named causes;
- :mod:`.records`: the frozen records passed between them (a candidate's test, a step, the
  selection, a cause);
- :mod:`.report`: :class:`DiagnosisReport`, its JSON built from the records, and the numbers in it;
- :mod:`.plots`: residual pictures (``kpioed diagnose --plots``);
- :mod:`.options`: levels and limits, and :class:`DiagnosisOptions`.
"""

from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.options import (
    ALPHA,
    FOLD_SEED,
    K_FOLDS,
    MAX_SWAPS,
    MIN_REMAINING,
    DiagnosisOptions,
    load_options,
)
from kpioed_drake.diagnosis.report import DiagnosisReport
from kpioed_drake.diagnosis.selection import candidate_effects, score_tests
from kpioed_drake.diagnosis.workflow import diagnose, diagnose_file
from kpioed_drake.estimation.identifiability import identifiability

__all__ = [
    "ALPHA",
    "FOLD_SEED",
    "K_FOLDS",
    "MAX_SWAPS",
    "MIN_REMAINING",
    "DiagnosisOptions",
    "DiagnosisReport",
    "Fit",
    "FitProblem",
    "candidate_effects",
    "diagnose",
    "diagnose_file",
    "identifiability",
    "load_options",
    "score_tests",
]
