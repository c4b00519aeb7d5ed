"""The tasks of the paper's study (sections 3.3.1 and 3.3.2, Tables 6-8): which designs, and one design
made, evaluated and checked.

A :class:`Task` is one design: robot x design method (``heuristic``, ``param`` = phi_A(Cp),
``kpi`` = phi_A(Cs), paper eq. 24a with the projections of eq. 25) x collision avoidance x seed.
:func:`run_task` makes it with :mod:`kpioed_drake.design`, evaluates both criteria with
``Problem.criteria`` and checks every pose with the independent Drake checker
(:class:`~kpioed_drake.tracker.feasibility.FeasibilityChecker`, collisions always checked, so a design made
without collision avoidance reports its colliding poses). It runs in a worker process, on a Dask worker
or inline, and returns a JSON-able row.

A :class:`BoundTask` is the other kind of task: the lower bound on tr(Cs)/3 of any n-pose design of
a robot with collision avoidance (:func:`kpioed_drake.design.certified_design`, the search behind
the optimality certificate), the same for every design of the robot; :func:`run_task` computes it
too and :mod:`.bounds` joins it into the tables as each design's efficiency.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import math
import re
import time
import traceback
from collections.abc import Iterable, Mapping

import numpy as np

from kpioed_drake import design
from kpioed_drake.errors import raise_if_interrupted
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.models import list_robots
from kpioed_drake.study.variants import DEFAULT, variant_problem
from kpioed_drake.tracker.feasibility import FeasibilityChecker

KUKA = ("kr16", "kr300", "kr500")
"""The KUKA robots of Table 6 (our kr16 is the paper's KR 15)."""

METHODS = ("heuristic", "param", "kpi")
"""Design methods of the study (a subset of ``kpioed_drake.design.DESIGN_METHODS``), in the row order
of Tables 7 and 8."""

QUICK_NOTIONAL = (
    "notional-650-600",
    "notional-650-1000",
    "notional-1100-600",
    "notional-1100-1000",
    "notional-850-800",
    "notional-950-700",
)
"""Notional robots of the quick study, spread over the lambda-mu grid."""

STUDY_STARTS = {"param": "heuristic", "kpi": "approximate"}
"""The optimiser's start per design method: the paper's random start for the standard design, and
for the KPI design what ``kpioed design`` does, the certified approximate design rounded to n poses
and exchanged on the exact criterion (docs/certificate.md), so that the KPI column and its
efficiency are what a user gets."""


_NOTIONAL = re.compile(r"^notional-(\d+)-(\d+)$")


@dataclasses.dataclass(frozen=True)
class Task:
    """One design of the study."""

    robot: str
    """Model name."""
    method: str
    """Design method: ``heuristic``, ``param`` or ``kpi`` (the ``criterion`` column of the results)."""
    collision: bool
    """Collision avoidance on (the paper's "CA") or off ("no CA")."""
    seed: int
    """Random seed of the heuristic draw or of the optimiser's start."""
    n: int
    """Number of poses."""
    variant: str = DEFAULT
    """Name of the problem variant (:mod:`.variants`)."""

    @classmethod
    def from_row(cls, row: Mapping) -> Task:
        """The task of a result row (a :func:`run_task` row or a row of ``results.csv``)."""
        return cls(
            str(row["robot"]),
            str(row["criterion"]),
            bool(row["collision_avoidance"]),
            int(row["seed"]),
            int(row["n"]),
            _variant_of(row),
        )

    @property
    def ca(self) -> str:
        """``ca`` or ``noca``."""
        return "ca" if self.collision else "noca"

    @property
    def task_id(self) -> str:
        """Unique name of the task (its result file is ``tasks/<task_id>.json``)."""
        return f"{self.robot}_{self.method}_{self.ca}_s{self.seed}_n{self.n}{self._suffix}"

    @property
    def _suffix(self) -> str:
        """``""`` for the default variant, else ``_v<variant>``."""
        return "" if self.variant == DEFAULT else f"_v{self.variant}"

    @property
    def design_name(self) -> str:
        """File name of the design in ``designs/`` (the seed only for the heuristic draws)."""
        base = f"{self.robot}_{self.method}_{self.ca}"
        base = f"{base}_s{self.seed}" if self.method == "heuristic" else base
        return f"{base}{self._suffix}.csv"


@dataclasses.dataclass(frozen=True)
class BoundTask:
    """The lower bound on tr(Cs)/3 of any ``n``-pose design of a robot with collision avoidance."""

    robot: str
    """Model name."""
    n: int
    """Number of poses."""
    variant: str = DEFAULT
    """Name of the problem variant (:mod:`.variants`)."""
    seed: int = 0
    """Seed of the search."""
    method = "bound"
    """The task kind (where a :class:`Task` has its design method)."""
    collision = True
    """The bound is on designs with collision avoidance."""

    @property
    def task_id(self) -> str:
        """Unique name of the task (its result file is ``tasks/<task_id>.json``)."""
        suffix = "" if self.variant == DEFAULT else f"_v{self.variant}"
        return f"{self.robot}_bound_ca_s{self.seed}_n{self.n}{suffix}"

    @property
    def design_name(self) -> None:
        """A bound has no design file."""
        return None


def make_bound_tasks(robots: Iterable[str], *, n: int = 60, seed: int = 0, variant: str = DEFAULT) -> list:
    """One :class:`BoundTask` per robot."""
    return [BoundTask(r, n, variant, seed) for r in robots]


def _run_bound(api, problem: Problem, task: BoundTask) -> dict:
    """The fields of a bound row: ``bound_mm2`` = ``tr(K^T Y)^2 / (n g_max)`` [mm^2] (the search's
    bound), ``dual_mm2`` = ``tr(K^T Y)^2``, ``g_max``, ``Y`` (k, 3) (to cover a design's own poses,
    :func:`.bounds.design_bound`), ``approximate_mm2`` (``Phi(w) / n``), the search's counts and time."""
    t0 = time.perf_counter()
    approx = api.certified_design(problem, collision=True, seed=task.seed)
    return dict(
        bound_mm2=approx.dual / approx.g_max / task.n,
        dual_mm2=float(approx.dual),
        g_max=float(approx.g_max),
        Y=np.asarray(approx.Y).tolist(),
        approximate_mm2=float(approx.phi) / task.n,
        dual_gap=1.0 - approx.dual / approx.g_max / approx.phi,
        rounds=int(approx.rounds),
        converged=bool(approx.converged),
        n_candidates=int(len(approx.q) + approx.n_checked),
        n_local_searches=int(approx.n_searched),
        solve_s=time.perf_counter() - t0,
    )


def _variant_of(row: Mapping) -> str:
    """The variant of a result row (rows and files written before variants existed: the default)."""
    v = row.get("variant")
    return v if isinstance(v, str) and v else DEFAULT


def is_notional(robot: str) -> bool:
    """Whether ``robot`` names one of the 90 notional robots (``notional-<lambda>-<mu>``)."""
    return _NOTIONAL.match(robot) is not None


def notional_lambda_mu(robot: str) -> tuple[float, float]:
    """(lambda, mu) [mm] of a notional robot name, NaNs for other robots."""
    m = _NOTIONAL.match(robot)
    return (float(m.group(1)), float(m.group(2))) if m else (math.nan, math.nan)


def study_robots(quick: bool) -> list[str]:
    """KUKA robots then the notional ones (all 90, or the quick six)."""
    if quick:
        return list(KUKA) + list(QUICK_NOTIONAL)
    notional = sorted((r for r in list_robots() if is_notional(r)), key=notional_lambda_mu)
    return list(KUKA) + notional


def make_tasks(
    robots: Iterable[str],
    *,
    n: int = 60,
    heuristic_draws: int = 10,
    seed: int = 0,
    variant: str = DEFAULT,
    no_ca: bool = True,
) -> list[Task]:
    """Per robot: kpi and param designs with (and, with ``no_ca``, without) collision avoidance
    (optimiser seed ``seed``), then ``heuristic_draws`` heuristic designs (seeds seed, seed+1, ...;
    feasible poses), all of the problem ``variant``."""
    cas = (True, False) if no_ca else (True,)
    tasks = []
    for r in robots:
        for method in ("kpi", "param"):
            tasks += [Task(r, method, ca, seed, n, variant) for ca in cas]
        tasks += [Task(r, "heuristic", True, seed + k, n, variant) for k in range(heuristic_draws)]
    return tasks


_CACHE: dict[tuple[str, str], tuple[Problem, FeasibilityChecker]] = {}


def _problem_and_checker(robot: str, variant: str = DEFAULT) -> tuple[Problem, FeasibilityChecker]:
    """The problem and the checker of a robot under a variant, built once per process."""
    if (robot, variant) not in _CACHE:
        p = variant_problem(robot, variant)
        _CACHE[robot, variant] = (p, FeasibilityChecker(p.robot, p.cell))
    return _CACHE[robot, variant]


def _design_api(design_api):
    if design_api is None:
        return design
    if isinstance(design_api, str):
        return importlib.import_module(design_api)
    return design_api


def _start_options(api, problem: Problem, task: Task) -> dict:
    """The start keywords of the task's optimisation: ``start`` from :data:`STUDY_STARTS` if the
    optimiser takes it (a stand-in may not), and for the approximate start with collision avoidance
    the certified approximate design (``api.certified_design``: the robot's bound task computes and
    caches it), as ``kpioed design`` passes it. Without collision avoidance the optimiser makes its
    own cheaper approximate design (no bound is paid for there)."""
    params = inspect.signature(api.optimize_design).parameters
    any_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    if not ("start" in params or any_kw):
        return {}
    out = {"start": STUDY_STARTS[task.method]}
    takes_approx = ("approx" in params or any_kw) and hasattr(api, "certified_design")
    if out["start"] == "approximate" and task.collision and takes_approx:
        out["approx"] = api.certified_design(problem, collision=task.collision, seed=task.seed)
    return out


def _make_design(api, problem: Problem, task: Task) -> tuple[np.ndarray, float, dict]:
    """The poses q: (n, 6) [rad], the solve time [s] and the solver fields of the row."""
    t0 = time.perf_counter()
    if task.method == "heuristic":
        q = np.asarray(api.heuristic_design(problem, n=task.n, seed=task.seed, collision=task.collision))
        info = dict(
            solver="heuristic",
            status="drawn",
            success=True,
            n_evals=0,
            design_feasible=True,
            all_rows_retry=False,
        )
        return q, time.perf_counter() - t0, info
    res = api.optimize_design(
        problem,
        criterion=task.method,
        n=task.n,
        collision=task.collision,
        seed=task.seed,
        allow_infeasible=True,
        **_start_options(api, problem, task),
    )
    solve_s = float(getattr(res, "solve_s", time.perf_counter() - t0))
    info = dict(
        solver=str(res.solver),
        status=str(res.status),
        success=bool(res.success),
        n_evals=int(res.n_evals or 0),
        design_feasible=bool(res.feasible),
        all_rows_retry=bool(getattr(res, "all_rows_retries", 0)),
    )
    return np.asarray(res.q), solve_s, info


def run_task(task: Task | BoundTask, design_api: str | object | None = None) -> dict:
    """Make, evaluate and check one design (or compute a :class:`BoundTask`'s bound).

    Args:
        task: the design to make, or a bound to compute (the row then has the fields of
            :func:`_run_bound` instead of the design's).
        design_api: object or module name with ``heuristic_design`` and ``optimize_design`` (the API of
            :mod:`kpioed_drake.design`, the default); tests inject a stand-in.

    Returns:
        a JSON-able row: task fields (the method under ``criterion``), ``kpi_avg_var_mm2`` [mm^2],
        ``param_crit``, checker counts, solver fields, ``solve_s`` [s], ``q_deg`` (n x 6) [deg] and
        ``error`` (None or the message; then also ``traceback``).
    """
    row = {
        "task_id": task.task_id,
        "robot": task.robot,
        "criterion": task.method,
        "collision_avoidance": task.collision,
        "seed": task.seed,
        "n": task.n,
        "variant": task.variant,
        "error": None,
    }
    try:
        api = _design_api(design_api)
        problem, checker = _problem_and_checker(task.robot, task.variant)
        if isinstance(task, BoundTask):
            row.update(_run_bound(api, problem, task))
            return row
        q, solve_s, info = _make_design(api, problem, task)
        raise_if_interrupted()
        crit = problem.criteria(q)
        reports = checker.check(q, collision=True)
        n_col = sum(any(f["check"] in ("collision", "beam") for f in r.failures) for r in reports)
        n_inf = sum(not r.feasible for r in reports)
        n_other = sum(any(f["check"] in ("joint_limit", "incidence") for f in r.failures) for r in reports)
        row.update(
            kpi_avg_var_mm2=crit["kpi_avg_var_mm2"],
            param_crit=crit["param_crit"],
            q_work_deg=",".join(f"{v:.4f}" for v in np.rad2deg(problem.q_work)),
            n_poses=len(q),
            n_colliding_poses=n_col,
            n_infeasible_poses=n_inf,
            n_limit_or_incidence_poses=n_other,
            # feasible: every pose passes the independent checker, collisions included
            feasible=n_inf == 0,
            solve_s=solve_s,
            **info,
            q_deg=np.rad2deg(q).tolist(),
        )
    except Exception as exc:  # recorded, the study goes on; retried on the next run
        raise_if_interrupted()  # a Ctrl-C that the solver turned into a failure stops the study
        row.update(
            kpi_avg_var_mm2=math.nan,
            param_crit=math.nan,
            feasible=False,
            status="error",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(limit=5),
        )
    return row
