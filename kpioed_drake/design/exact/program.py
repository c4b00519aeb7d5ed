"""The design problem (paper eq. 24) as a Drake ``MathematicalProgram``.

6n decision variables (pose-major: variable ``6k + j`` is joint j+1 of pose k) [rad],
bounding-box joint limits, ONE vectorised Python cost (:class:`~kpioed_drake.design.exact.objective.
DesignObjective`, scaled) and Python constraint bindings of ``pose_block`` poses each
(:data:`~kpioed_drake.design.settings.POSE_BLOCK` = 10 by default: six bindings for 60 poses) holding,
for every pose, the incidence row and (with collision avoidance) the pose's ``active_rows``
smallest clearances (:class:`~kpioed_drake.design.exact.constraints.DesignConstraints`). The rows of all
poses are computed in one vectorised call per iterate and shared by the bindings; cost and
constraints share one forward kinematics per iterate. Each binding declares its gradient sparsity
(a row of pose k depends on variables 6k..6k+5 only).

The worst of several working poses' variances (``kpi`` criterion, ``kpi_aggregate == "max"``) is
not differentiable where two of them tie, so it is minimised in epigraph form: one more variable
``t`` [mm^2], the linear cost ``t`` and one smooth constraint row ``t - v_k(q) >= 0`` per working
pose k (all scaled like the cost). At a solution ``t`` is the largest ``v_k``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from pydrake.autodiffutils import ExtractValue, InitializeAutoDiff
from pydrake.solvers import MathematicalProgram

from kpioed_drake.design.exact.constraints import DesignConstraints
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.settings import ACTIVE_ROWS_PER_POSE, POSE_BLOCK
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.kinematics import Frames

SINGULAR_PENALTY = 1e12
"""Cost returned where F1^T F1 is singular (only reachable with very few poses)."""


@dataclasses.dataclass
class CallbackCounters:
    """Evaluations of the Python callbacks with gradients (what the solver asks for)."""

    cost: int = 0
    """Cost evaluations."""
    constraint: int = 0
    """Constraint evaluations, counted once per iterate (by the first binding)."""
    cost_s: float = 0.0
    """Wall time in the cost callback [s]."""
    constraint_s: float = 0.0
    """Wall time in the constraint callbacks, all bindings [s]."""


class DesignProgram:
    """The design problem as a Drake ``MathematicalProgram``.

    Args:
        problem, criterion, n, collision: the design problem.
        cost_scale: the cost passed to the solver is ``criterion * cost_scale``.
        active_rows: clearance rows per pose passed to the solver: the pose's ``active_rows``
            smallest clearances (:meth:`DesignConstraints.evaluate_active`; the same feasible set
            as all rows, with far fewer rows for the solver). None: every clearance row.
        pose_block: poses per constraint binding (default
            :data:`~kpioed_drake.design.settings.POSE_BLOCK`; None: one binding over all 6n
            variables). The AutoDiffXd gradient of one binding is a dense (b r, 6b) matrix, so its
            conversion grows as b^2: blocks make it grow as n. The rows of all poses
            are computed once per iterate, by the first block evaluated after the cost (the solver
            evaluates the cost first, and the cost's forward kinematics is kept); the other blocks
            read them. A block evaluated at poses that differ from the kept ones computes its own.
        fixed_information: (k, k) information of poses measured too but held fixed (see
            :class:`~kpioed_drake.design.exact.objective.DesignObjective`).

    Attributes:
        prog: the program; ``x`` its (6n,) decision variables (pose-major).
        objective, constraints: the numpy evaluators.
        rows_per_pose: constraint rows per pose that the solver sees.
        active: (n, active_rows) the clearance rows in the slots after the last evaluation (None
            before every pose has been evaluated, or without ``active_rows``).
        t: the epigraph variable of the worst case (None otherwise); ``epigraph_binding``: its K
            constraint rows ``(t - v_k(q)) * cost_scale >= 0`` (None otherwise).
        cost_binding: the one cost; ``constraint_bindings``: the constraints, one per block of
            ``pose_block`` poses (six for 60 poses by default), each with its gradient sparsity
            pattern (row of pose k -> variables 6k..6k+5); ``constraint_binding`` is the first.
        counters: :class:`CallbackCounters` of the Python callbacks.
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
        self.problem, self.n, self.collision = problem, n, collision
        self.objective = DesignObjective(problem, criterion, fixed_information=fixed_information)
        self.constraints = DesignConstraints(problem, collision=collision)
        self.cost_scale = float(cost_scale)
        self.counters = CallbackCounters()
        n_clear = self.constraints.rows_per_pose - self.constraints.n_incidence
        self.active_rows = None if (active_rows is None or n_clear == 0) else min(int(active_rows), n_clear)
        if self.active_rows is not None and self.active_rows < 1:
            raise InputError(f"active_rows must be positive, got {active_rows}")
        # per pose: its clearance rows in the slots (-1: none yet)
        self._slots = None if self.active_rows is None else np.full((n, self.active_rows), -1, np.intp)
        self._fk: Frames | None = None  # forward kinematics of all poses at _fk_q
        self._fk_q: np.ndarray | None = None
        self.nj = nj = problem.robot.n_joints
        self._rows_q = np.full((n, nj), np.nan)  # per pose: the q its kept rows belong to
        self._rows_v: np.ndarray | None = None  # (n, r) kept rows (unscaled)
        self._rows_J: np.ndarray | None = None  # (n, r, 6) their Jacobian
        prog = MathematicalProgram()
        x = prog.NewContinuousVariables(self.nj * n, "q")
        robot = problem.robot
        prog.AddBoundingBoxConstraint(np.tile(robot.lower, n), np.tile(robot.upper, n), x)
        if robot.joint_map is not None:  # poses the controller can command: N q = c per pose
            N, c = robot.joint_map.coupling_equations()
            for k in range(n if N.shape[0] else 0):
                prog.AddLinearEqualityConstraint(N, c, x[self.nj * k : self.nj * (k + 1)])
        self.t = self.epigraph_binding = None
        if self.objective.worst_case:
            self.t = prog.NewContinuousVariables(1, "t")[0]
            self.cost_binding = prog.AddLinearCost(np.array([self.cost_scale]), 0.0, [self.t])
            K = problem.n_kpis
            self.epigraph_binding = prog.AddConstraint(
                self._epigraph,
                lb=np.zeros(K),
                ub=np.full(K, np.inf),
                vars=np.append(x, self.t),
                description="kpi_epigraph",
            )
        else:
            self.cost_binding = prog.AddCost(self._cost, vars=x)
        n_inc = self.constraints.n_incidence
        r = self.rows_per_pose = n_inc + (n_clear if self.active_rows is None else self.active_rows)
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
                vars=x[self.nj * k0 : self.nj * (k0 + b)],
                description=f"incidence_and_clearance[{k0}:{k0 + b}]",
            )
            rows = np.arange(b * r)
            pattern = [(int(i), int(self.nj * (i // r) + j)) for i in rows for j in range(self.nj)]
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
    # rule through ExtractGradient(x) (milliseconds per call on the constraint Jacobian).
    def _cost(self, x):
        s = self.cost_scale
        if x.dtype != object:
            return self._safe_value(x) * s
        t0 = time.perf_counter()
        self.counters.cost += 1
        q = ExtractValue(x).reshape(self.n, self.nj)
        try:
            v, g = self.objective.value_and_grad(q, frames=self._frames(q))
        except np.linalg.LinAlgError:
            v, g = SINGULAR_PENALTY, np.zeros((self.n, self.nj))
        out = InitializeAutoDiff(np.array([v * s]), (g * s).reshape(1, -1))[0, 0]
        self.counters.cost_s += time.perf_counter() - t0
        return out

    def initial_guess(self, q_start: np.ndarray) -> np.ndarray:
        """Start of every decision variable: the poses ``q_start`` (n, 6) [rad] and, in the worst
        case, ``t`` = the largest variance at ``q_start`` (a feasible start of the epigraph)."""
        x0 = np.asarray(q_start, dtype=float).reshape(-1)
        return x0 if self.t is None else np.append(x0, self._safe_value(x0))

    def _epigraph(self, x):
        """Rows ``(t - v_k(q)) * cost_scale`` of the worst case; x = (q (6n,), t)."""
        s, n = self.cost_scale, self.n
        if x.dtype != object:
            q = np.asarray(x[:-1], dtype=float).reshape(n, self.nj)
            try:
                v = self.objective.values_and_grads(q)[0]
            except np.linalg.LinAlgError:
                v = np.full(self.problem.n_kpis, SINGULAR_PENALTY)
            return (float(x[-1]) - v) * s
        t0 = time.perf_counter()
        self.counters.cost += 1
        xv = ExtractValue(x).reshape(-1)
        q = xv[:-1].reshape(n, self.nj)
        K = self.problem.n_kpis
        try:
            v, g = self.objective.values_and_grads(q, frames=self._frames(q))
        except np.linalg.LinAlgError:
            v, g = np.full(K, SINGULAR_PENALTY), np.zeros((K, n, self.nj))
        grad = np.concatenate([-g.reshape(K, -1), np.ones((K, 1))], axis=1) * s
        out = InitializeAutoDiff((xv[-1] - v) * s, grad)[:, 0]
        self.counters.cost_s += time.perf_counter() - t0
        return out

    def _safe_value(self, x) -> float:
        try:
            return self.objective.value(np.asarray(x, dtype=float).reshape(self.n, self.nj))
        except np.linalg.LinAlgError:
            return SINGULAR_PENALTY

    def _block_constraint(self, k0: int, b: int):
        """The constraint function of poses k0 .. k0+b-1 (its variables are theirs, pose-major)."""
        r = self.rows_per_pose
        # The (b r, 6 b) gradient is block diagonal. It is handed to InitializeAutoDiff a few poses
        # at a time (about 300 rows) through a reused zero buffer: allocating the dense matrix
        # afresh on every call cost more than the whole numpy evaluation.
        buf = np.zeros((max(1, min(b, 300 // r)), r, b, self.nj))
        C = buf.shape[0]

        def constraint(x):
            if x.dtype != object:
                v, _ = self._rows(k0, np.asarray(x, dtype=float).reshape(b, self.nj))
                return (v * self._row_scale).reshape(-1)
            t0 = time.perf_counter()
            if k0 == 0:
                self.counters.constraint += 1
            v, J = self._rows(k0, ExtractValue(x).reshape(b, self.nj))
            v = v * self._row_scale
            J = J * self._row_scale[None, :, None]
            parts = []
            for c0 in range(0, b, C):
                c = min(C, b - c0)
                idx = np.arange(c)
                buf[idx, :, c0 + idx, :] = J[c0 : c0 + c]
                parts.append(
                    InitializeAutoDiff(v[c0 : c0 + c].reshape(-1), buf[:c].reshape(c * r, b * self.nj))
                )
                buf[idx, :, c0 + idx, :] = 0.0
            out = np.concatenate(parts, axis=0)
            self.counters.constraint_s += time.perf_counter() - t0
            return out

        return constraint
