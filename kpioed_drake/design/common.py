"""The design methods and the optimiser's settings shared by its modules (margins, sizes, sweeps).

Each value was measured on kr16 unless said otherwise (bench/results.md, docs/studies.md).
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
the heuristic). "Default when it wins" (issue 14): with the exchange pass after the rounding the
approximate start met both targets in one benchmark run (bench/bound_results.md,
docs/certificate.md; 60 poses, seeds 0-2): certified efficiency >= 0.95 on kr16, kr300, kr500
and >= 0.93 on the notional robots, at most twice the heuristic start's median time per design.
``start="heuristic"`` keeps the paper's start (and the numbers before the switch)."""
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
feasible set as all 51 rows; SNOPT's work per iteration grows with the number of rows). Measured on
kr16 (bench/results.md): 4 was faster than 3, 6, 8 and all rows, and reached the same optima."""
MAX_BLOCK_POSES = 60
"""Most poses one solve varies by default. SNOPT's work per major iteration grows about as n nS^2
(nS, the number of free "superbasic" variables, is about half of the 6n angles): one solve over all
240 poses took 110 s against 3.5 s at 60 poses. Larger designs are optimised by sweeps over blocks of
:data:`SWEEP_BLOCK_POSES` poses, each solved with the other poses' information held fixed; the
constraints hold pose by pose, so a block problem is the full problem restricted to the block.
Measured on kr16 (seed 0, bench/results.md): 120 poses 12.7 s to tr(Cs)/3 = 0.0292 mm^2 against
22.4 s to 0.0300 in one solve; 240 poses 15.5 s to 0.01456 against 110 s to 0.01463. At 60 poses
sweeps were slower than one solve (3.9-7.2 s against 2.5-4.7 s, 5 seeds)."""
SWEEP_BLOCK_POSES = 30
"""Poses per block in sweeps. Blocks of 60 instead took 15.9 s (120 poses) and 25.6 s (240 poses)
and ended higher (0.0301, 0.01466)."""
SWEEP_RTOL = 1e-3
"""Sweeps stop when one lowers the criterion by less than this fraction (of its normalisation,
:meth:`kpioed_drake.estimation.criteria.Criterion.normalisation`)."""
MAX_SWEEPS = 10
"""Most sweeps."""
POSE_BLOCK = 10
"""Poses per constraint binding by default. Drake hands a Python constraint's gradient over as one
AutoDiffXd per row with a derivative per variable of the binding: with one binding over all 6n
variables that is a dense (rows, 6n) matrix whose conversion grew faster than n^2 (4.3 ms of an
evaluation at 60 poses). With bindings of 10 poses the conversion costs 1.2 ms in all; the rows of
every pose are still computed in one vectorised call (see
:class:`~kpioed_drake.design.exact.program.DesignProgram`)."""


def as_poses(q, n_joints: int = N_JOINTS) -> np.ndarray:
    """``q`` as an (n, n_joints) float array of poses [rad] (a flat vector is pose-major)."""
    return np.asarray(q, dtype=float).reshape(-1, n_joints)


def method_label(method: str) -> str:
    """Name of a design method for tables and printed summaries (``heuristic``, ``KPI``, ...)."""
    return "heuristic" if method == "heuristic" else TABLE[method].label
