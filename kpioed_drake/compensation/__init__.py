"""Compensation: joint values with which a calibrated model is where the nominal one promised
(``kpioed compensate``).

- :mod:`.solve`: :func:`compensate_program` (a nominal program's poses) and :func:`reach_targets`
  (given points in W), both over the one forward map :func:`model_pose` (geometry and estimated
  effects), a vectorised projected Levenberg-Marquardt;
- :mod:`.report`: :class:`CompensationReport`, what a run computed and wrote, and its summary;
- :mod:`.workflow`: :func:`compensate_file`, the whole ``kpioed compensate`` run (program or target
  file in, the compensated joint values out; the effects of the model file, given or of a
  calibration's report).
"""

from kpioed_drake.compensation.report import CompensationReport
from kpioed_drake.compensation.solve import (
    Compensation,
    compensate_program,
    model_pose,
    reach_targets,
    rotation_error,
)
from kpioed_drake.compensation.workflow import ANGLES, compensate_file, effects_argument, file_effects

__all__ = [
    "ANGLES",
    "Compensation",
    "CompensationReport",
    "compensate_file",
    "compensate_program",
    "effects_argument",
    "file_effects",
    "model_pose",
    "reach_targets",
    "rotation_error",
]
