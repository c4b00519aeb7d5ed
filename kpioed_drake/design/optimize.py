"""The design entry point: the optimum experimental design of paper eq. (24), or the heuristic.

:func:`optimize_design` validates the request, makes one or more heuristic starts
(:mod:`~kpioed_drake.design.heuristic`), solves each (:mod:`~kpioed_drake.design.exact.solve`: one solve
up to :data:`~kpioed_drake.design.common.MAX_BLOCK_POSES` poses, block sweeps above), checks every
result independently (:func:`~kpioed_drake.design.exact.check.check_design`) and keeps the best feasible
start. A failed or infeasible result raises :class:`~kpioed_drake.design.result.DesignError`
unless ``allow_infeasible``.

Starts (``start``, :data:`~kpioed_drake.design.common.START_METHODS`): the paper's heuristic, or for
the ``kpi`` criterion the approximate design (column generation over the feasible poses, Clarabel)
rounded to n poses (:func:`~kpioed_drake.design.approximate.design.approximate_start`); with poses
held fixed, the certified approximate design's candidates chosen with their information
(:func:`~kpioed_drake.design.approximate.sequential.given_start`), and as a second start the same
rounding over the candidates of the approximate design made with their information
(:func:`~kpioed_drake.design.approximate.given.given_design`): neither start wins on every set of
measured poses (docs/online.md). The approximate design is the
optimum of the KPI criterion over weights on poses; it is not defined for the other criteria's
objectives, so ``start="approximate"`` is an input error there.

Sequential re-identification (paper, section 3.1 and Outlook): with ``given`` poses already
measured, their information ``F1^T F1`` is held fixed and only the new poses are optimised, the
same as the block solves of a sweep; the result's criteria are those of the combined design.
"""

from __future__ import annotations

import time

import numpy as np

from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate.design import ApproximateDesign, approximate_start, start_approximation
from kpioed_drake.design.approximate.given import given_design
from kpioed_drake.design.approximate.sequential import given_start
from kpioed_drake.design.common import (
    ACTIVE_ROWS_PER_POSE,
    DEFAULT_START,
    DESIGN_METHODS,
    MAX_BLOCK_POSES,
    POSE_BLOCK,
    SOLVERS,
    START_METHODS,
    SWEEP_BLOCK_POSES,
)
from kpioed_drake.design.exact.check import DesignCheck, check_design
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.exact.solve import SolveOutcome, SolveSetup, solve_blocks, solve_checked
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.polish import POLISH_ROUNDS, polish_design
from kpioed_drake.design.result import DesignError, DesignResult
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem


def _positive_int(x) -> bool:
    return isinstance(x, int | np.integer) and x >= 1


def min_new_poses(problem: Problem, n_given: int = 0) -> int:
    """Fewest new poses of a design: enough to determine the parameters together with ``n_given``
    poses held fixed (at least 1)."""
    return max(1, problem.min_poses() - n_given) if n_given else problem.min_poses()


def _validate(
    problem: Problem, criterion: str, n: int, solver: str, starts: int, max_block, sweep_block, n_given: int
) -> None:
    """Raise :class:`~kpioed_drake.errors.InputError` naming the first bad argument of
    :func:`optimize_design`."""
    if criterion not in DESIGN_METHODS:
        raise InputError(
            f"unknown criterion {criterion!r}; expected one of {', '.join(DESIGN_METHODS)}",
            fields=("criterion",),
        )
    if solver not in SOLVERS:
        raise InputError(
            f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}", fields=("solver",)
        )
    if not isinstance(n, int | np.integer) or n < min_new_poses(problem, n_given):
        given = f" with the {n_given} given poses" if n_given else ""
        raise InputError(
            f"n {n}: a design needs at least {min_new_poses(problem, n_given)} poses{given} to "
            f"determine the {problem.n_params} parameters of {problem.robot.name} (3 coordinates per pose)",
            fields=("n",),
        )
    if not _positive_int(starts):
        raise InputError(f"starts must be a positive integer, got {starts!r}", fields=("starts",))
    if max_block is not None and not _positive_int(max_block):
        raise InputError(f"max_block must be a positive integer or None, got {max_block!r}")
    if not _positive_int(sweep_block):
        raise InputError(f"sweep_block must be a positive integer, got {sweep_block!r}")


def resolve_start(start: str | None, criterion: str, *, given=None, worst_case: bool = False) -> str:
    """The start method of :func:`optimize_design`: ``start``, or for None
    :data:`~kpioed_drake.design.common.DEFAULT_START` where it applies (``kpi`` criterion, not the
    worst case of several working poses, whose approximate design would be that of their mean)
    and else ``heuristic``.

    Raises:
        InputError: an unknown start, or ``approximate`` for another criterion than ``kpi``.
    """
    if start is None:
        applies = criterion == "kpi" and not worst_case
        return DEFAULT_START if applies else "heuristic"
    if start not in START_METHODS:
        raise InputError(
            f"unknown start {start!r}; expected one of {', '.join(START_METHODS)}", fields=("start",)
        )
    if start == "approximate" and criterion != "kpi":
        raise InputError(
            f"start 'approximate' is the approximate KPI design: it needs criterion 'kpi', not {criterion!r}",
            fields=("start", "criterion"),
        )
    return start


def _start_poses(
    problem: Problem, start: str, *, n: int, seed: int, collision: bool, given=None, approx=None
) -> tuple[np.ndarray, object]:
    """(n, 6) [rad] starting poses of the method ``start`` with seed ``seed``, and the approximate
    design behind them (its candidates ``q`` and rows ``F``; None for the heuristic); with
    ``given`` poses the approximate start is the certified approximate design's candidates chosen
    with their information (:func:`~kpioed_drake.design.approximate.sequential.given_start`).
    ``approx``: the approximate design to round (None: :func:`start_approximation`)."""
    if start in ("approximate", "given") and given is not None:
        approx = certificate.certified_design(problem, collision=collision, seed=seed)
        if start == "given":
            approx = given_design(problem, approx, given=given, n=n, collision=collision)
        return given_start(problem, approx, n=n, given=given), approx
    if start == "approximate":
        if approx is None:
            approx = start_approximation(problem, collision=collision, seed=seed)
        return approximate_start(problem, n=n, collision=collision, seed=seed, approx=approx), approx
    return heuristic_design(problem, n=n, seed=seed, collision=collision), None


def _start_methods(start: str, starts: int, *, given, q0) -> list[str]:
    """The start method of each solve: ``q0`` first if given; with ``given`` poses and the
    approximate start, its two roundings (``approximate``: the certified design's candidates;
    ``given``: those of the approximate design with the measured information) count as one start,
    and further starts are heuristic (one certified design); else ``start`` each time."""
    first = "q0" if q0 is not None else start
    if given is None:
        return [first] + [start] * (starts - 1)
    two = [first, "given"] if first == "approximate" else [first]
    return two + ["heuristic"] * (starts - 1)


def _checked_poses(problem: Problem, q, n: int | None, name: str, *, limits: bool = True) -> np.ndarray:
    """``q`` as a finite (n, 6) array (any n >= 1 if ``n`` is None), within the joint limits if
    ``limits`` (not for measured poses: they enter only through their information, and a pose
    measured at a limit comes back from a file in degrees a rounding beyond it)."""
    q = np.asarray(q, dtype=float)
    nj = problem.robot.n_joints
    shape = f"({'m' if n is None else n}, {nj})"
    if q.ndim != 2 or q.shape[1] != nj or q.shape[0] != (n or q.shape[0]) or not q.size:
        raise InputError(f"{name} must be a finite {shape} array of joint angles [rad], got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InputError(f"{name} must be a finite {shape} array of joint angles [rad]")
    if limits and (np.any(q < problem.robot.lower) or np.any(q > problem.robot.upper)):
        raise InputError(f"{name}: a joint angle is outside the robot's joint limits")
    return q


def _criteria(problem: Problem, q: np.ndarray, given: np.ndarray | None, *, strict: bool = False) -> dict:
    """``kpi_avg_var_mm2``, ``param_crit`` and (several working poses) ``kpi_vars_mm2`` of the
    design ``q`` together with the ``given`` poses (NaN where they do not determine the parameters,
    or with ``strict`` the :class:`~kpioed_drake.errors.InputError`)."""
    q_all = q if given is None else np.concatenate([given, q])
    try:
        crit = problem.criteria(q_all)
        if problem.n_kpis > 1:
            crit["kpi_vars_mm2"] = problem.kpi_variances(q_all).tolist()
    except InputError:
        if strict:
            raise
        crit = {"kpi_avg_var_mm2": float("nan"), "param_crit": float("nan")}
    return crit


def _given_record(problem: Problem, given: np.ndarray | None) -> dict | None:
    """The ``given`` field of :class:`DesignResult`: the given poses alone."""
    if given is None:
        return None
    alone = _criteria(problem, given, None)
    return {
        "n_given": int(len(given)),
        "given_kpi_avg_var_mm2": alone["kpi_avg_var_mm2"],
        "given_param_crit": alone["param_crit"],
        "given_q_deg": np.rad2deg(given).tolist(),
    }


def _heuristic_result(
    problem: Problem, *, n: int, seed: int, collision: bool, given: np.ndarray | None, base: dict
) -> DesignResult:
    q = heuristic_design(problem, n=n, seed=seed, collision=collision)
    reports, n_bad, n_col = check_design(problem, q, collision=collision)
    crit = _criteria(problem, q, given, strict=given is None)
    return DesignResult(
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
    given: np.ndarray | None = None,
    start: str | None = None,
    polish: int = POLISH_ROUNDS,
    approx: ApproximateDesign | None = None,
) -> DesignResult:
    """Optimum experimental design (paper eq. 24) or, for ``criterion="heuristic"``, the heuristic.

    Args:
        problem: robot, cell, model, ``q_work`` and noise.
        criterion: the design method, one of :data:`~kpioed_drake.design.common.DESIGN_METHODS`:
            ``heuristic``, ``kpi`` (tr(Cs)/3), ``param`` (scaled tr(Cp)), ``d`` or ``o1``.
        n: number of poses (at least ``problem.min_poses()``).
        collision: impose collision and laser-beam clearance (paper "CA").
        solver: ``snopt`` or ``ipopt``.
        seed: seed of the start; start k uses ``seed + k``.
        starts: number of starts; the best feasible result is kept (with ``given`` poses the
            approximate start is two solves, from the certified design's candidates and from
            those of the approximate design with the measured information; starts after the
            first are heuristic).
        q0: (n, 6) [rad] start of the first solve instead of ``start``'s.
        allow_infeasible: return a failed or infeasible result instead of raising.
        active_rows: clearance rows per pose passed to the solver (its smallest ones; None: all
            rows); see :class:`~kpioed_drake.design.exact.program.DesignProgram`.
        pose_block: poses per constraint binding (default
            :data:`~kpioed_drake.design.common.POSE_BLOCK`; None: one binding for all poses).
        max_block: most poses one solve varies (default
            :data:`~kpioed_drake.design.common.MAX_BLOCK_POSES`). A design of more poses is
            optimised by sweeps over blocks of about ``sweep_block`` poses, each solved with the
            others fixed; ``status`` then reports the sweeps and ``sweeps`` their number. None:
            always one solve over all poses.
        sweep_block: poses per block in sweeps (default
            :data:`~kpioed_drake.design.common.SWEEP_BLOCK_POSES`).
        given: (m, 6) [rad] poses already measured (sequential re-identification): their
            information is held fixed and the ``n`` new poses are optimised (at least
            :func:`min_new_poses`). The given poses are neither moved nor checked.
        start: how the starting poses are made, one of
            :data:`~kpioed_drake.design.common.START_METHODS`: ``heuristic`` (paper 3.2) or
            ``approximate`` (``kpi`` only, without ``given``:
            :func:`~kpioed_drake.design.approximate.design.approximate_start`; several working poses:
            the approximate design of their weighted mean); None: :func:`resolve_start`.
            Recorded in the result's ``start`` (``q0`` when the caller's ``q0`` was kept).
        approx: the approximate design the first approximate start is rounded from (without
            ``given``), e.g. the certificate's
            :func:`~kpioed_drake.design.approximate.certificate.certified_design` of the same
            problem and ``collision``, whose rounding starts the optimiser nearer the optimum than
            the cheaper default (:func:`~kpioed_drake.design.approximate.design.start_approximation`).
        polish: most rounds of the final exchange on the exact criterion after the optimiser
            (``kpi`` criterion with an approximate start, one solve over all poses;
            :func:`~kpioed_drake.design.polish.polish_design`); 0: none.

    Returns:
        :class:`~kpioed_drake.design.result.DesignResult` of the ``n`` new poses; its criteria
        (``value``, ``kpi_avg_var_mm2``, ``param_crit``) are those of the combined design (given
        and new poses), ``given`` records the given poses alone.

    Raises:
        InputError: bad ``n``, criterion, solver, ``start`` or ``q0``; no feasible heuristic start.
        DesignError: the solver failed or the design is infeasible (unless ``allow_infeasible``).
    """
    if given is not None:
        given = _checked_poses(problem, given, None, "given", limits=False)
    _validate(
        problem, criterion, n, solver, starts, max_block, sweep_block, 0 if given is None else len(given)
    )
    n = int(n)
    start = resolve_start(start, criterion, given=given, worst_case=problem.worst_case)
    base = dict(
        criterion=criterion,
        collision=collision,
        robot=problem.robot.name,
        seed=int(seed),
        given=_given_record(problem, given),
    )
    if criterion == "heuristic":
        res = _heuristic_result(problem, n=n, seed=seed, collision=collision, given=given, base=base)
        return _finish(res, allow_infeasible)
    if q0 is not None:
        q0 = _checked_poses(problem, q0, n, "q0")
    M_given = None
    if given is not None:
        F_given = problem.F1(given)
        M_given = F_given.T @ F_given
    setup = SolveSetup(
        problem=problem,
        criterion=criterion,
        collision=collision,
        solver=solver,
        pose_block=pose_block,
        active_rows=active_rows,
    )
    obj = DesignObjective(problem, criterion, fixed_information=M_given)
    solves: list[SolveOutcome] = []
    checks: list[DesignCheck] = []
    initial: list[float] = []
    pools: list = []  # the approximate design behind each start (None: heuristic or q0)
    start_s = 0.0
    methods = _start_methods(start, starts, given=given, q0=q0)
    for k, method in enumerate(methods):
        pool = None
        if method == "q0":
            q_start = q0
        else:
            t_start = time.perf_counter()
            s = seed if method == "given" else seed + k  # the certified design of ``seed``
            q_start, pool = _start_poses(
                problem,
                method,
                n=n,
                seed=s,
                collision=collision,
                given=given,
                approx=approx if k == 0 else None,
            )
            start_s += time.perf_counter() - t_start
        pools.append(pool)
        try:
            initial.append(float(obj.value(q_start)))
        except np.linalg.LinAlgError:
            initial.append(float("nan"))
        if max_block is not None and n > max_block:
            sol = solve_blocks(
                setup, q_start, block=int(sweep_block), seed=seed + k, fixed_information=M_given
            )
            check = check_design(problem, sol.q, collision=collision)
        else:
            sol, check = solve_checked(setup, q_start, fixed_information=M_given)
        solves.append(sol)
        checks.append(check)
    good = [k for k, s in enumerate(solves) if s.success and checks[k].n_infeasible == 0]
    pool = good or [k for k, s in enumerate(solves) if np.isfinite(s.value)] or [0]
    best = min(pool, key=lambda k: solves[k].value if np.isfinite(solves[k].value) else np.inf)
    sol, check, polished = solves[best], checks[best], None
    one_solve = max_block is None or n <= max_block
    if polish and criterion == "kpi" and one_solve and pools[best] is not None:
        polished = polish_design(
            setup,
            sol,
            check,
            pool_q=pools[best].q,
            pool_F=pools[best].F,
            rounds=int(polish),
            fixed_information=M_given,
        )
        sol, check = polished.sol, polished.check
    reports, n_bad, n_col = check
    crit = _criteria(problem, sol.q, given)
    res = DesignResult(
        q=sol.q,
        value=sol.value,
        solver=solver,
        status=sol.status,
        success=sol.success,
        solve_s=float(sum(s.solve_s for s in solves)) + (polished.solve_s if polished else 0.0),
        n_evals=int(sum(s.n_evals for s in solves)) + (polished.n_evals if polished else 0),
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
        start="q0" if (best == 0 and q0 is not None) else start,
        start_s=start_s,
        polish=None if polished is None else _polish_record(polished),
        **crit,
        **base,
    )
    return _finish(res, allow_infeasible)


def _polish_record(p) -> dict:
    """The ``polish`` field of :class:`DesignResult`."""
    return {"rounds": p.rounds, "value_before": p.value_before, "solve_s": p.solve_s, "n_evals": p.n_evals}


def _finish(res: DesignResult, allow_infeasible: bool) -> DesignResult:
    """``res``, or :class:`DesignError` naming the failure or the first infeasible pose."""
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
    raise DesignError(
        msg + "; use allow_infeasible to keep it anyway, or try another seed/starts",
        res,
        fields=("allow_infeasible", "seed", "starts"),
    )
