"""3-D scenes of designs, calibrations and diagnoses as self-contained HTML pages (Drake Meshcat).

Modules: :mod:`.pages` (the pages), :mod:`.drawing` (robot, obstacles, beams and points drawn into
a Meshcat scene), :mod:`.canvas` (the scene recorded as one self-contained HTML file).

Public functions (plain arrays in, HTML text out; see :mod:`kpioed_drake.scene3d.pages`):
:func:`design_page`, :func:`calibration_page`, :func:`diagnosis_page`, :func:`write_page`, and
:func:`external_references` (markup of a page that would load from the network).
"""

from kpioed_drake.scene3d.canvas import INFEASIBLE, ROBOT, external_references
from kpioed_drake.scene3d.pages import calibration_page, design_page, diagnosis_page, write_page

__all__ = [
    "INFEASIBLE",
    "ROBOT",
    "calibration_page",
    "design_page",
    "diagnosis_page",
    "external_references",
    "write_page",
]
