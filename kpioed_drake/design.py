"""Optimum experimental design (OED) of measurement poses, paper eq. (24), and the heuristic design.

The design problem (paper eq. 24a-e) chooses ``n`` measurement poses ``q`` (n, 6) [rad] that
minimise a criterion of the covariance of the identified parameters,

    min_q  phi(C(q))   s.t.  q_lo <= q_i <= q_up,
                             incidence angle of pose i <= max incidence (eq. 4),
                             every capsule clearance of pose i >= 0 (eq. 20-22),

with ``C`` from the KKT system of eq. (24c), ``F1 = dh/dp / sigma`` (eq. 24d) and
``F2 = dTCP/dp`` at the working pose ``q_work`` (eq. 24e). Criteria (:mod:`kpioed_drake.covariance`):

- ``kpi``: tr(Cs)/3 [mm^2], the average variance of the TCP at ``q_work`` (the paper's method);
- ``param``: tr(P^T Cp P) with SPEC's scaling (the paper's standard method);
- ``d``: -log det(F1^T F1) (D-optimality);
- ``o1``: -(prod mu)^(1/r)/sqrt(r) (Borm-Menq observability index, paper eq. 8).

The problem is a Drake ``MathematicalProgram`` with 6n decision variables (pose-major: variable
``6k + j`` is joint j+1 of pose k), bounding-box joint limits, ONE vectorised Python cost and
Python constraint bindings of ``POSE_BLOCK`` poses (the rows of all poses are computed in one
vectorised call per iterate and shared) holding, for every pose, the incidence row and (with collision
avoidance) the pose's ``ACTIVE_ROWS_PER_POSE`` smallest clearances of
:class:`~kpioed_drake.geometry.ClearanceModel` (51 rows for the KUKA robots). "Every clearance >= 0"
and "the 4 smallest clearances >= 0" are the same condition, so the feasible set is that of paper
eq. (24b); the solver's work per iteration shrinks with its rows (kr16, 60 poses: 300 rows instead of
3120). A row keeps its slot while it stays among its pose's smallest (:func:`update_active_rows`).
If such a solve fails or returns an infeasible design, the start is solved again with all rows.
Each constraint row depends only on its own pose's six variables; this sparsity is declared to the
solver. Derivatives are closed form and vectorised over poses: the cost gradient is the adjoint
``d phi/d F1`` (from :func:`kpioed_drake.covariance.criterion`) contracted with ``d F1/d q``
(:meth:`kpioed_drake.problem.Problem.F1`); the incidence gradient follows from
``d z_F/d q_j = w_j x z_F`` and ``d p/d q_j = w_j x (p - o_{j-1})``; clearance gradients come from
:mod:`kpioed_drake.geometry`. Cost and constraint share one forward kinematics per iterate.
Solvers: SNOPT (default) or IPOPT, both bundled with pydrake.

Designs of more than ``MAX_BLOCK_POSES`` poses are optimised by sweeps over blocks of about
``SWEEP_BLOCK_POSES`` poses: each block is the problem above for its poses, with the information
``F1^T F1`` of the other poses held fixed (exact, since the constraints hold pose by pose).

The heuristic design (paper 3.2, SPEC) draws poses uniformly from the joint box and keeps each pose
that is feasible. It is also the optimiser's starting point.

Every returned design is checked independently by :class:`~kpioed_drake.feasibility.FeasibilityChecker`
(Drake signed-distance queries), never by the optimiser's own constraint functions.

Units: millimetres and radians inside; degrees in files and on the command line.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from pathlib import Path

import numpy as np

from kpioed_drake import covariance
from kpioed_drake.errors import InputError
from kpioed_drake.feasibility import FeasibilityChecker, PoseReport
from kpioed_drake.geometry import ClearanceModel
from kpioed_drake.kinematics import Frames, cross, flange_point, forward_kinematics
from kpioed_drake.measurement import incidence_cosine
from kpioed_drake.models import N_JOINTS
from kpioed_drake.problem import Problem

CRITERIA = covariance.CRITERIA
"""Criteria an optimiser can minimise: ``kpi``, ``param``, ``d``, ``o1``."""
DESIGN_CRITERIA = (*CRITERIA, "heuristic")
"""Everything :func:`optimize_design` accepts as ``criterion``."""
SOLVERS = ("snopt", "ipopt")

HEURISTIC_MARGIN_MM = 1.0
"""Smallest clearance [mm] of a pose the heuristic keeps (a feasible, not grazing, start)."""
CLEARANCE_ROW_SCALE = 1e-2
"""Clearance rows are passed to the solver in units of 100 mm (incidence rows are cosines, O(1))."""
INCIDENCE_MARGIN_DEG = 1e-4
"""The optimiser keeps the incidence angle this far inside the limit [deg], so that a pose on the
limit still passes the independent check (tolerance 1e-6 deg) despite the solver's own feasibility
tolerance (SNOPT's is relative to the size of the solution vector)."""
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
"""Sweeps stop when one lowers the criterion by less than this fraction."""
MAX_SWEEPS = 10
"""Most sweeps."""
POSE_BLOCK = 10
"""Poses per constraint binding by default. Drake hands a Python constraint's gradient over as one
AutoDiffXd per row with a derivative per variable of the binding: with one binding over all 6n
variables that is a dense (rows, 6n) matrix whose conversion grew faster than n^2 (4.3 ms of an
evaluation at 60 poses). With bindings of 10 poses the conversion costs 1.2 ms in all; the rows of
every pose are still computed in one vectorised call (see :class:`DesignProgram`)."""


class DesignError(InputError):
    """The optimiser failed or returned an infeasible design (the CLI exits with status 3).

    Attributes:
        result: the :class:`DesignResult` that was rejected (None if there is none).
    """

    def __init__(self, message: str, result: DesignResult | None = None):
        super().__init__(message)
        self.result = result


@dataclasses.dataclass
class DesignResult:
    """An experimental design and how it was obtained.

    Attributes:
        q: (n, 6) measurement poses [rad].
        criterion: ``kpi``, ``param``, ``d``, ``o1`` or ``heuristic``.
        value: the criterion's value at ``q`` (for ``heuristic``: tr(Cs)/3) [criterion units].
        kpi_avg_var_mm2: tr(Cs)/3 of the design [mm^2].
        param_crit: SPEC's scaled tr(Cp) of the design [mm^2].
        solver: ``snopt``, ``ipopt`` or ``none`` (heuristic).
        status: the solver's status text (e.g. ``"snopt info 1: optimality conditions satisfied"``).
        success: the solver reported success (always True for the heuristic).
        solve_s: wall time of all solver calls [s] (all starts; with block sweeps, of the sweeps
            including the checks of the block results).
        n_evals: cost evaluations counted in our callback (all starts).
        feasible: every pose passes the independent check of the constraints that were imposed
            (joint limits and incidence; and clearances when ``collision`` is True).
        n_infeasible_poses: poses failing those checks.
        n_colliding_poses: poses with a collision or beam failure in the full check (reported also
            when the design was made without collision avoidance).
        reports: per pose, :meth:`~kpioed_drake.feasibility.PoseReport.as_dict` of the full check.
        start_values: the criterion's value reached from each start (NaN where the solve failed).
        initial_values: the criterion's value at each starting design.
        collision: whether collision avoidance was imposed.
        robot: robot name.
        seed: seed of the first start (start k uses ``seed + k``).
        best_start: index of the start that was kept.
        constraint_evals: constraint evaluations (all starts).
        all_rows_retries: solves with each pose's smallest clearance rows that failed or were
            infeasible and were repeated with all rows (times and evaluations include both solves).
        sweeps: block sweeps of the kept start (0: one solve over all poses; see ``max_block`` of
            :func:`optimize_design`).
    """

    q: np.ndarray
    criterion: str
    value: float
    kpi_avg_var_mm2: float
    param_crit: float
    solver: str
    status: str
    success: bool
    solve_s: float
    n_evals: int
    feasible: bool
    n_infeasible_poses: int
    n_colliding_poses: int
    reports: list[dict]
    start_values: list[float]
    initial_values: list[float] = dataclasses.field(default_factory=list)
    collision: bool = True
    robot: str = ""
    seed: int = 0
    best_start: int = 0
    constraint_evals: int = 0
    all_rows_retries: int = 0
    sweeps: int = 0

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    def summary(self) -> dict:
        """JSON-ready record (angles in degrees)."""
        return {
            "robot": self.robot,
            "criterion": self.criterion,
            "n_poses": self.n,
            "collision_avoidance": self.collision,
            "values": {
                "criterion_value": self.value,
                "kpi_avg_var_mm2": self.kpi_avg_var_mm2,
                "param_crit": self.param_crit,
            },
            "solver": self.solver,
            "status": self.status,
            "success": self.success,
            "solve_s": self.solve_s,
            "n_evals": self.n_evals,
            "constraint_evals": self.constraint_evals,
            "all_rows_retries": self.all_rows_retries,
            "sweeps": self.sweeps,
            "seed": self.seed,
            "starts": len(self.start_values) if self.start_values else 1,
            "best_start": self.best_start,
            "start_values": self.start_values,
            "initial_values": self.initial_values,
            "feasible": self.feasible,
            "n_infeasible_poses": self.n_infeasible_poses,
            "n_colliding_poses": self.n_colliding_poses,
            "poses": [
                {"q_deg": np.rad2deg(qi).tolist(), **rep}
                for qi, rep in zip(self.q, self.reports, strict=True)
            ],
        }


# ----------------------------------------------------------------------------------------------
# Heuristic design
# ----------------------------------------------------------------------------------------------
def heuristic_design(
    problem: Problem,
    *,
    n: int = 60,
    seed: int = 0,
    collision: bool = True,
    max_draws: int = 200_000,
    margin_mm: float = HEURISTIC_MARGIN_MM,
    batch: int = 4096,
) -> np.ndarray:
    """The paper's heuristic: uniform random poses from the joint box, kept only if feasible.

    Poses are drawn with ``numpy.random.default_rng(seed)`` in batches (the result does not depend
    on ``batch``: the first ``n`` feasible draws are kept, in draw order). A pose is kept if its
    incidence angle is within the cell's limit and, with ``collision``, every clearance of
    :class:`~kpioed_drake.geometry.ClearanceModel` (robot, obstacles, self pairs, laser beam) is at
    least ``margin_mm``.

    Args:
        problem: robot, cell and measurement model.
        n: number of poses.
        seed: random seed.
        collision: require collision and beam clearance.
        max_draws: give up after this many draws.
        margin_mm: smallest admitted clearance [mm].

    Returns:
        q: (n, 6) [rad].

    Raises:
        InputError: fewer than ``n`` feasible poses in ``max_draws`` draws.
    """
    if n < 1:
        raise InputError(f"the number of poses must be positive, got {n}")
    robot, cell = problem.robot, problem.cell
    rng = np.random.default_rng(seed)
    cos_max = math.cos(cell.max_incidence)
    cm = ClearanceModel(robot, cell) if collision else None
    kept, n_kept, draws = [], 0, 0
    while n_kept < n and draws < max_draws:
        b = min(batch, max_draws - draws)
        q = rng.uniform(robot.lower, robot.upper, size=(b, N_JOINTS))
        draws += b
        frames = forward_kinematics(robot, q)
        ok = incidence_cosine(problem.model, q, frames=frames) >= cos_max
        if cm is not None and ok.any():
            vals = cm.values(q[ok])
            ok[ok] = np.all(vals >= margin_mm, axis=1)
        kept.append(q[ok])
        n_kept += int(ok.sum())
    q = np.concatenate(kept, axis=0)[:n] if kept else np.zeros((0, N_JOINTS))
    if q.shape[0] < n:
        what = "incidence and collision-free" if collision else "incidence"
        msg = (
            f"no feasible pose found in {draws} draws"
            if q.shape[0] == 0
            else f"only {q.shape[0]} of {n} feasible poses found in {draws} draws"
        )
        raise InputError(
            f"{robot.name}: {msg} ({what} constraints): check the cell (car position, tracker, "
            "incidence limit) and the robot's joint limits"
        )
    return q


# ----------------------------------------------------------------------------------------------
# Objective and constraints (numpy, vectorised over poses)
# ----------------------------------------------------------------------------------------------
def _poses(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q.reshape(-1, N_JOINTS)


class DesignObjective:
    """A design criterion of ``n`` poses and its closed-form gradient.

    Args:
        problem: the identification problem.
        criterion: ``kpi``, ``param``, ``d`` or ``o1``.
        fixed_information: (k, k) information ``F1^T F1`` of further poses that are measured too
            but not varied (block sweeps of :func:`optimize_design`); None: none.
    """

    def __init__(self, problem: Problem, criterion: str, *, fixed_information: np.ndarray | None = None):
        if criterion not in CRITERIA:
            raise InputError(f"unknown criterion {criterion!r}; expected one of {', '.join(CRITERIA)}")
        self.problem, self.criterion = problem, criterion
        self.Js = problem.Js()
        self.scale = problem.scale
        self.M0 = fixed_information

    def value(self, q, *, frames: Frames | None = None) -> float:
        """Criterion of the design ``q`` (n, 6) [rad] (``frames``: its forward kinematics, if known)."""
        F1 = self.problem.F1(_poses(q), frames=frames)
        return covariance.criterion(self.criterion, F1, self.Js, self.scale, with_grad=False, M0=self.M0)

    def value_and_grad(self, q, *, frames: Frames | None = None) -> tuple[float, np.ndarray]:
        """Criterion and its gradient (n, 6) w.r.t. the joint angles [criterion units / rad].

        ``d phi/d q[k, j] = sum_{a, c} (d phi/d F1)[3k + a, c] * (d F1[3k + a, c] / d q[k, j])``.
        """
        q = _poses(q)
        F1, dF1 = self.problem.F1(q, with_dq=True, frames=frames)  # (3n, k), (n, 6, 3, k)
        value, G = covariance.criterion(self.criterion, F1, self.Js, self.scale, M0=self.M0)
        n = q.shape[0]
        grad = np.einsum("nak,njak->nj", G.reshape(n, 3, -1), dF1)
        return value, grad


def incidence_rows(problem: Problem, q, *, frames: Frames | None = None):
    """Incidence constraint ``cos(beta) - cos(beta_max)`` (>= 0 is feasible) and its gradient.

    With ``z`` the reflector axis (flange z), ``p`` the reflector, ``g = p_WT - p`` and
    ``g^ = g/|g|``: ``c = z . g^``; ``dz/dq_j = w_j x z``; ``dp/dq_j = w_j x (p - o_{j-1})``;
    ``dc/dq_j = (w_j x z) . g^ - (z - c g^) . dp/dq_j / |g|``.

    Args:
        q: (n, 6) [rad].

    Returns:
        values: (n,) [-]; jac: (n, 6) [1/rad].
    """
    q = _poses(q)
    frames = problem.model.frames(q) if frames is None else frames
    z = frames.R[:, N_JOINTS, :, 2]  # (n,3)
    p = flange_point(frames, problem.model.p_FQ)  # (n,3)
    g = problem.model.p_WT - p
    dist = np.linalg.norm(g, axis=1)
    gh = g / dist[:, None]
    c = np.einsum("ni,ni->n", z, gh)
    w, o = frames.joint_axes, frames.joint_points  # (n,6,3)
    dz = cross(w, z[:, None, :])
    dp = cross(w, p[:, None, :] - o)
    perp = z - c[:, None] * gh  # (n,3)
    jac = np.einsum("nji,ni->nj", dz, gh) - np.einsum("nji,ni->nj", dp, perp) / dist[:, None]
    return c - math.cos(problem.cell.max_incidence), jac


class DesignConstraints:
    """All constraint rows of every pose: incidence, then (with ``collision``) the clearances.

    Args:
        problem: the identification problem (robot, cell, model).
        collision: include the clearance rows of :class:`~kpioed_drake.geometry.ClearanceModel`.
    """

    def __init__(self, problem: Problem, *, collision: bool = True):
        self.problem, self.collision = problem, collision
        self.clearance = ClearanceModel(problem.robot, problem.cell) if collision else None
        names = ["incidence"] + (list(self.clearance.rows.names) if self.clearance else [])
        self.row_names = tuple(names)

    @property
    def rows_per_pose(self) -> int:
        """Rows of one pose: incidence plus every clearance."""
        return len(self.row_names)

    def frames(self, q) -> Frames:
        """Forward kinematics of ``q`` (n, 6) as every evaluator of the design problem uses it."""
        return forward_kinematics(self.problem.robot, _poses(q), self.problem.model.geometry)

    def evaluate(self, q, *, frames: Frames | None = None):
        """Constraint values and their per-pose Jacobian.

        Args:
            q: (n, 6) [rad].
            frames: :meth:`frames` of ``q``, if already computed.

        Returns:
            values: (n, r) (row 0 cosine difference [-], rows 1.. clearances [mm]; >= 0 feasible);
            jac: (n, r, 6) derivative w.r.t. the pose's own joint angles [per rad].
        """
        q = _poses(q)
        frames = self.frames(q) if frames is None else frames
        c, dc = incidence_rows(self.problem, q, frames=frames)
        if self.clearance is None:
            return c[:, None], dc[:, None, :]
        v, J = self.clearance.evaluate(q, frames=frames)
        return np.concatenate([c[:, None], v], axis=1), np.concatenate([dc[:, None, :], J], axis=1)

    def evaluate_active(self, q, active: np.ndarray | None, m: int, *, frames: Frames | None = None):
        """Incidence and the ``m`` smallest clearances of every pose, with their Jacobian.

        "All clearances >= b" holds exactly when "the m smallest clearances >= b" does, so these
        rows define the same feasible set as :meth:`evaluate`'s. The clearance rows kept for a pose
        are held in ``m`` slots: a row keeps its slot while it stays among the pose's ``m``
        smallest, and a row that enters takes the slot of one that left (see
        :func:`update_active_rows`). Only the kept rows' Jacobian is computed.

        Args:
            q: (n, 6) [rad].
            active: (n, m) clearance row indices (0-based, into ``clearance.rows``) held in the slots
                so far, or None (start: the m smallest, in increasing order of clearance).
            m: slots per pose (1 <= m <= number of clearance rows).
            frames: :meth:`frames` of ``q``, if already computed.

        Returns:
            values: (n, 1 + m); jac: (n, 1 + m, 6); active: (n, m) the rows now in the slots.
        """
        q = _poses(q)
        frames = self.frames(q) if frames is None else frames
        c, dc = incidence_rows(self.problem, q, frames=frames)
        ev = self.clearance.compute(q, frames=frames)
        active = update_active_rows(ev.values, active, m)
        J = self.clearance.jacobian(ev, active)
        values = np.concatenate([c[:, None], np.take_along_axis(ev.values, active, axis=1)], axis=1)
        return values, np.concatenate([dc[:, None, :], J], axis=1), active

    def row_scale(self, r: int | None = None) -> np.ndarray:
        """(r,) factors applied to the first ``r`` rows (default: all) before they reach the solver."""
        s = np.full(self.rows_per_pose if r is None else r, CLEARANCE_ROW_SCALE)
        s[0] = 1.0
        return s

    def lower_bounds(self, r: int | None = None) -> np.ndarray:
        """(r,) lower bounds of the first ``r`` unscaled rows (default: all; small inward margins,
        see the module constants)."""
        mi = self.problem.cell.max_incidence
        lb = np.full(self.rows_per_pose if r is None else r, CLEARANCE_MARGIN_MM)
        lb[0] = math.cos(mi - math.radians(INCIDENCE_MARGIN_DEG)) - math.cos(mi)
        return lb


def update_active_rows(values: np.ndarray, active: np.ndarray | None, m: int) -> np.ndarray:
    """The ``m`` smallest rows of every pose, each kept in its slot while it stays among them.

    Args:
        values: (n, R) clearances of every row.
        active: (n, m) the row indices in the slots so far, or None. A pose whose slots are all -1
            has none yet (as with None).
        m: number of slots.

    Returns:
        (n, m) row indices: the set is the m smallest of each pose; a row that was in ``active`` and
        still belongs to the set keeps its position, the rows that enter fill the freed positions
        in increasing row index. A pose without slots gets its m smallest in increasing order.
    """
    n, R = values.shape
    if not 1 <= m <= R:
        raise ValueError(f"the number of active rows must be in 1..{R}, got {m}")
    if active is None:
        return np.argsort(values, axis=1, kind="stable")[:, :m]
    unset = active[:, 0] < 0
    if unset.any():
        out = np.empty((n, m), dtype=np.intp)
        out[unset] = update_active_rows(values[unset], None, m)
        if not unset.all():
            out[~unset] = update_active_rows(values[~unset], active[~unset], m)
        return out
    best = (
        np.sort(np.argpartition(values, m - 1, axis=1)[:, :m], axis=1)
        if m < R
        else np.tile(np.arange(R), (n, 1))
    )
    stays = (active[:, :, None] == best[:, None, :]).any(axis=2)  # (n, m) slot keeps its row
    enters = ~(best[:, :, None] == active[:, None, :]).any(axis=2)  # (n, m) best row not yet in a slot
    out = active.copy()
    # Both masks have the same count per pose; nonzero() lists them pose by pose, in order.
    out[np.nonzero(~stays)] = best[np.nonzero(enters)]
    return out


# ----------------------------------------------------------------------------------------------
# Drake MathematicalProgram
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class _Counters:
    cost: int = 0
    constraint: int = 0
    cost_s: float = 0.0
    constraint_s: float = 0.0


class DesignProgram:
    """The design problem as a Drake ``MathematicalProgram``.

    Args:
        problem, criterion, n, collision: the design problem.
        cost_scale: the cost passed to the solver is ``criterion * cost_scale``.
        active_rows: clearance rows per pose passed to the solver: the pose's ``active_rows``
            smallest clearances (:meth:`DesignConstraints.evaluate_active`; the same feasible set
            as all rows, with far fewer rows for the solver). None: every clearance row.
        pose_block: poses per constraint binding (default :data:`POSE_BLOCK`; None: one binding
            over all 6n variables). The AutoDiffXd gradient of one binding is a dense (b r, 6b)
            matrix, so its conversion grows as b^2: blocks make it grow as n. The rows of all poses
            are computed once per iterate, by the first block evaluated after the cost (the solver
            evaluates the cost first, and the cost's forward kinematics is kept); the other blocks
            read them. A block evaluated at poses that differ from the kept ones computes its own.
        fixed_information: (k, k) information of poses measured too but held fixed (see
            :class:`DesignObjective`).

    Attributes:
        prog: the program; ``x`` its (6n,) decision variables (pose-major).
        objective, constraints: the numpy evaluators.
        rows_per_pose: constraint rows per pose that the solver sees.
        active: (n, active_rows) the clearance rows in the slots after the last evaluation (None
            before every pose has been evaluated, or without ``active_rows``).
        cost_binding: the one cost; ``constraint_bindings``: the constraint(s), each with its
            gradient sparsity pattern (row of pose k -> variables 6k..6k+5);
            ``constraint_binding`` is the first (the only one by default).
        counters: evaluation counts and times of the Python callbacks.
    """

    def __init__(
        self,
        problem: Problem,
        *,
        criterion: str,
        n: int,
        collision: bool,
        cost_scale: float = 1.0,
        active_rows: int | None = ACTIVE_ROWS_PER_POSE,
        pose_block: int | None = POSE_BLOCK,
        fixed_information: np.ndarray | None = None,
    ):
        from pydrake.solvers import MathematicalProgram

        self.problem, self.n, self.collision = problem, n, collision
        self.objective = DesignObjective(problem, criterion, fixed_information=fixed_information)
        self.constraints = DesignConstraints(problem, collision=collision)
        self.cost_scale = float(cost_scale)
        self.counters = _Counters()
        n_clear = self.constraints.rows_per_pose - 1
        self.active_rows = None if (active_rows is None or n_clear == 0) else min(int(active_rows), n_clear)
        if self.active_rows is not None and self.active_rows < 1:
            raise InputError(f"active_rows must be positive, got {active_rows}")
        # per pose: its clearance rows in the slots (-1: none yet)
        self._slots = None if self.active_rows is None else np.full((n, self.active_rows), -1, np.intp)
        self._fk: Frames | None = None  # forward kinematics of all poses at _fk_q
        self._fk_q: np.ndarray | None = None
        self._rows_q = np.full((n, N_JOINTS), np.nan)  # per pose: the q its kept rows belong to
        self._rows_v: np.ndarray | None = None  # (n, r) kept rows (unscaled)
        self._rows_J: np.ndarray | None = None  # (n, r, 6) their Jacobian
        prog = MathematicalProgram()
        x = prog.NewContinuousVariables(N_JOINTS * n, "q")
        robot = problem.robot
        prog.AddBoundingBoxConstraint(np.tile(robot.lower, n), np.tile(robot.upper, n), x)
        self.cost_binding = prog.AddCost(self._cost, vars=x)
        r = self.rows_per_pose = 1 + (n_clear if self.active_rows is None else self.active_rows)
        self._row_scale = self.constraints.row_scale(r)
        lb_pose = self.constraints.lower_bounds(r) * self._row_scale
        B = n if pose_block is None else max(1, min(int(pose_block), n))
        self.constraint_bindings = []
        for k0 in range(0, n, B):
            b = min(B, n - k0)
            binding = prog.AddConstraint(
                self._block_constraint(k0, b),
                lb=np.tile(lb_pose, b),
                ub=np.full(b * r, np.inf),
                vars=x[N_JOINTS * k0 : N_JOINTS * (k0 + b)],
                description=f"incidence_and_clearance[{k0}:{k0 + b}]",
            )
            rows = np.arange(b * r)
            pattern = [(int(i), int(N_JOINTS * (i // r) + j)) for i in rows for j in range(N_JOINTS)]
            binding.evaluator().SetGradientSparsityPattern(pattern)
            self.constraint_bindings.append(binding)
        self.constraint_binding = self.constraint_bindings[0]
        self.prog, self.x = prog, x

    def _frames(self, q: np.ndarray) -> Frames:
        """Forward kinematics of ``q``; that of all poses is kept for the constraint blocks
        (:meth:`_rows`), which the solver evaluates after the cost at the same x."""
        if q.shape[0] < self.n:
            return self.constraints.frames(q)
        if self._fk_q is None or not np.array_equal(self._fk_q, q):
            self._fk, self._fk_q = self.constraints.frames(q), q.copy()
        return self._fk

    @property
    def active(self) -> np.ndarray | None:
        """(n, active_rows) clearance rows in the slots after the last evaluation of every block
        (None before that, or without ``active_rows``)."""
        if self._slots is None or np.any(self._slots < 0):
            return None
        return self._slots.copy()

    def _rows(self, k0: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unscaled rows the solver sees for the poses ``q`` (b, 6) of the block starting at ``k0``:
        values (b, r) and per-pose Jacobian (b, r, 6). Updates the slots of the poses evaluated.

        Rows depend on their own pose only, so rows kept for the same pose angles are reused. If
        the cost was last evaluated where this block's poses are, every pose's rows are computed
        in one call (the other blocks then read them)."""
        b = q.shape[0]
        hi = k0 + b
        if self._rows_v is not None and np.array_equal(self._rows_q[k0:hi], q):
            return self._rows_v[k0:hi], self._rows_J[k0:hi]
        lo, up = k0, hi
        if b < self.n and self._fk_q is not None and np.array_equal(self._fk_q[k0:hi], q):
            lo, up, q, frames = 0, self.n, self._fk_q, self._fk
        else:
            frames = self._frames(q)
        if self.active_rows is None:
            v, J = self.constraints.evaluate(q, frames=frames)
        else:
            v, J, self._slots[lo:up] = self.constraints.evaluate_active(
                q, self._slots[lo:up], self.active_rows, frames=frames
            )
        if self._rows_v is None:
            self._rows_v = np.empty((self.n, *v.shape[1:]))
            self._rows_J = np.empty((self.n, *J.shape[1:]))
        self._rows_q[lo:up], self._rows_v[lo:up], self._rows_J[lo:up] = q, v, J
        return v[k0 - lo : hi - lo], J[k0 - lo : hi - lo]

    # Drake passes x as float (plain evaluation) or as AutoDiffXd with an identity gradient (SNOPT,
    # IPOPT; DRAKE-NOTES): the returned gradient is therefore d/dx directly, without the chain
    # rule through ExtractGradient(x) (which cost 4 ms per call on the constraint Jacobian).
    def _cost(self, x):
        from pydrake.autodiffutils import ExtractValue, InitializeAutoDiff

        s = self.cost_scale
        if x.dtype != object:
            return self._safe_value(x) * s
        t0 = time.perf_counter()
        self.counters.cost += 1
        q = ExtractValue(x).reshape(self.n, N_JOINTS)
        try:
            v, g = self.objective.value_and_grad(q, frames=self._frames(q))
        except np.linalg.LinAlgError:
            v, g = _SINGULAR_PENALTY, np.zeros((self.n, N_JOINTS))
        out = InitializeAutoDiff(np.array([v * s]), (g * s).reshape(1, -1))[0, 0]
        self.counters.cost_s += time.perf_counter() - t0
        return out

    def _safe_value(self, x) -> float:
        try:
            return self.objective.value(np.asarray(x, dtype=float).reshape(self.n, N_JOINTS))
        except np.linalg.LinAlgError:
            return _SINGULAR_PENALTY

    def _block_constraint(self, k0: int, b: int):
        """The constraint function of poses k0 .. k0+b-1 (its variables are theirs, pose-major)."""
        from pydrake.autodiffutils import ExtractValue, InitializeAutoDiff

        r = self.rows_per_pose
        # The (b r, 6 b) gradient is block diagonal. It is handed to InitializeAutoDiff a few poses
        # at a time (about 300 rows) through a reused zero buffer: allocating the dense matrix
        # afresh on every call cost more than the whole numpy evaluation.
        buf = np.zeros((max(1, min(b, 300 // r)), r, b, N_JOINTS))
        C = buf.shape[0]

        def constraint(x):
            if x.dtype != object:
                v, _ = self._rows(k0, np.asarray(x, dtype=float).reshape(b, N_JOINTS))
                return (v * self._row_scale).reshape(-1)
            t0 = time.perf_counter()
            if k0 == 0:
                self.counters.constraint += 1
            v, J = self._rows(k0, ExtractValue(x).reshape(b, N_JOINTS))
            v = v * self._row_scale
            J = J * self._row_scale[None, :, None]
            parts = []
            for c0 in range(0, b, C):
                c = min(C, b - c0)
                idx = np.arange(c)
                buf[idx, :, c0 + idx, :] = J[c0 : c0 + c]
                parts.append(
                    InitializeAutoDiff(v[c0 : c0 + c].reshape(-1), buf[:c].reshape(c * r, b * N_JOINTS))
                )
                buf[idx, :, c0 + idx, :] = 0.0
            out = np.concatenate(parts, axis=0)
            self.counters.constraint_s += time.perf_counter() - t0
            return out

        return constraint


_SINGULAR_PENALTY = 1e12
"""Cost returned where F1^T F1 is singular (only reachable with very few poses)."""

_SNOPT_INFO = {
    1: "optimality conditions satisfied",
    2: "feasible point found",
    3: "requested accuracy could not be achieved",
    11: "infeasible linear constraints",
    12: "infeasible linear equalities",
    13: "nonlinear infeasibilities minimized",
    14: "infeasibilities minimized",
    15: "infeasible linear constraints in QP subproblem",
    21: "unbounded objective",
    22: "constraint violation limit reached",
    31: "iteration limit reached",
    32: "major iteration limit reached",
    33: "the superbasics limit is too small",
    41: "current point cannot be improved",
    42: "singular basis",
    43: "cannot satisfy the general constraints",
    44: "ill-conditioned null-space basis",
}


def solver_options(solver: str, n: int) -> dict[str, float | int | str]:
    """Options passed to the solver for an ``n``-pose design."""
    if solver == "snopt":
        return {
            # 1e-5 (SNOPT's default 1e-6): measured on kr16 KPI with CA, 60 poses, seeds 0-9: 29 %
            # fewer evaluations, final tr(Cs)/3 +0.12 % on average (max +0.9 %, some seeds lower);
            # kr300/kr500 seeds 0-2 within 0.5 %; kr16 param seeds 0-1: criterion within 0.02 %.
            "Major optimality tolerance": 1e-5,
            # At most 0.2 (1 + |x|) per major step (SNOPT's default 2): with only each pose's
            # smallest clearances in the QP, long first steps on notional robots went deep into
            # collision and SNOPT stopped there (info 41). No change seen on the KUKA robots.
            "Major step limit": 0.2,
            # Tighter than SNOPT's default 1e-6 (which is relative to the norm of the solution
            # vector): with 1e-6 and no margins, poses on the incidence limit were seen 3e-5 deg
            # beyond it. With the margins above, 1e-7 passed the independent check in every
            # design of the study, and needed fewer evaluations than 1e-9.
            "Major feasibility tolerance": 1e-7,
            "Minor feasibility tolerance": 1e-7,
            # the param criterion has a long flat tail (kr300, 60 poses, no CA: 1609 major iterations)
            "Major iterations limit": 3000,
            "Iterations limit": 200000,
            "Superbasics limit": max(500, N_JOINTS * n + 50),
        }
    # IPOPT's tol is on its scaled NLP error (not comparable one to one with SNOPT's); 1e-5 was
    # measured to reach SNOPT-quality optima. The constraint-violation tolerances are tight so that
    # an "acceptable" stop cannot return poses violating the incidence limit.
    return {
        "tol": 1e-5,
        "acceptable_tol": 1e-4,
        "constr_viol_tol": 1e-8,
        "acceptable_constr_viol_tol": 1e-8,
        "max_iter": 3000,
        "print_level": 0,
        "mu_strategy": "adaptive",
        "hessian_approximation": "limited-memory",
    }


def _make_solver(solver: str):
    from pydrake.solvers import IpoptSolver, SnoptSolver

    s = SnoptSolver() if solver == "snopt" else IpoptSolver()
    if not (s.available() and s.enabled()):
        raise InputError(f"solver {solver!r} is not available in this pydrake build")
    return s


def _status_text(solver: str, result) -> str:
    details = result.get_solver_details()
    if solver == "snopt":
        info = int(details.info)
        return f"snopt info {info}: {_SNOPT_INFO.get(info, 'see the SNOPT manual')}"
    return f"ipopt status {int(details.status)}: {details.ConvertStatusToString()}"


@dataclasses.dataclass
class _Solve:
    q: np.ndarray
    value: float
    success: bool
    status: str
    solve_s: float
    n_evals: int
    constraint_evals: int
    all_rows_retries: int = 0  # solves repeated with all clearance rows
    sweeps: int = 0  # block sweeps (0: one solve over all poses)


def _solve_once(
    problem: Problem,
    criterion: str,
    q_start: np.ndarray,
    collision: bool,
    solver: str,
    pose_block: int | None = POSE_BLOCK,
    active_rows: int | None = ACTIVE_ROWS_PER_POSE,
    fixed_information: np.ndarray | None = None,
) -> _Solve:
    from pydrake.solvers import SolverOptions

    n = q_start.shape[0]
    obj = DesignObjective(problem, criterion, fixed_information=fixed_information)
    v0 = obj.value(q_start)
    # Scale the cost to O(1) at the start: kpi and param are positive variances, o1 is negative;
    # the d criterion is a log (differences matter, not ratios), so it is divided by the number of
    # parameters instead (mean log-eigenvalue).
    scale = 1.0 / problem.n_params if criterion == "d" else 1.0 / max(abs(v0), 1e-300)
    dp = DesignProgram(
        problem,
        criterion=criterion,
        n=n,
        collision=collision,
        cost_scale=scale,
        active_rows=active_rows,
        pose_block=pose_block,
        fixed_information=fixed_information,
    )
    s = _make_solver(solver)
    opts = SolverOptions()
    for key, val in solver_options(solver, n).items():
        opts.SetOption(s.solver_id(), key, val)
    t0 = time.perf_counter()
    result = s.Solve(dp.prog, q_start.reshape(-1), opts)
    dt = time.perf_counter() - t0
    q = np.asarray(result.GetSolution(dp.x), dtype=float).reshape(n, N_JOINTS)
    # Bounds are hard in the check: clip round-off outside the joint box (SNOPT/IPOPT may leave
    # 1e-9 rad outside); the change is far below every tolerance.
    q = np.clip(q, problem.robot.lower, problem.robot.upper)
    try:
        value = obj.value(q)
    except np.linalg.LinAlgError:
        value = float("nan")
    return _Solve(
        q=q,
        value=float(value),
        success=bool(result.is_success()) and np.isfinite(value),
        status=_status_text(solver, result),
        solve_s=dt,
        n_evals=dp.counters.cost,
        constraint_evals=dp.counters.constraint,
    )


def _solve_checked(
    problem: Problem,
    criterion: str,
    q_start: np.ndarray,
    collision: bool,
    solver: str,
    pose_block: int | None,
    active_rows: int | None,
    fixed_information: np.ndarray | None = None,
) -> tuple[_Solve, tuple[list[PoseReport], int, int]]:
    """One solve from ``q_start`` and the independent check of its result.

    The reduced rows change identity between iterates; rarely (seen on some notional robots after a
    long first step) SNOPT then stops early. Such a start is solved again with every clearance row,
    the slower but robust formulation."""
    args = (problem, criterion, q_start, collision, solver, pose_block)
    sol = _solve_once(*args, active_rows, fixed_information)
    check = check_design(problem, sol.q, collision=collision)
    if collision and active_rows is not None and not (sol.success and check[1] == 0):
        full = _solve_once(*args, None, fixed_information)
        full.solve_s += sol.solve_s
        full.n_evals += sol.n_evals
        full.constraint_evals += sol.constraint_evals
        full.all_rows_retries = 1
        sol, check = full, check_design(problem, full.q, collision=collision)
    return sol, check


def _solve_blocks(
    problem: Problem,
    criterion: str,
    q_start: np.ndarray,
    collision: bool,
    solver: str,
    pose_block: int | None,
    active_rows: int | None,
    *,
    block: int,
    seed: int,
) -> _Solve:
    """Sweeps over blocks of about ``block`` poses, each block optimised with the others fixed.

    The constraints hold pose by pose, so a block's problem is the full problem with the other
    poses' information ``F1^T F1`` held fixed (:class:`DesignObjective`), and a point where no block
    can improve is a KKT point of the full problem. A block's result is kept only if its solve
    succeeded, it passes the independent check and it does not increase the criterion; the design
    therefore stays feasible and its criterion never increases. The first sweep takes the poses in
    order, later ones in a random order (seeded by ``seed``). Sweeps stop when one improves the
    criterion by less than :data:`SWEEP_RTOL` (relative; for ``d``, a log, the change divided by
    the number of parameters), or after :data:`MAX_SWEEPS`. ``solve_s`` is the wall time of all
    sweeps, including the checks of the block results.
    """
    t0 = time.perf_counter()
    n = q_start.shape[0]
    q = q_start.copy()
    obj = DesignObjective(problem, criterion)
    value = float(obj.value(q))
    n_blocks = -(-n // block)
    rng = np.random.default_rng(seed)
    out = _Solve(q=q, value=value, success=False, status="", solve_s=0.0, n_evals=0, constraint_evals=0)
    solves = kept = 0
    infos: dict[str, int] = {}
    change = np.inf
    for sweep in range(MAX_SWEEPS):
        order = np.arange(n) if sweep == 0 else rng.permutation(n)
        before = value
        for idx in np.array_split(order, n_blocks):
            idx = np.sort(idx)
            F = problem.F1(np.delete(q, idx, axis=0))
            sol, check = _solve_checked(
                problem, criterion, q[idx], collision, solver, pose_block, active_rows, F.T @ F
            )
            solves += 1
            out.n_evals += sol.n_evals
            out.constraint_evals += sol.constraint_evals
            out.all_rows_retries += sol.all_rows_retries
            infos[sol.status] = infos.get(sol.status, 0) + 1
            if sol.success and check[1] == 0 and sol.value <= value:
                q[idx], value = sol.q, sol.value
                kept += 1
        out.sweeps = sweep + 1
        change = (before - value) / (problem.n_params if criterion == "d" else max(abs(before), 1e-300))
        if change < SWEEP_RTOL:
            break
    out.q, out.value = q, value
    out.solve_s = time.perf_counter() - t0
    converged = change < SWEEP_RTOL
    out.success = converged and kept > 0
    statuses = "; ".join(f"{k} ({v}x)" for k, v in sorted(infos.items(), key=lambda kv: -kv[1]))
    out.status = (
        f"{out.sweeps} sweeps over {n_blocks} blocks of <= {-(-n // n_blocks)} poses, "
        f"{'converged' if converged else 'not converged'} (last sweep changed the criterion by "
        f"{change:.1e}, tolerance {SWEEP_RTOL:g}); {kept} of {solves} block solves kept; {statuses}"
    )
    return out


# ----------------------------------------------------------------------------------------------
# Public entry points
# ----------------------------------------------------------------------------------------------
_LOCAL = threading.local()  # checkers hold a Drake context: one cache per thread


def _checker(problem: Problem) -> FeasibilityChecker:
    cache = _LOCAL.__dict__.setdefault("checkers", {})
    key = (id(problem.robot), id(problem.cell))
    ch = cache.get(key)
    if ch is None or ch.robot is not problem.robot or ch.cell is not problem.cell:
        ch = FeasibilityChecker(problem.robot, problem.cell)
        if len(cache) > 16:
            cache.clear()
        cache[key] = ch
    return ch


def check_design(problem: Problem, q, *, collision: bool = True) -> tuple[list[PoseReport], int, int]:
    """Independent feasibility check of a design (Drake geometry queries, all checks).

    Args:
        q: (n, 6) [rad].
        collision: whether collision avoidance was imposed; without it, only joint-limit and
            incidence failures make a pose infeasible (collisions are still counted).

    Returns:
        reports (full check), number of infeasible poses (w.r.t. the imposed constraints), number
        of poses with a collision or beam failure.
    """
    reports = _checker(problem).check(q, collision=True)
    imposed = {"joint_limit", "incidence"} | ({"collision", "beam"} if collision else set())
    n_bad = sum(any(f["check"] in imposed for f in r.failures) for r in reports)
    n_col = sum(any(f["check"] in ("collision", "beam") for f in r.failures) for r in reports)
    return reports, n_bad, n_col


def _validate(
    problem: Problem,
    criterion: str,
    n: int,
    solver: str,
    starts: int,
    max_block: int | None = None,
    sweep_block: int = SWEEP_BLOCK_POSES,
) -> None:
    if criterion not in DESIGN_CRITERIA:
        raise InputError(f"unknown criterion {criterion!r}; expected one of {', '.join(DESIGN_CRITERIA)}")
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")
    if not isinstance(n, int | np.integer) or n < problem.min_poses():
        raise InputError(
            f"--n {n}: a design needs at least {problem.min_poses()} poses to determine the "
            f"{problem.n_params} parameters of {problem.robot.name} (3 coordinates per pose)"
        )
    if not isinstance(starts, int | np.integer) or starts < 1:
        raise InputError(f"--starts must be a positive integer, got {starts!r}")
    if max_block is not None and (not isinstance(max_block, int | np.integer) or max_block < 1):
        raise InputError(f"max_block must be a positive integer or None, got {max_block!r}")
    if not isinstance(sweep_block, int | np.integer) or sweep_block < 1:
        raise InputError(f"sweep_block must be a positive integer, got {sweep_block!r}")


def optimize_design(
    problem: Problem,
    *,
    criterion: str = "kpi",
    n: int = 60,
    collision: bool = True,
    solver: str = "snopt",
    seed: int = 0,
    starts: int = 1,
    q0: np.ndarray | None = None,
    allow_infeasible: bool = False,
    active_rows: int | None = ACTIVE_ROWS_PER_POSE,
    pose_block: int | None = POSE_BLOCK,
    max_block: int | None = MAX_BLOCK_POSES,
    sweep_block: int = SWEEP_BLOCK_POSES,
) -> DesignResult:
    """Optimum experimental design (paper eq. 24) or, for ``criterion="heuristic"``, the heuristic.

    Args:
        problem: robot, cell, model, ``q_work`` and noise.
        criterion: ``kpi`` (tr(Cs)/3), ``param`` (scaled tr(Cp)), ``d``, ``o1`` or ``heuristic``.
        n: number of poses (at least ``problem.min_poses()``).
        collision: impose collision and laser-beam clearance (paper "CA").
        solver: ``snopt`` or ``ipopt``.
        seed: seed of the heuristic start; start k uses ``seed + k``.
        starts: number of starts; the best feasible result is kept.
        q0: (n, 6) [rad] start of the first solve instead of the heuristic.
        allow_infeasible: return a failed or infeasible result instead of raising.
        active_rows: clearance rows per pose passed to the solver (its smallest ones; None: all
            rows); see :class:`DesignProgram`.
        pose_block: poses per constraint binding (default :data:`POSE_BLOCK`; None: one binding
            for all poses; see :class:`DesignProgram`).
        max_block: most poses one solve varies (default :data:`MAX_BLOCK_POSES`). A design of more
            poses is optimised by sweeps over blocks of about ``sweep_block`` poses, each solved
            with the others fixed (see :data:`MAX_BLOCK_POSES`); ``status`` then reports the sweeps
            and ``sweeps`` their number. None: always one solve over all poses.
        sweep_block: poses per block in sweeps (default :data:`SWEEP_BLOCK_POSES`).

    Returns:
        :class:`DesignResult`.

    Raises:
        InputError: bad ``n``, criterion, solver or ``q0``; no feasible heuristic start.
        DesignError: the solver failed or the design is infeasible (unless ``allow_infeasible``).
    """
    _validate(problem, criterion, n, solver, starts, max_block, sweep_block)
    n = int(n)
    base = dict(criterion=criterion, collision=collision, robot=problem.robot.name, seed=int(seed))
    if criterion == "heuristic":
        q = heuristic_design(problem, n=n, seed=seed, collision=collision)
        reports, n_bad, n_col = check_design(problem, q, collision=collision)
        crit = problem.criteria(q)
        res = DesignResult(
            q=q,
            value=crit["kpi_avg_var_mm2"],
            solver="none",
            status="heuristic (no solve)",
            success=True,
            solve_s=0.0,
            n_evals=0,
            feasible=n_bad == 0,
            n_infeasible_poses=n_bad,
            n_colliding_poses=n_col,
            reports=[r.as_dict() for r in reports],
            start_values=[crit["kpi_avg_var_mm2"]],
            initial_values=[crit["kpi_avg_var_mm2"]],
            **crit,
            **base,
        )
        return _finish(res, allow_infeasible)
    if q0 is not None:
        q0 = np.asarray(q0, dtype=float)
        if q0.shape != (n, N_JOINTS) or not np.all(np.isfinite(q0)):
            raise InputError(f"q0 must be a finite ({n}, 6) array of joint angles [rad], got {q0.shape}")
        if np.any(q0 < problem.robot.lower) or np.any(q0 > problem.robot.upper):
            raise InputError("q0: a joint angle is outside the robot's joint limits")
    obj = DesignObjective(problem, criterion)
    solves, checks, initial = [], [], []
    for k in range(starts):
        q_start = (
            q0
            if (k == 0 and q0 is not None)
            else heuristic_design(problem, n=n, seed=seed + k, collision=collision)
        )
        try:
            initial.append(float(obj.value(q_start)))
        except np.linalg.LinAlgError:
            initial.append(float("nan"))
        if max_block is not None and n > max_block:
            sol = _solve_blocks(
                problem,
                criterion,
                q_start,
                collision,
                solver,
                pose_block,
                active_rows,
                block=int(sweep_block),
                seed=seed + k,
            )
            check = check_design(problem, sol.q, collision=collision)
        else:
            sol, check = _solve_checked(
                problem, criterion, q_start, collision, solver, pose_block, active_rows
            )
        solves.append(sol)
        checks.append(check)
    good = [k for k, s in enumerate(solves) if s.success and checks[k][1] == 0]
    pool = good or [k for k, s in enumerate(solves) if np.isfinite(s.value)] or [0]
    best = min(pool, key=lambda k: solves[k].value if np.isfinite(solves[k].value) else np.inf)
    sol = solves[best]
    reports, n_bad, n_col = checks[best]
    try:
        crit = problem.criteria(sol.q)
    except InputError:
        crit = {"kpi_avg_var_mm2": float("nan"), "param_crit": float("nan")}
    res = DesignResult(
        q=sol.q,
        value=sol.value,
        solver=solver,
        status=sol.status,
        success=sol.success,
        solve_s=float(sum(s.solve_s for s in solves)),
        n_evals=int(sum(s.n_evals for s in solves)),
        constraint_evals=int(sum(s.constraint_evals for s in solves)),
        feasible=n_bad == 0,
        n_infeasible_poses=n_bad,
        n_colliding_poses=n_col,
        reports=[r.as_dict() for r in reports],
        start_values=[s.value if s.success else float("nan") for s in solves],
        initial_values=initial,
        best_start=best,
        all_rows_retries=sum(s.all_rows_retries for s in solves),
        sweeps=sol.sweeps,
        **crit,
        **base,
    )
    return _finish(res, allow_infeasible)


def _finish(res: DesignResult, allow_infeasible: bool) -> DesignResult:
    if allow_infeasible or (res.success and res.feasible):
        return res
    if not res.success:
        msg = f"{res.robot}: the {res.criterion} design failed: {res.status}"
    else:
        first = next(r for r in res.reports if not r["feasible"])
        f = first["failures"][0]
        msg = (
            f"{res.robot}: the {res.criterion} design has {res.n_infeasible_poses} infeasible pose(s) "
            f"(first: pose {first['index'] + 1}, {f['check']} {f['name']}, violation {f['violation']:.3g})"
        )
    raise DesignError(msg + "; use --allow-infeasible to keep it anyway, or try another --seed/--starts", res)


def run_design(
    robot_name: str,
    *,
    criterion: str = "kpi",
    n: int = 60,
    collision: bool = True,
    solver: str = "snopt",
    seed: int = 0,
    starts: int = 1,
    sigma_mm: float | None = None,
    q_work_deg=None,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    allow_infeasible: bool = False,
    plot: str | Path | None = None,
    extend=(),
) -> DesignResult:
    """Compute a design for a robot in the default cell and write its files (what ``kpioed design`` runs).

    Args:
        robot_name: model name (``kr16``, ``notional-850-800``) or path to a robot YAML file.
        criterion, n, collision, solver, seed, starts, allow_infeasible: see :func:`optimize_design`.
        sigma_mm: measurement noise per coordinate [mm] (default: the cell's).
        q_work_deg: working pose [deg], a ``"q1,...,q6"`` string or 6 numbers (default: the model
            file's).
        out: design CSV (``q1_deg`` .. ``q6_deg`` plus per-pose ``incidence_deg`` and
            ``min_clearance_mm``), written atomically.
        json_path: JSON record of the run, written atomically (also when the design is rejected).
        plot: PNG picture of the poses.
        extend: model extensions (e.g. ``["joint_elasticity:2"]``): the design then also estimates
            their parameters and its KPI variance includes them (:func:`problem.make_problem`).

    Returns:
        :class:`DesignResult`.

    Raises:
        InputError: bad input. DesignError: solver failure or infeasible design.
    """
    from kpioed_drake import designio
    from kpioed_drake.models import load_robot
    from kpioed_drake.problem import make_problem

    robot = load_robot(robot_name)
    q_work = None
    if q_work_deg is not None:
        text = q_work_deg if isinstance(q_work_deg, str) else ",".join(repr(float(v)) for v in q_work_deg)
        q_work = designio.parse_q_work(text, robot)
    problem = make_problem(robot, q_work=q_work, sigma_mm=sigma_mm, extend=extend)
    try:
        res = optimize_design(
            problem,
            criterion=criterion,
            n=n,
            collision=collision,
            solver=solver,
            seed=seed,
            starts=starts,
            allow_infeasible=allow_infeasible,
        )
    except DesignError as exc:
        if json_path is not None and exc.result is not None:
            designio.atomic_write_json(json_path, _json_record(exc.result, problem, error=str(exc)))
        raise
    if out is not None:
        extra = {
            "incidence_deg": np.array([r["incidence_deg"] for r in res.reports]),
            "min_clearance_mm": np.array([r["min_clearance_mm"] for r in res.reports]),
        }
        designio.write_design(out, res.q, extra)
    if json_path is not None:
        designio.atomic_write_json(json_path, _json_record(res, problem))
    if plot is not None:
        from kpioed_drake.plots import plot_design_poses

        plot_design_poses(
            problem.robot,
            problem.cell,
            res.q,
            plot,
            q_work=problem.q_work,
            infeasible=np.array([not r["feasible"] for r in res.reports]),
            title=f"{robot.name}: {criterion} design, {res.n} poses, "
            f"tr(Cs)/3 = {res.kpi_avg_var_mm2:.4g} mm^2",
        )
    return res


def _json_record(res: DesignResult, problem: Problem, error: str | None = None) -> dict:
    rec = res.summary()
    rec["q_work_deg"] = np.rad2deg(problem.q_work).tolist()
    rec["sigma_mm"] = problem.sigma
    if error is not None:
        rec["error"] = error
    return _finite_json(rec)


def _finite_json(obj):
    """Replace NaN/inf by None (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {k: _finite_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite_json(v) for v in obj]
    if isinstance(obj, float | np.floating) and not np.isfinite(obj):
        return None
    return obj


def format_summary(res: DesignResult) -> str:
    """A few human-readable lines about a design."""
    ca = "with" if res.collision else "without"
    lines = [
        f"{res.robot}: {res.criterion} design, {res.n} poses, {ca} collision avoidance",
        f"  tr(Cs)/3 = {res.kpi_avg_var_mm2:.4g} mm^2   scaled tr(Cp) = {res.param_crit:.4g} mm^2",
    ]
    if res.criterion != "heuristic":
        start = res.initial_values[res.best_start] if res.initial_values else float("nan")
        lines.append(f"  {res.criterion} criterion = {res.value:.6g} (heuristic start {start:.6g})")
        lines.append(
            f"  solver {res.solver}: {res.status}; {res.solve_s:.2f} s, {res.n_evals} cost evaluations"
        )
        if res.all_rows_retries:
            lines.append("  (solved again with all clearance rows after the reduced rows failed)")
    n_ok = res.n - res.n_infeasible_poses
    lines.append(
        f"  independent check: {n_ok}/{res.n} poses feasible; {res.n_colliding_poses} pose(s) collide"
    )
    return "\n".join(lines)


def demo(out_dir: str | Path = "out/demo", *, robot: str = "kr16", n: int = 60, seed: int = 0) -> dict:
    """KPI design for the KR 16 in the default cell, compared with the heuristic and standard designs.

    Prints tr(Cs)/3 of the heuristic, the standard (``param``) and the KPI design, and writes
    ``<out_dir>/<robot>-kpi-design.csv`` and ``<out_dir>/<robot>-kpi-design.png``.

    Returns:
        {criterion: tr(Cs)/3 [mm^2]}.
    """
    from kpioed_drake import designio
    from kpioed_drake.plots import plot_design_poses
    from kpioed_drake.problem import make_problem

    out_dir = Path(out_dir)
    problem = make_problem(robot)
    print(f"{robot}: {n} poses, collision avoidance on, SNOPT; average TCP variance tr(Cs)/3 [mm^2]")
    results = {}
    for crit in ("heuristic", "param", "kpi"):
        res = optimize_design(problem, criterion=crit, n=n, seed=seed)
        results[crit] = res
        label = {"heuristic": "heuristic", "param": "standard (param)", "kpi": "KPI"}[crit]
        extra = "" if crit == "heuristic" else f"  ({res.solve_s:.1f} s, {res.status})"
        print(f"  {label:18s} {res.kpi_avg_var_mm2:.4f}{extra}")
    h, p, k = (results[c].kpi_avg_var_mm2 for c in ("heuristic", "param", "kpi"))
    print(
        f"  KPI vs heuristic: {100 * (1 - k / h):.0f} % lower; vs standard: {100 * (1 - k / p):.0f} % lower"
    )
    kres = results["kpi"]
    csv_path = out_dir / f"{robot}-kpi-design.csv"
    png_path = out_dir / f"{robot}-kpi-design.png"
    designio.write_design(csv_path, kres.q)
    plot_design_poses(
        problem.robot,
        problem.cell,
        kres.q,
        png_path,
        q_work=problem.q_work,
        title=f"{robot}: KPI design, {n} poses, tr(Cs)/3 = {k:.3f} mm^2",
    )
    print(f"  feasible (Drake check): {kres.feasible}; wrote {csv_path} and {png_path}")
    return {c: r.kpi_avg_var_mm2 for c, r in results.items()}
