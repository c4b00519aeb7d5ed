"""The design methods and the optimiser's settings shared by its modules (margins, sizes, sweeps).

The measurements behind the values: docs/design.md.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.estimation.criteria import CRITERIA, TABLE
from kpioed_drake.robot.models import N_JOINTS

DESIGN_METHODS: tuple[str, ...] = ("heuristic", *CRITERIA)
"""Everything :func:`~kpioed_drake.design.optimize.optimize_design` accepts as ``criterion``: the
heuristic (paper 3.2) and the optimum designs of the criteria of :mod:`kpioed_drake.estimation.criteria`."""
START_METHODS = ("heuristic", "approximate")
"""Starts of the optimiser (``start`` of :func:`~kpioed_drake.design.optimize.optimize_design`):
the paper's heuristic (random feasible poses) or, for the ``kpi`` criterion only, the approximate
design rounded to n poses (:func:`~kpioed_drake.design.approximate.design.approximate_start`)."""
DEFAULT_START = "approximate"
"""The start of the ``kpi`` criterion when none is asked for (other criteria and ``given`` poses:
the heuristic): with the exchange pass after the rounding, its designs have a higher certified
efficiency than the heuristic start's, in under twice its median time per design
(docs/certificate.md). ``start="heuristic"`` keeps the paper's start."""
SOLVERS = ("snopt", "ipopt")
"""NLP solvers :func:`~kpioed_drake.design.optimize.optimize_design` can use (both bundled with pydrake)."""

HEURISTIC_MARGIN_MM = 1.0
"""Smallest clearance [mm] of a pose the heuristic keeps (a feasible, not grazing, start)."""
CLEARANCE_ROW_SCALE = 1e-2
"""Clearance rows are passed to the solver in units of 100 mm (incidence rows are cosines, O(1))."""
INCIDENCE_MARGIN_DEG = 1e-4
"""The optimiser keeps the incidence angle this far inside the limit [deg], so that a pose on the
limit still passes the independent check (tolerance :data:`~kpioed_drake.tracker.feasibility.TOL_DEG`,
1e-4 deg) despite the solver's own feasibility tolerance (SNOPT's is relative to the size of the
solution vector); an overshoot beyond both is pulled back by
:func:`~kpioed_drake.design.exact.constraints.restore_incidence`."""
CLEARANCE_MARGIN_MM = 1e-3
"""The optimiser keeps every clearance at least this large [mm] (the check's tolerance is -1e-3)."""
ACTIVE_ROWS_PER_POSE = 4
"""Clearance rows per pose the solver sees by default: the pose's 4 smallest clearances (the same
feasible set as all 51 rows; SNOPT's work per iteration grows with the number of rows). 4 is the
fastest count that reaches the same optima (docs/design.md)."""
MAX_BLOCK_POSES = 60
"""Most poses one solve varies by default. SNOPT's work per major iteration grows about as n nS^2
(nS, the number of free "superbasic" variables, is about half of the 6n angles), so one solve over
hundreds of poses is slow. Larger designs are optimised by sweeps over blocks of
:data:`SWEEP_BLOCK_POSES` poses, each solved with the other poses' information held fixed; the
constraints hold pose by pose, so a block problem is the full problem restricted to the block.
Above 60 poses sweeps are faster than one solve and end as low or lower; at 60 they are slower
(docs/design.md)."""
LARGE_SOLVE_VARIABLES = MAX_BLOCK_POSES * N_JOINTS
"""Joint variables (poses x joints) of a design above which it counts as large (360, the most a
six-joint solve varies; the 18-joint twin's 40 poses are 720). Above it SNOPT stops at a looser
optimality tolerance and the certificate refines its bound only below efficiency 0.97
(docs/design.md, docs/certificate.md)."""


SWEEP_BLOCK_POSES = 30
"""Poses per block in sweeps: faster than blocks of 60 and ending lower (docs/design.md)."""
SWEEP_RTOL = 1e-3
"""Sweeps stop when one lowers the criterion by less than this fraction (of its normalisation,
:meth:`kpioed_drake.estimation.criteria.Criterion.normalisation`)."""
MAX_SWEEPS = 10
"""Most sweeps."""
POSE_BLOCK = 10
"""Poses per constraint binding by default. Drake hands a Python constraint's gradient over as one
AutoDiffXd per row with a derivative per variable of the binding: with one binding over all 6n
variables that is a dense (rows, 6n) matrix whose conversion grows faster than n^2; bindings of 10
poses keep it to a fraction (docs/design.md). The rows of every pose are still computed in one
vectorised call (see
:class:`~kpioed_drake.design.exact.program.DesignProgram`)."""


def as_poses(q: np.ndarray, n_joints: int = N_JOINTS) -> np.ndarray:
    """``q`` as an (n, n_joints) float array of poses [rad] (a flat vector is pose-major)."""
    return np.asarray(q, dtype=float).reshape(-1, n_joints)


def method_label(method: str) -> str:
    """Name of a design method for tables and printed summaries (``heuristic``, ``KPI``, ...)."""
    return "heuristic" if method == "heuristic" else TABLE[method].label


def is_large(n: int, n_joints: int) -> bool:
    """Whether a design of ``n`` poses of a ``n_joints``-joint robot has more than
    :data:`LARGE_SOLVE_VARIABLES` joint variables (the one rule of the solver and the certificate)."""
    return n * n_joints > LARGE_SOLVE_VARIABLES
