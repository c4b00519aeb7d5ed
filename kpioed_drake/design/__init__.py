"""Optimum experimental design (OED) of measurement poses, paper eq. (24), and the heuristic design.

The design problem (paper eq. 24a-e) chooses ``n`` measurement poses ``q`` (n, 6) [rad] that
minimise a criterion of the covariance of the identified parameters,

    min_q  phi(C(q))   s.t.  q_lo <= q_i <= q_up,
                             incidence angle of pose i <= max incidence (eq. 4),
                             every capsule clearance of pose i >= 0 (eq. 20-22),

with ``C`` from the KKT system of eq. (24c), ``F1 = dh/dp / sigma`` (eq. 24d) and
``F2 = dTCP/dp`` at the working pose ``q_work`` (eq. 24e; several working poses or a sampled path:
the weighted mean or the worst of their variances, paper Outlook). The criteria ``phi`` (``kpi``, the
paper's method; ``param``, the standard method; ``d``; ``o1``) are those of
:mod:`kpioed_drake.estimation.criteria`. The design methods (:data:`DESIGN_METHODS`) are the heuristic and the
optimum design for each criterion.

Modules, in dependency order:

- :mod:`~kpioed_drake.design.settings`: the design methods, solvers and the optimiser's settings;
- :mod:`~kpioed_drake.design.heuristic`: the paper's heuristic (uniform random feasible poses), also
  the optimiser's default start;
- :mod:`~kpioed_drake.design.exact.objective`: the cost and its closed-form gradient;
- :mod:`~kpioed_drake.design.exact.constraints`: incidence and clearance rows pose by pose, and the
  choice of each pose's smallest clearance rows;
- :mod:`~kpioed_drake.design.exact.program`: the Drake ``MathematicalProgram`` (one cost, constraint
  bindings of 10 poses);
- :mod:`~kpioed_drake.design.exact.check`: the independent check with Drake signed distances;
- :mod:`~kpioed_drake.design.exact.solve`: SNOPT/IPOPT settings, one solve, the checked solve with its
  all-rows retry, and block sweeps for designs over 60 poses;
- :mod:`~kpioed_drake.design.approximate.search`: local maxima over the feasible poses of the pricing function
  ``g(x) = ||F_x Y||^2`` of a dual matrix ``Y``, and starts with joints at their limits;
- :mod:`~kpioed_drake.design.approximate.design`: the approximate KPI design (weights on poses) by column
  generation with a Clarabel cone program, its efficient rounding to n poses
  (:func:`approximate_start`, the optimiser's ``start="approximate"``);
- :mod:`~kpioed_drake.design.approximate.certificate`: the optimality certificate, a lower bound on
  tr(Cs)/3 of any n-pose design and a design's efficiency (:func:`certify`; rigorous over the poses evaluated,
  a search over the continuous feasible set; docs/certificate.md);
- :mod:`~kpioed_drake.design.polish`: the final exchange on the exact criterion after the optimiser
  (the optimiser's poses and the approximate design's candidates as one pool) and the greedy
  removal of poses (:func:`remove_poses`);
- :mod:`~kpioed_drake.design.report`: :class:`DesignReport`, its JSON record and summary;
- :mod:`~kpioed_drake.design.starts`: where the solves start (the heuristic or the rounded approximate
  design; :func:`resolve_start`);
- :mod:`~kpioed_drake.design.optimize`: :func:`optimize_design`, the entry point (also with poses
  already measured held fixed: ``given``, sequential re-identification);
- :mod:`~kpioed_drake.design.target`: :func:`design_for_target`, the fewest poses reaching a target
  tr(Cs)/3 (paper, Conclusion);
- :mod:`~kpioed_drake.design.options`: :class:`DesignOptions`, the settings of one design;
- :mod:`~kpioed_drake.design.plots` and :mod:`~kpioed_drake.design.workflow`: pictures, the
  ``kpioed design`` file workflow (:func:`run_design`) and :func:`demo`;
- :mod:`~kpioed_drake.design.discriminate.design`: designs that tell two explanations (effects) apart,
  T-optimal through the worst case of the KPI machinery (:func:`discrimination_design`,
  ``kpioed design --discriminate "A|B"``);
- :mod:`~kpioed_drake.design.contact`: the KPI design of contact systems without a tracker, plane
  touches or a pivot ballbar (one row per pose; :func:`~kpioed_drake.design.contact.design.contact_design`,
  ``kpioed design --measure plane|ballbar``; the poses stay on the planes or the pivot's sphere by
  projection, not by constraints of the exact design's program);
- :mod:`~kpioed_drake.design.evaluate`: ``kpioed evaluate`` (:func:`evaluate_file`), a given design's
  KPI variance, criteria and feasibility.

Every returned design is checked independently by
:class:`~kpioed_drake.tracker.feasibility.FeasibilityChecker` (Drake signed-distance queries), never
by the optimiser's own constraint functions.

Units: millimetres and radians inside; degrees in files and on the command line.
"""

from kpioed_drake.design.approximate.certificate import (
    PoolCertificate,
    certificate_fields,
    certificate_line,
    certified_design,
    certify,
    pool_certificate,
)
from kpioed_drake.design.approximate.design import ApproximateDesign, approximate_design, approximate_start
from kpioed_drake.design.discriminate.design import (
    DiscriminationReport,
    discrimination_design,
    discrimination_lines,
)
from kpioed_drake.design.evaluate import evaluate_file
from kpioed_drake.design.exact.check import DesignCheck, check_design
from kpioed_drake.design.exact.constraints import DesignConstraints, incidence_rows, update_active_rows
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.exact.program import DesignProgram
from kpioed_drake.design.exact.solve import solver_options
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.optimize import min_new_poses, optimize_design
from kpioed_drake.design.options import DesignOptions
from kpioed_drake.design.plots import plot_design_poses
from kpioed_drake.design.polish import remove_poses
from kpioed_drake.design.report import DesignError, DesignReport, format_summary, json_record
from kpioed_drake.design.settings import (
    ACTIVE_ROWS_PER_POSE,
    CLEARANCE_MARGIN_MM,
    CLEARANCE_ROW_SCALE,
    DEFAULT_START,
    DESIGN_METHODS,
    HEURISTIC_MARGIN_MM,
    INCIDENCE_MARGIN_DEG,
    MAX_BLOCK_POSES,
    MAX_SWEEPS,
    POSE_BLOCK,
    SOLVERS,
    START_METHODS,
    SWEEP_BLOCK_POSES,
    SWEEP_RTOL,
    method_label,
)
from kpioed_drake.design.starts import resolve_start
from kpioed_drake.design.target import MAX_TARGET_POSES, design_for_target
from kpioed_drake.design.workflow import demo, read_working_poses, run_design
from kpioed_drake.estimation.criteria import CRITERIA

DESIGN_CRITERIA = DESIGN_METHODS
"""Alias of :data:`DESIGN_METHODS`, kept for callers of the older name."""

__all__ = [
    "ACTIVE_ROWS_PER_POSE",
    "CLEARANCE_MARGIN_MM",
    "CLEARANCE_ROW_SCALE",
    "CRITERIA",
    "DEFAULT_START",
    "DESIGN_CRITERIA",
    "DESIGN_METHODS",
    "HEURISTIC_MARGIN_MM",
    "INCIDENCE_MARGIN_DEG",
    "MAX_BLOCK_POSES",
    "MAX_SWEEPS",
    "MAX_TARGET_POSES",
    "POSE_BLOCK",
    "SOLVERS",
    "START_METHODS",
    "SWEEP_BLOCK_POSES",
    "SWEEP_RTOL",
    "ApproximateDesign",
    "DesignCheck",
    "DesignConstraints",
    "DesignError",
    "DesignObjective",
    "DesignProgram",
    "DesignReport",
    "DiscriminationReport",
    "PoolCertificate",
    "approximate_design",
    "approximate_start",
    "certificate_fields",
    "certificate_line",
    "certified_design",
    "certify",
    "check_design",
    "demo",
    "discrimination_design",
    "discrimination_lines",
    "evaluate_file",
    "design_for_target",
    "format_summary",
    "heuristic_design",
    "incidence_rows",
    "json_record",
    "method_label",
    "min_new_poses",
    "optimize_design",
    "plot_design_poses",
    "pool_certificate",
    "read_working_poses",
    "remove_poses",
    "resolve_start",
    "run_design",
    "DesignOptions",
    "solver_options",
    "update_active_rows",
]
