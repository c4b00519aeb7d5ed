"""3-D scenes of designs, calibrations, validations, diagnoses as self-contained HTML pages (Drake Meshcat).

Modules: :mod:`.pages` (the pages), :mod:`.contacts` (the page of plane contacts and distances:
planes, touches, pivots, bars), :mod:`.probe` (a 6-DoF probe's measured and predicted frames as
triads), :mod:`.drawing` (robot, obstacles, beams and points drawn into a Meshcat scene),
:mod:`.canvas` (the scene recorded as one self-contained HTML file).

Public functions (plain arrays in, HTML text out; see :mod:`kpioed_drake.scene3d.pages`):
:func:`design_page`, :func:`calibration_page`, :func:`validation_page`, :func:`diagnosis_page`,
:func:`contact_page`, :func:`probe_frames` (a probe's frames for a page), :func:`write_page`, and
:func:`external_references` (markup of a page that would load from the network).
"""

from kpioed_drake.scene3d.canvas import INFEASIBLE, ROBOT, external_references
from kpioed_drake.scene3d.contacts import contact_page
from kpioed_drake.scene3d.pages import (
    calibration_page,
    design_page,
    diagnosis_page,
    validation_page,
    write_page,
)
from kpioed_drake.scene3d.probe import ProbeFrames, probe_frames

__all__ = [
    "INFEASIBLE",
    "ROBOT",
    "ProbeFrames",
    "calibration_page",
    "contact_page",
    "design_page",
    "diagnosis_page",
    "external_references",
    "probe_frames",
    "validation_page",
    "write_page",
]
