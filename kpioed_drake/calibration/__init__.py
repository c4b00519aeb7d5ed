"""Calibration from measured laser-tracker data (SPEC "Measured data and model discrepancy").

One module per concern:

- :mod:`.options`: :class:`CalibrationOptions`, the settings of one calibration;
- :mod:`.inputs`: :func:`~kpioed_drake.calibration.inputs.read_inputs`, the robot, cell and data of
  a command on a measurement file, loaded once after the paths are checked;
- :mod:`.kpi`: the working pose and the KPI (TCP at the working pose) with its covariance, shared by
  the plain and the extended fit;
- :mod:`.fit`: :func:`calibrate`, registration, least squares on the free geometric parameters
  (and the values of non-geometric effects: an extended model), outlier handling, goodness of fit,
  the KPI and its covariance;
- :mod:`.robust`: the outlier screening against ``max(sigma, robust scale of the residuals)``;
- :mod:`.extended`: :func:`resolve_extension`, the effects of an extended calibration sized for the
  robot and the data (``kpioed calibrate --extend``);
- :mod:`.report`: :class:`CalibrationReport` (JSON report and text summary);
- :mod:`.modelfile`: :func:`calibrated_robot_yaml`, the calibrated robot as a model file;
- :mod:`.plots`: residual plots;
- :mod:`.workflow`: :func:`calibrate_file`, the whole ``kpioed calibrate`` run;
- :mod:`.validate`: ``kpioed validate``, a model's predictions of fresh measurements (nothing
  fitted; :func:`~kpioed_drake.calibration.validate.validate_file`);
- :mod:`.contacts`: the same two commands on plane-contact and distance files (docs/contacts.md):
  the fit with the planes, pivots and bars written into the model file, held-out contacts scored
  with them.

Reading and validating the data: :mod:`kpioed_drake.tracker.data`.
"""

from kpioed_drake.calibration.extended import resolve_extension
from kpioed_drake.calibration.fit import MIN_POSES_FOR_OUTLIER_TEST, calibrate, hold_undetermined
from kpioed_drake.calibration.kpi import kpi_and_covariance, working_pose
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.plots import plot_calibration
from kpioed_drake.calibration.report import N_CORRELATIONS, CalibrationReport
from kpioed_drake.calibration.workflow import calibrate_file
from kpioed_drake.files.tables import ROW_CONVENTION
from kpioed_drake.tracker.data import Measurements, read_measurements

__all__ = [
    "MIN_POSES_FOR_OUTLIER_TEST",
    "N_CORRELATIONS",
    "ROW_CONVENTION",
    "CalibrationOptions",
    "CalibrationReport",
    "Measurements",
    "calibrate",
    "hold_undetermined",
    "calibrate_file",
    "calibrated_robot_yaml",
    "kpi_and_covariance",
    "plot_calibration",
    "read_measurements",
    "resolve_extension",
    "working_pose",
]
