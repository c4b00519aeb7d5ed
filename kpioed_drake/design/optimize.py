"""The design entry point: the optimum experimental design of paper eq. (24), or the heuristic.

:func:`optimize_design` checks the request, then solves from each start in turn (the start methods
and poses: :mod:`~kpioed_drake.design.starts`): one solve up to
:data:`~kpioed_drake.design.settings.MAX_BLOCK_POSES` poses, block sweeps above
(:mod:`~kpioed_drake.design.exact.solve`), each result checked independently
(:func:`~kpioed_drake.design.exact.check.check_design`); it keeps the best feasible start, polishes it
on the exact criterion (:mod:`~kpioed_drake.design.polish`) and records it. A failed or infeasible
result raises :class:`~kpioed_drake.design.report.DesignError` unless ``allow_infeasible``.

Sequential re-identification (paper, section 3.1 and Outlook): with ``given`` poses already
measured, their information ``F1^T F1`` is held fixed and only the new poses are optimised, the
same as the block solves of a sweep; the result's criteria are those of the combined design.

Starts (``start``): ``heuristic`` (paper 3.2) or ``approximate`` (``kpi`` only, without ``given``:
:func:`~kpioed_drake.design.approximate.design.approximate_start`; several working poses: the
approximate design of their weighted mean). With ``given`` poses the approximate start is two
solves, from the certified design's candidates and from those of the approximate design with the
measured information. ``approx``, the approximate design the first approximate start is rounded
from (without ``given``), e.g. the certificate's
:func:`~kpioed_drake.design.approximate.certificate.certified_design` of the same problem and
``collision``, starts the optimiser nearer the optimum than the cheaper default
(:func:`~kpioed_drake.design.approximate.design.start_approximation`). The polish runs for the
``kpi`` criterion with an approximate start and one solve over all poses.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from kpioed_drake import progress
from kpioed_drake.design.approximate.design import ApproximateDesign
from kpioed_drake.design.exact.check import DesignCheck, check_design
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.exact.solve import SolveOutcome, SolveSetup, solve_blocks, solve_checked
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.polish import POLISH_ROUNDS, Polished, polish_design, remove_poses
from kpioed_drake.design.report import DesignError, DesignReport
from kpioed_drake.design.settings import (
    ACTIVE_ROWS_PER_POSE,
    DESIGN_METHODS,
    MAX_BLOCK_POSES,
    POSE_BLOCK,
    SOLVERS,
    SWEEP_BLOCK_POSES,
)
from kpioed_drake.design.starts import checked_poses, resolve_start, start_methods, start_poses
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
            f"determine the {problem.n_params} parameters of {problem.robot.name} "
            f"({problem.rows_per_pose} coordinates per pose)",
            fields=("n",),
        )
    if not _positive_int(starts):
        raise InputError(f"starts must be a positive integer, got {starts!r}", fields=("starts",))
    if max_block is not None and not _positive_int(max_block):
        raise InputError(f"max_block must be a positive integer or None, got {max_block!r}")
    if not _positive_int(sweep_block):
        raise InputError(f"sweep_block must be a positive integer, got {sweep_block!r}")


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
    """The ``given`` field of :class:`DesignReport`: the given poses alone."""
    if given is None:
        return None
    alone = _criteria(problem, given, None)
    return {
        "n_given": int(len(given)),
        "given_kpi_avg_var_mm2": alone["kpi_avg_var_mm2"],
        "given_param_crit": alone["param_crit"],
        "given_q_deg": np.rad2deg(given).tolist(),
    }


def _base_record(
    problem: Problem, criterion: str, collision: bool, seed: int, given: np.ndarray | None
) -> dict:
    """The fields of :class:`DesignReport` every design method fills the same way."""
    return dict(
        criterion=criterion,
        collision=collision,
        robot=problem.robot.name,
        seed=int(seed),
        given=_given_record(problem, given),
    )


def _heuristic_result(
    problem: Problem, *, n: int, seed: int, collision: bool, given: np.ndarray | None, base: dict
) -> DesignReport:
    q = heuristic_design(problem, n=n, seed=seed, collision=collision)
    reports, n_bad, n_col = check_design(problem, q, collision=collision)
    crit = _criteria(problem, q, given, strict=given is None)
    return DesignReport(
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
) -> DesignReport:
    """Optimum experimental design (paper eq. 24) or, for ``criterion="heuristic"``, the heuristic.

    Args:
        problem: robot, cell, model, ``q_work`` and noise.
        criterion: the design method, one of :data:`~kpioed_drake.design.settings.DESIGN_METHODS`:
            ``heuristic``, ``kpi`` (tr(Cs)/3), ``param`` (scaled tr(Cp)), ``d`` or ``o1``.
        n: number of poses (at least ``problem.min_poses()``).
        collision: impose collision and laser-beam clearance (paper "CA").
        solver: ``snopt`` or ``ipopt``.
        seed: seed of the start; start k uses ``seed + k``.
        starts: number of starts; the best feasible result is kept (starts after the first are
            heuristic; with ``given``, see the module's note on starts).
        q0: (n, 6) [rad] start of the first solve instead of ``start``'s.
        allow_infeasible: return a failed or infeasible result instead of raising.
        active_rows, pose_block, max_block, sweep_block: the solves' sizes (defaults in
            :mod:`~kpioed_drake.design.settings`): clearance rows per pose passed to the solver
            (None: all), poses per constraint binding (None: one binding), most poses one solve
            varies (more: sweeps over blocks of about ``sweep_block`` poses, the others fixed;
            ``status`` reports them, ``sweeps`` counts them; None: always one solve).
        given: (m, 6) [rad] poses already measured (sequential re-identification): their
            information is held fixed and the ``n`` new poses are optimised (at least
            :func:`min_new_poses`). The given poses are neither moved nor checked.
        start: how the starting poses are made (module note; one of
            :data:`~kpioed_drake.design.settings.START_METHODS`; None: :func:`resolve_start`),
            recorded in the result's ``start`` (``q0`` when the caller's ``q0`` was kept).
        approx: the approximate design the first approximate start is rounded from (module note).
        polish: most rounds of the final exchange on the exact criterion
            (:func:`~kpioed_drake.design.polish.polish_design`; module note); 0: none.

    Returns:
        :class:`~kpioed_drake.design.report.DesignReport` of the ``n`` new poses; its criteria
        (``value``, ``kpi_avg_var_mm2``, ``param_crit``) are those of the combined design (given
        and new poses), ``given`` records the given poses alone.

    Raises:
        InputError: bad ``n``, criterion, solver, ``start`` or ``q0``; no feasible heuristic start.
        DesignError: the solver failed or the design is infeasible (unless ``allow_infeasible``).
    """
    if given is not None:
        given = checked_poses(problem, given, None, "given", limits=False)
    _validate(
        problem, criterion, n, solver, starts, max_block, sweep_block, 0 if given is None else len(given)
    )
    n = int(n)
    start = resolve_start(start, criterion, given=given, worst_case=problem.worst_case)
    base = _base_record(problem, criterion, collision, seed, given)
    if criterion == "heuristic":
        res = _heuristic_result(problem, n=n, seed=seed, collision=collision, given=given, base=base)
        return _finish(res, allow_infeasible)
    if q0 is not None:
        q0 = checked_poses(problem, q0, n, "q0")
    setup = SolveSetup(problem, criterion, collision, solver, pose_block, active_rows)
    run = _make_run(setup, n=n, seed=seed, given=given, max_block=max_block, sweep_block=sweep_block)
    res = _optimized(run, start, starts=starts, q0=q0, approx=approx, polish=polish, base=base)
    return _finish(res, allow_infeasible)


@dataclasses.dataclass(frozen=True)
class _Run:
    """What every start of one :func:`optimize_design` call shares."""

    setup: SolveSetup
    objective: DesignObjective
    n: int
    seed: int
    given: np.ndarray | None
    M_given: np.ndarray | None  # the given poses' information F^T F
    blocks: int | None  # poses per block of the sweeps; None: one solve over all poses


def _make_run(
    setup: SolveSetup, *, n: int, seed: int, given: np.ndarray | None, max_block: int | None, sweep_block: int
) -> _Run:
    """What every start of one :func:`optimize_design` call shares: the objective (with the
    ``given`` poses' information held fixed) and the sweep blocks (None up to ``max_block`` poses)."""
    M_given = None
    if given is not None:
        F_given = setup.problem.F1(given)
        M_given = F_given.T @ F_given
    return _Run(
        setup=setup,
        objective=DesignObjective(setup.problem, setup.criterion, fixed_information=M_given),
        n=n,
        seed=int(seed),
        given=given,
        M_given=M_given,
        blocks=None if max_block is None or n <= max_block else int(sweep_block),
    )


@dataclasses.dataclass(frozen=True)
class _Start:
    """One start's solve: its outcome, the independent check, the criterion at its starting poses,
    the approximate design its poses were rounded from (None: heuristic or q0) and its start time."""

    sol: SolveOutcome
    check: DesignCheck
    initial: float
    pool: ApproximateDesign | None
    start_s: float


def _optimized(
    run: _Run, start: str, *, starts: int, q0: np.ndarray | None, approx, polish: int, base: dict
) -> DesignReport:
    """Solve from each start, keep the best, polish it where the polish applies: the report."""
    methods = start_methods(start, starts, given=run.given, q0=q0)
    runs = []
    with progress.stage(f"design of {run.n} poses", total=len(methods), unit="start"):
        for k, m in enumerate(methods):
            runs.append(_solve_from(run, k, m, q0=q0, approx=approx if k == 0 else None))
            progress.step(criterion=float(runs[-1].sol.value))
    best = _best(runs)
    polished = None
    if polish and run.setup.criterion == "kpi" and run.blocks is None and runs[best].pool is not None:
        polished = _polish(run, runs[best], int(polish))
    return _result(
        run, runs, best, polished, start="q0" if (best == 0 and q0 is not None) else start, base=base
    )


def _solve_from(run: _Run, k: int, method: str, *, q0, approx) -> _Start:
    """Start ``k`` (method ``method``): its poses, their criterion, the solve and the check."""
    problem, pool, start_s = run.setup.problem, None, 0.0
    if method == "q0":
        q_start = q0
    else:
        t_start = time.perf_counter()
        seed = run.seed if method == "given" else run.seed + k  # the certified design of ``seed``
        q_start, pool = start_poses(
            problem, method, n=run.n, seed=seed, collision=run.setup.collision, given=run.given, approx=approx
        )
        start_s = time.perf_counter() - t_start
    try:
        initial = float(run.objective.value(q_start))
    except np.linalg.LinAlgError:
        initial = float("nan")
    if run.blocks is not None:
        sol = solve_blocks(
            run.setup, q_start, block=run.blocks, seed=run.seed + k, fixed_information=run.M_given
        )
        check = check_design(problem, sol.q, collision=run.setup.collision)
    else:
        sol, check = solve_checked(run.setup, q_start, fixed_information=run.M_given)
    return _Start(sol, check, initial, pool, start_s)


def _best(runs: list[_Start]) -> int:
    """The best start: the lowest value of the successful feasible ones, else of the finite ones."""
    good = [k for k, r in enumerate(runs) if r.sol.success and r.check.n_infeasible == 0]
    pool = good or [k for k, r in enumerate(runs) if np.isfinite(r.sol.value)] or [0]
    return min(pool, key=lambda k: runs[k].sol.value if np.isfinite(runs[k].sol.value) else np.inf)


def _polish(run: _Run, best: _Start, rounds: int) -> Polished:
    """The final exchange on the exact criterion (:func:`~kpioed_drake.design.polish.polish_design`)
    over the candidates of the best start's approximate design."""
    return polish_design(
        run.setup,
        best.sol,
        best.check,
        pool_q=best.pool.q,
        pool_F=best.pool.F,
        rounds=rounds,
        fixed_information=run.M_given,
    )


def _result(run: _Run, runs: list[_Start], best: int, polished: Polished | None, *, start: str, base: dict):
    """The :class:`DesignReport` of the best start (polished where it was)."""
    sol, check = (runs[best].sol, runs[best].check) if polished is None else (polished.sol, polished.check)
    reports, n_bad, n_col = check
    crit = _criteria(run.setup.problem, sol.q, run.given)
    return DesignReport(
        q=sol.q,
        value=sol.value,
        solver=run.setup.solver,
        status=sol.status,
        success=sol.success,
        solve_s=float(sum(r.sol.solve_s for r in runs)) + (polished.solve_s if polished else 0.0),
        n_evals=int(sum(r.sol.n_evals for r in runs)) + (polished.n_evals if polished else 0),
        constraint_evals=int(sum(r.sol.constraint_evals for r in runs)),
        feasible=n_bad == 0,
        n_infeasible_poses=n_bad,
        n_colliding_poses=n_col,
        reports=[r.as_dict() for r in reports],
        start_values=[r.sol.value if r.sol.success else float("nan") for r in runs],
        initial_values=[r.initial for r in runs],
        best_start=best,
        all_rows_retries=sum(r.sol.all_rows_retries for r in runs),
        sweeps=sol.sweeps,
        start=start,
        start_s=sum(r.start_s for r in runs),
        polish=None if polished is None else _polish_record(polished),
        **crit,
        **base,
    )


def _polish_record(p) -> dict:
    """The ``polish`` field of :class:`DesignReport`."""
    return {"rounds": p.rounds, "value_before": p.value_before, "solve_s": p.solve_s, "n_evals": p.n_evals}


def _finish(res: DesignReport, allow_infeasible: bool) -> DesignReport:
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


def first_target_n(problem: Problem, V: float, given: np.ndarray | None, max_poses: int) -> int:
    """The first N of :func:`~kpioed_drake.design.target.design_for_target`'s search for the target
    V [mm^2]: :func:`min_new_poses`, after checking that the ``given`` poses alone do not reach V
    and that ``max_poses`` allows N (else :class:`~kpioed_drake.errors.InputError`)."""
    n_given = 0 if given is None else len(np.atleast_2d(given))
    n_min = min_new_poses(problem, n_given)
    if given is not None:
        try:
            alone = problem.criteria(given)["kpi_avg_var_mm2"]
        except InputError:
            alone = np.inf
        if alone <= V:
            raise InputError(
                f"the {n_given} given poses already reach tr(Cs)/3 = {alone:.4g} <= {V:.4g} mm^2: "
                "no new poses are needed"
            )
    if max_poses < n_min:
        raise InputError(f"max_poses {max_poses} is below the fewest poses {n_min}")
    return n_min


def target_attempt(
    problem: Problem, n: int, V: float, previous: DesignReport | None, *, shrink: bool, settings: dict
) -> tuple[DesignReport, dict]:
    """One solve of :func:`~kpioed_drake.design.target.design_for_target`'s search: ``n`` poses
    (``optimize_design`` with ``settings``, infeasible results kept) started from ``previous``
    reduced to ``n`` poses by :func:`~kpioed_drake.design.polish.remove_poses` (``shrink``, the
    bisection) or grown with heuristic poses (the doubling; no ``q0`` if ``previous`` is None
    or infeasible).

    Returns:
        The design and its row of the search's trail: ``n_poses``, ``kpi_avg_var_mm2`` [mm^2],
        ``reached`` (solved, feasible and at most V), ``success``, ``feasible``, ``solve_s``.
    """
    q0 = None
    if previous is not None and shrink:
        q0 = remove_poses(problem, previous.q, n, given=settings["given"])
    elif previous is not None:
        more = heuristic_design(
            problem, n=n - len(previous.q), seed=settings["seed"] + n, collision=settings["collision"]
        )
        q0 = np.concatenate([previous.q, more]) if previous.feasible else None
    res = optimize_design(problem, n=n, q0=q0, allow_infeasible=True, **settings)
    row = {
        "n_poses": n,
        "kpi_avg_var_mm2": res.kpi_avg_var_mm2,
        "reached": bool(res.success and res.feasible and res.kpi_avg_var_mm2 <= V),
        "success": res.success,
        "feasible": res.feasible,
        "solve_s": res.solve_s,
    }
    return res, row
