"""Calibration and validation with plane contacts and distances from files (docs/contacts.md).

- :mod:`.environment`: the planes, pivots and bars as a model file's ``contact_environment`` and
  back, fitted alone with the robot held, and the residual figures;
- :mod:`.fit`: :func:`calibrate_contacts` and :class:`ContactCalibrationReport` (alone or with
  tracker points);
- :mod:`.workflow`: :func:`calibrate_contacts_file`, ``kpioed calibrate`` with ``planes`` or
  ``distances`` (the model file written with the estimated environment);
- :mod:`.validate`: :func:`validate_contacts_file`, ``kpioed validate`` of held-out contacts.
"""

from kpioed_drake.calibration.contacts.fit import ContactCalibrationReport, calibrate_contacts
from kpioed_drake.calibration.contacts.validate import (
    ContactValidationReport,
    contact_validation,
    validate_contacts_file,
)
from kpioed_drake.calibration.contacts.workflow import calibrate_contacts_file, contact_calibration

__all__ = [
    "ContactCalibrationReport",
    "ContactValidationReport",
    "calibrate_contacts",
    "calibrate_contacts_file",
    "contact_calibration",
    "contact_validation",
    "validate_contacts_file",
]
