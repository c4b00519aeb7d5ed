"""Solving the design problem: solver settings, one solve, a checked solve and block sweeps.

:func:`solve_once` builds a :class:`~kpioed_drake.design.exact.program.DesignProgram` and runs SNOPT or
IPOPT on it from a start design. :func:`solve_checked` checks its result independently
(:func:`~kpioed_drake.design.exact.check.check_design`) and, if the solve with each pose's smallest
clearance rows failed or is infeasible, solves again with all rows. :func:`solve_blocks` optimises
a large design by sweeps over blocks of poses, each block solved with the information ``F1^T F1``
of the other poses held fixed (exact: the constraints hold pose by pose).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from pydrake.solvers import IpoptSolver, MathematicalProgramResult, SnoptSolver, SolverOptions

from kpioed_drake.design.exact.check import DesignCheck, check_design
from kpioed_drake.design.exact.constraints import restore_incidence
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.exact.program import DesignProgram
from kpioed_drake.design.settings import MAX_SWEEPS, SWEEP_RTOL, is_large
from kpioed_drake.errors import InputError, raise_if_interrupted
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.jointmap import commandable_projection
from kpioed_drake.robot.models import N_JOINTS

OPTIMALITY_TOLERANCE = 1e-5
"""SNOPT's major optimality tolerance (its default 1e-6): about 30 % fewer evaluations for a
criterion about 0.1 % higher on average (docs/design.md)."""
LARGE_OPTIMALITY_TOLERANCE = 1e-4
"""The tolerance above :data:`~kpioed_drake.design.settings.LARGE_SOLVE_VARIABLES` joint variables,
where SNOPT's work per major iteration (about n nS^2) makes its long flat tail the larger part of a
solve: on the 40-pose design of the 18-joint twin it took a third of the evaluations of 3e-5 for a
criterion 0.04-0.07 % higher (docs/design.md)."""

SNOPT_INFO = {
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
"""SNOPT's exit conditions by ``info`` code (as in the SNOPT user's guide)."""


def solver_options(solver: str, n: int, *, n_joints: int = N_JOINTS) -> dict[str, float | int | str]:
    """Options passed to the solver for an ``n``-pose design of a robot of ``n_joints`` joints."""
    if solver == "snopt":
        large = is_large(n, n_joints)
        return {
            "Major optimality tolerance": LARGE_OPTIMALITY_TOLERANCE if large else OPTIMALITY_TOLERANCE,
            # At most 0.2 (1 + |x|) per major step (SNOPT's default 2): with only each pose's
            # smallest clearances in the QP, a long first step can go deep into collision, where
            # SNOPT stops (info 41).
            "Major step limit": 0.2,
            # Tighter than SNOPT's default 1e-6 (which is relative to the norm of the solution
            # vector, so 1e-6 lets a pose on the incidence limit end beyond the check's tolerance).
            # With the margins of design.settings, 1e-7 passes the independent check and needs fewer
            # evaluations than 1e-9 (docs/design.md).
            "Major feasibility tolerance": 1e-7,
            "Minor feasibility tolerance": 1e-7,
            # the param criterion has a long flat tail (over 1000 major iterations, docs/design.md)
            "Major iterations limit": 3000,
            "Iterations limit": 200000,
            "Superbasics limit": max(500, n_joints * n + 50),
        }
    # IPOPT's tol is on its scaled NLP error (not comparable one to one with SNOPT's); 1e-5 reaches
    # SNOPT-quality optima. The constraint-violation tolerances are tight so that
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


def make_solver(solver: str) -> SnoptSolver | IpoptSolver:
    """pydrake's ``SnoptSolver`` or ``IpoptSolver`` for ``solver`` (``snopt`` or ``ipopt``).

    Raises:
        InputError: the solver is not available in this pydrake build.
    """
    s = SnoptSolver() if solver == "snopt" else IpoptSolver()
    if not (s.available() and s.enabled()):
        raise InputError(f"solver {solver!r} is not available in this pydrake build")
    return s


def status_text(solver: str, result: MathematicalProgramResult) -> str:
    """The solver's exit status as one line (e.g. ``snopt info 1: optimality conditions satisfied``)."""
    details = result.get_solver_details()
    if solver == "snopt":
        info = int(details.info)
        return f"snopt info {info}: {SNOPT_INFO.get(info, 'see the SNOPT manual')}"
    return f"ipopt status {int(details.status)}: {details.ConvertStatusToString()}"


@dataclasses.dataclass(frozen=True)
class SolveSetup:
    """What every solve of one design run shares."""

    problem: Problem
    """Robot, cell, model, ``q_work`` and noise."""
    criterion: str
    """``kpi``, ``param``, ``d`` or ``o1``."""
    collision: bool
    """Impose collision and laser-beam clearance."""
    solver: str
    """``snopt`` or ``ipopt``."""
    pose_block: int | None
    """Poses per constraint binding (see :class:`~kpioed_drake.design.exact.program.DesignProgram`)."""
    active_rows: int | None
    """Clearance rows per pose passed to the solver (None: all)."""


@dataclasses.dataclass
class SolveOutcome:
    """The design one solve (or one series of block sweeps) reached, and what it cost."""

    q: np.ndarray
    """(n, 6) poses [rad], clipped to the joint box."""
    value: float
    """The criterion at ``q`` (NaN where F1^T F1 is singular) [criterion units]."""
    success: bool
    """The solver reported success (sweeps: converged with a kept block) and ``value`` is finite."""
    status: str
    """The solver's :func:`status_text` (sweeps: a summary of the sweeps and block statuses)."""
    solve_s: float
    """Wall time of the solver calls [s] (sweeps: of all sweeps, including the block checks)."""
    n_evals: int
    """Cost evaluations with gradient."""
    constraint_evals: int
    """Constraint evaluations with gradient (one per iterate)."""
    all_rows_retries: int = 0
    """Solves repeated with all clearance rows (:func:`solve_checked`)."""
    sweeps: int = 0
    """Block sweeps (0: one solve over all poses)."""


def solve_once(
    setup: SolveSetup,
    q_start: np.ndarray,
    *,
    active_rows: int | None,
    fixed_information: np.ndarray | None = None,
) -> SolveOutcome:
    """One solve of the design problem from ``q_start`` (n, 6) [rad].

    The cost is scaled to O(1) at the start: divided by the criterion's normalisation
    (:meth:`~kpioed_drake.estimation.criteria.Criterion.normalisation`).

    Args:
        active_rows: clearance rows per pose passed to the solver (None: all).
        fixed_information: (k, k) information of further poses held fixed (block sweeps).
    """
    problem, solver = setup.problem, setup.solver
    n = q_start.shape[0]
    obj = DesignObjective(problem, setup.criterion, fixed_information=fixed_information)
    v0 = obj.value(q_start)
    dp = DesignProgram(
        problem,
        criterion=setup.criterion,
        n=n,
        collision=setup.collision,
        cost_scale=1.0 / obj.normalisation(v0),
        active_rows=active_rows,
        pose_block=setup.pose_block,
        fixed_information=fixed_information,
    )
    s = make_solver(solver)
    opts = SolverOptions()
    options = solver_options(solver, n, n_joints=problem.robot.n_joints)
    for key, val in options.items():
        opts.SetOption(s.solver_id(), key, val)
    t0 = time.perf_counter()
    try:
        result = s.Solve(dp.prog, dp.initial_guess(q_start), opts)
    except RuntimeError:  # Drake wraps an exception of our callbacks, a Ctrl-C among them
        raise_if_interrupted()
        raise
    dt = time.perf_counter() - t0
    raise_if_interrupted()  # the solver may also turn a Ctrl-C in our callbacks into a failed solve
    q = np.asarray(result.GetSolution(dp.x), dtype=float).reshape(n, problem.robot.n_joints)
    # The controller commands only coupled poses: back onto the joint map's coupling equations
    # (SNOPT keeps linear equalities to its feasibility tolerance, 1e-6 rad)
    q = commandable_projection(problem.robot, q)
    # Bounds are hard in the check: clip round-off outside the joint box (SNOPT/IPOPT may leave
    # 1e-9 rad outside); the change is far below every tolerance.
    q = np.clip(q, problem.robot.lower, problem.robot.upper)
    # an incidence beyond the limit by the solver's own tolerance: back to the bound (poses the
    # independent check accepts are not touched)
    q = restore_incidence(problem, q)
    try:
        value = obj.value(q)
    except np.linalg.LinAlgError:
        value = float("nan")
    return SolveOutcome(
        q=q,
        value=float(value),
        success=bool(result.is_success()) and np.isfinite(value),
        status=status_text(solver, result),
        solve_s=dt,
        n_evals=dp.counters.cost,
        constraint_evals=dp.counters.constraint,
    )


def solve_checked(
    setup: SolveSetup, q_start: np.ndarray, *, fixed_information: np.ndarray | None = None
) -> tuple[SolveOutcome, DesignCheck]:
    """One solve from ``q_start`` and the independent check of its result.

    The reduced rows change identity between iterates; rarely (after a long first step) SNOPT then
    stops early. Such a start is solved again with every clearance row,
    the slower but robust formulation (times and evaluations then include both solves).
    """
    sol = solve_once(setup, q_start, active_rows=setup.active_rows, fixed_information=fixed_information)
    check = check_design(setup.problem, sol.q, collision=setup.collision)
    if setup.collision and setup.active_rows is not None and not (sol.success and check.n_infeasible == 0):
        full = solve_once(setup, q_start, active_rows=None, fixed_information=fixed_information)
        full.solve_s += sol.solve_s
        full.n_evals += sol.n_evals
        full.constraint_evals += sol.constraint_evals
        full.all_rows_retries = 1
        sol, check = full, check_design(setup.problem, full.q, collision=setup.collision)
    return sol, check


def solve_blocks(
    setup: SolveSetup,
    q_start: np.ndarray,
    *,
    block: int,
    seed: int,
    fixed_information: np.ndarray | None = None,
) -> SolveOutcome:
    """Sweeps over blocks of about ``block`` poses, each block optimised with the others fixed.

    The constraints hold pose by pose, so a block's problem is the full problem with the other
    poses' information ``F1^T F1`` held fixed (``fixed_information`` of
    :class:`~kpioed_drake.design.exact.objective.DesignObjective`), and a point where no block can
    improve is a KKT point of the full problem. A block's result is kept only if its solve
    succeeded, it passes the independent check and it does not increase the criterion; the design
    therefore stays feasible and its criterion never increases. The first sweep takes the poses in
    order, later ones in a random order (seeded by ``seed``). Sweeps stop when one lowers the
    criterion by less than :data:`~kpioed_drake.design.settings.SWEEP_RTOL` of its normalisation
    (:meth:`~kpioed_drake.estimation.criteria.Criterion.normalisation`: relative; for ``d``, a log, per
    parameter), or after :data:`~kpioed_drake.design.settings.MAX_SWEEPS`. ``solve_s`` is the wall
    time of all sweeps, including the checks of the block results. ``fixed_information`` (k, k):
    information of further poses held fixed throughout (given poses), added to every block's.
    """
    t0 = time.perf_counter()
    problem = setup.problem
    n = q_start.shape[0]
    q = q_start.copy()
    obj = DesignObjective(problem, setup.criterion, fixed_information=fixed_information)
    value = float(obj.value(q))
    n_blocks = -(-n // block)
    rng = np.random.default_rng(seed)
    out = SolveOutcome(q=q, value=value, success=False, status="", solve_s=0.0, n_evals=0, constraint_evals=0)
    solves = kept = 0
    infos: dict[str, int] = {}
    change = np.inf
    for sweep in range(MAX_SWEEPS):
        order = np.arange(n) if sweep == 0 else rng.permutation(n)
        before = value
        for idx in np.array_split(order, n_blocks):
            idx = np.sort(idx)
            F = problem.F1(np.delete(q, idx, axis=0))
            M0 = F.T @ F if fixed_information is None else F.T @ F + fixed_information
            sol, check = solve_checked(setup, q[idx], fixed_information=M0)
            solves += 1
            out.n_evals += sol.n_evals
            out.constraint_evals += sol.constraint_evals
            out.all_rows_retries += sol.all_rows_retries
            infos[sol.status] = infos.get(sol.status, 0) + 1
            if sol.success and check.n_infeasible == 0 and sol.value <= value:
                q[idx], value = sol.q, sol.value
                kept += 1
        out.sweeps = sweep + 1
        change = (before - value) / obj.normalisation(before)
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
