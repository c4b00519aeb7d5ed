"""The KPI design of contact systems: plane touches or a pivot ballbar, one row per pose.

:mod:`.surfaces` (the systems: planes, and ballbar pivots whose spheres the tool ball stays on; each
one's residual, gradient, rows and rules), :mod:`.poses` (the feasible set: poses on a surface,
sampled, projected and checked), :mod:`.problem` (:class:`ContactProblem`: F1 of the poses and its
closed-form dF1/dq, the contact gauge), :mod:`.design` (the approximate design on the surfaces by
column generation with a search that stays on them, its rounding and the certificate's lower bound),
:mod:`.inputs` (plane sets from files, a robot's default planes, a pivot from text) and
:mod:`.workflow` (``kpioed design --measure plane|ballbar``: :func:`contact_design_file`, its CSV,
JSON record and Drake's check of the poses).
"""

from kpioed_drake.design.contact.design import ContactDesign, ballbar_design, contact_design, plane_design
from kpioed_drake.design.contact.problem import ContactProblem, make_ballbar_problem, make_plane_problem
from kpioed_drake.design.contact.workflow import ContactDesignReport, contact_design_file

__all__ = [
    "ContactDesign",
    "ContactDesignReport",
    "ContactProblem",
    "ballbar_design",
    "contact_design",
    "contact_design_file",
    "make_ballbar_problem",
    "make_plane_problem",
    "plane_design",
]
