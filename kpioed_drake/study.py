"""The paper's studies (Tables 6, 7, 8; Figures 7, 8): many independent design tasks, run in parallel.

A study is a list of :class:`Task` (robot x criterion x collision avoidance [x seed]); each task makes
one design with :mod:`kpioed_drake.design`, evaluates it (``problem.criteria``) and checks it with the
independent Drake checker (:class:`~kpioed_drake.feasibility.FeasibilityChecker`, collisions always
checked, so a design made without collision avoidance reports its colliding poses). Each finished task
is written at once and atomically to ``DIR/tasks/<task_id>.json`` and ``DIR/designs/<...>.csv``; a
study started again skips the tasks whose result file exists, so a killed study resumes and gives the
same tables. Tasks run on local processes (``jobs``) or on a Dask cluster (``scheduler``).

The paper's numbers are kept in :data:`PAPER` (one place; source named there).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import time
import traceback
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake import designio
from kpioed_drake.errors import InputError
from kpioed_drake.models import list_robots

KUKA = ("kr16", "kr300", "kr500")
CRITERIA = ("heuristic", "param", "kpi")

# Paper numbers: Jost, Kudruss, Körkel and Walter, "A computational method for
# key-performance-indicator-based parameter identification of industrial manipulators",
# J. Math. Industry 7:7 (2017), Tables 6, 7, 8 and
# sections 3.3-4 (also /work/shared/SPEC.md "Figures to compare with"). KPI average variance
# tr(Cs)/3 [mm^2]; None = not given ("-").
PAPER = {
    "table6": {  # robot -> heuristic, phi_A(Cp) with CA, phi_A(Cs) with CA
        "kr16": {"heuristic": 0.59, "param_ca": 0.40, "kpi_ca": 0.33},  # the paper's KR 15
        "kr300": {"heuristic": 0.58, "param_ca": 0.39, "kpi_ca": 0.35},
        "kr500": {"heuristic": 0.61, "param_ca": 0.40, "kpi_ca": 0.35},
    },
    "table7": {  # cost -> min/max over the 90 notional robots
        "heuristic": {"noca_min": None, "noca_max": None, "ca_min": 0.55, "ca_max": 0.71},
        "param": {"noca_min": 0.39, "noca_max": 0.39, "ca_min": 0.42, "ca_max": 0.45},
        "kpi": {"noca_min": 0.33, "noca_max": 0.34, "ca_min": 0.34, "ca_max": 0.37},
    },
    "table8": {  # cost -> mean over the 90 notional robots
        "heuristic": {"noca_mean": None, "ca_mean": 0.61},
        "param": {"noca_mean": 0.39, "ca_mean": 0.43},
        "kpi": {"noca_mean": 0.33, "ca_mean": 0.35},
    },
    "colliding_share_noca": (0.50, 0.70),  # section 3.3.2: 50-70 % of no-CA poses collide
}

# Quick study: the three KUKA robots and six notional robots spread over the lambda-mu grid.
QUICK_NOTIONAL = (
    "notional-650-600",
    "notional-650-1000",
    "notional-1100-600",
    "notional-1100-1000",
    "notional-850-800",
    "notional-950-700",
)

_NOTIONAL = re.compile(r"^notional-(\d+)-(\d+)$")


@dataclasses.dataclass(frozen=True)
class Task:
    """One design of the study.

    Attributes:
        robot: model name.
        criterion: ``heuristic``, ``param`` or ``kpi``.
        collision: collision avoidance on (the paper's "CA") or off ("no CA").
        seed: random seed of the draw or of the optimiser's start.
        n: number of poses.
    """

    robot: str
    criterion: str
    collision: bool
    seed: int
    n: int

    @property
    def ca(self) -> str:
        return "ca" if self.collision else "noca"

    @property
    def task_id(self) -> str:
        return f"{self.robot}_{self.criterion}_{self.ca}_s{self.seed}_n{self.n}"

    @property
    def design_name(self) -> str:
        base = f"{self.robot}_{self.criterion}_{self.ca}"
        return f"{base}_s{self.seed}.csv" if self.criterion == "heuristic" else f"{base}.csv"


@dataclasses.dataclass
class StudyResult:
    """Outputs of :func:`run_study` (all also written to ``out_dir``)."""

    out_dir: Path
    results: pd.DataFrame
    table6: pd.DataFrame
    table7: pd.DataFrame
    table8: pd.DataFrame
    report: str
    figures: list
    n_tasks: int
    n_run: int
    n_skipped: int
    n_errors: int
    wall_s: float


def notional_lambda_mu(robot: str) -> tuple[float, float]:
    """(lambda, mu) [mm] of a notional robot name, NaNs for other robots."""
    m = _NOTIONAL.match(robot)
    return (float(m.group(1)), float(m.group(2))) if m else (math.nan, math.nan)


def study_robots(quick: bool) -> list[str]:
    """KUKA robots then the notional ones (all 90, or the quick six)."""
    if quick:
        return list(KUKA) + list(QUICK_NOTIONAL)
    names = list_robots()
    notional = sorted((r for r in names if _NOTIONAL.match(r)), key=notional_lambda_mu)
    return list(KUKA) + notional


def make_tasks(robots: Iterable[str], *, n: int = 60, heuristic_draws: int = 10, seed: int = 0) -> list[Task]:
    """Per robot: ``heuristic_draws`` heuristic designs (seeds seed, seed+1, ...; feasible poses),
    then param and kpi designs with and without collision avoidance (optimiser seed ``seed``)."""
    tasks = []
    for r in robots:
        for c in ("kpi", "param"):
            for ca in (True, False):
                tasks.append(Task(r, c, ca, seed, n))
        tasks += [Task(r, "heuristic", True, seed + k, n) for k in range(heuristic_draws)]
    return tasks


# ---------------------------------------------------------------------------------------------
# one task (runs in a worker process, a Dask worker or inline)

_CACHE: dict = {}


def _problem_and_checker(robot: str):
    if robot not in _CACHE:
        from kpioed_drake.feasibility import FeasibilityChecker
        from kpioed_drake.problem import make_problem

        p = make_problem(robot)
        _CACHE[robot] = (p, FeasibilityChecker(p.robot, p.cell))
    return _CACHE[robot]


def _design_api(design_api):
    if design_api is None:
        from kpioed_drake import design

        return design
    if isinstance(design_api, str):
        import importlib

        return importlib.import_module(design_api)
    return design_api


def run_task(task: Task, design_api=None) -> dict:
    """Make, evaluate and check one design.

    Args:
        design_api: object or module name with ``heuristic_design`` and ``optimize_design`` (the API of
            :mod:`kpioed_drake.design`, the default); tests inject a stand-in.

    Returns:
        a JSON-able row: task fields, criteria, checker counts, solver status, ``q_deg`` (n x 6) and
        ``error`` (None or the message).
    """
    row = {
        "task_id": task.task_id,
        "robot": task.robot,
        "criterion": task.criterion,
        "collision_avoidance": task.collision,
        "seed": task.seed,
        "n": task.n,
        "error": None,
    }
    try:
        api = _design_api(design_api)
        problem, checker = _problem_and_checker(task.robot)
        t0 = time.perf_counter()
        if task.criterion == "heuristic":
            q = np.asarray(api.heuristic_design(problem, n=task.n, seed=task.seed, collision=task.collision))
            solve_s = time.perf_counter() - t0
            info = dict(
                solver="heuristic",
                status="drawn",
                success=True,
                n_evals=0,
                design_feasible=True,
                all_rows_retry=False,
            )
        else:
            res = api.optimize_design(
                problem,
                criterion=task.criterion,
                n=task.n,
                collision=task.collision,
                seed=task.seed,
                allow_infeasible=True,
            )
            q = np.asarray(res.q)
            solve_s = float(getattr(res, "solve_s", time.perf_counter() - t0))
            info = dict(
                solver=str(res.solver),
                status=str(res.status),
                success=bool(res.success),
                n_evals=int(res.n_evals or 0),
                design_feasible=bool(res.feasible),
                all_rows_retry=bool(getattr(res, "all_rows_retries", 0)),
            )
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
        row.update(
            kpi_avg_var_mm2=math.nan,
            param_crit=math.nan,
            feasible=False,
            status="error",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(limit=5),
        )
    return row


# ---------------------------------------------------------------------------------------------
# running many tasks


def _task_path(out_dir: Path, task: Task) -> Path:
    return out_dir / "tasks" / f"{task.task_id}.json"


def _load_done(out_dir: Path, task: Task) -> dict | None:
    p = _task_path(out_dir, task)
    if not p.is_file():
        return None
    try:
        row = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return None if row.get("error") else row


def _save(out_dir: Path, task: Task, row: dict) -> None:
    if not row.get("error"):
        designio.write_design(out_dir / "designs" / task.design_name, np.deg2rad(np.asarray(row["q_deg"])))
    designio.atomic_write_json(_task_path(out_dir, task), row)


def _execute(todo: list[Task], *, jobs: int, scheduler, design_api, on_done: Callable) -> None:
    if not todo:
        return
    if scheduler is not None:
        from distributed import Client, as_completed

        client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
        try:
            futs = {
                client.submit(run_task, t, design_api, pure=False, key=f"kpioed-{t.task_id}"): t for t in todo
            }
            for fut in as_completed(futs):
                on_done(futs[fut], fut.result())
        finally:
            if client is not scheduler:
                client.close()
        return
    if jobs <= 1:
        for t in todo:
            on_done(t, run_task(t, design_api))
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # one BLAS/OpenMP thread per worker process: the matrices are small and the workers fill the CPUs
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")

    with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as ex:
        futs = {ex.submit(run_task, t, design_api): t for t in todo}
        try:
            for fut in as_completed(futs):
                on_done(futs[fut], fut.result())
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def run_tasks(
    tasks: list[Task],
    out_dir: str | Path,
    *,
    jobs: int | None = None,
    scheduler=None,
    progress: bool = True,
    design_api=None,
) -> tuple[list[dict], int, int]:
    """Run the tasks whose result file is missing (or recorded an error); return all rows in task order,
    the number run and the number skipped."""
    out_dir = Path(out_dir)
    rows: dict[str, dict] = {}
    todo = []
    for t in tasks:
        done = _load_done(out_dir, t)
        if done is None:
            todo.append(t)
        else:
            rows[t.task_id] = done
    # the optimisations first: they are the long tasks
    todo.sort(key=lambda t: t.criterion == "heuristic")
    bar = None
    if progress and todo:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(todo), desc="study tasks", unit="task", smoothing=0.05)

    def on_done(task: Task, row: dict) -> None:
        _save(out_dir, task, row)
        rows[task.task_id] = row
        if bar is not None:
            bar.update(1)
            if row.get("error"):
                bar.write(f"{task.task_id}: {row['error']}")

    try:
        _execute(
            todo,
            jobs=jobs or os.cpu_count() or 1,
            scheduler=scheduler,
            design_api=design_api,
            on_done=on_done,
        )
    finally:
        if bar is not None:
            bar.close()
    return [rows[t.task_id] for t in tasks], len(todo), len(tasks) - len(todo)


# ---------------------------------------------------------------------------------------------
# tables

RESULT_COLUMNS = [
    "robot",
    "lambda_mm",
    "mu_mm",
    "criterion",
    "collision_avoidance",
    "seed",
    "n",
    "kpi_avg_var_mm2",
    "param_crit",
    "n_colliding_poses",
    "n_infeasible_poses",
    "n_limit_or_incidence_poses",
    "feasible",
    "design_feasible",
    "solve_s",
    "solver",
    "status",
    "success",
    "n_evals",
    "all_rows_retry",
    "q_work_deg",
    "error",
]


def results_frame(rows: list[dict]) -> pd.DataFrame:
    df = pd.DataFrame([{k: v for k, v in r.items() if k not in ("q_deg", "traceback")} for r in rows])
    lm = [notional_lambda_mu(r) for r in df["robot"]]
    df["lambda_mm"] = [a for a, _ in lm]
    df["mu_mm"] = [b for _, b in lm]
    for c in RESULT_COLUMNS:
        if c not in df:
            df[c] = None
    return df[RESULT_COLUMNS]


def per_robot(df: pd.DataFrame) -> pd.DataFrame:
    """One row per robot: heuristic (mean, std and count over draws), param/kpi with and without CA,
    the share of colliding poses of the no-CA designs."""
    ok = df[df["error"].isna()]
    out = {}
    for robot, g in ok.groupby("robot", sort=False):
        h = g[g["criterion"] == "heuristic"]["kpi_avg_var_mm2"]
        d = {
            "heuristic": h.mean(),
            "heuristic_std": h.std(ddof=1) if len(h) > 1 else math.nan,
            "heuristic_draws": len(h),
        }
        for c in ("param", "kpi"):
            for ca in (True, False):
                s = g[(g["criterion"] == c) & (g["collision_avoidance"] == ca)]
                key = f"{c}_{'ca' if ca else 'noca'}"
                d[key] = s["kpi_avg_var_mm2"].iloc[0] if len(s) else math.nan
                if not ca:
                    d[f"{key}_colliding_share"] = (
                        s["n_colliding_poses"].iloc[0] / s["n"].iloc[0] if len(s) else math.nan
                    )
                else:
                    d[f"{key}_feasible"] = bool(s["feasible"].iloc[0]) if len(s) else False
        d["lambda_mm"], d["mu_mm"] = notional_lambda_mu(robot)
        out[robot] = d
    pr = pd.DataFrame.from_dict(out, orient="index")
    pr.index.name = "robot"
    return pr


def _paper(v):
    return math.nan if v is None else v


def make_tables(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Tables 6, 7, 8 (with the paper's numbers beside ours) and the per-robot table."""
    pr = per_robot(df)
    kuka = [r for r in KUKA if r in pr.index]
    t6 = pr.loc[kuka, ["heuristic", "heuristic_std", "param_ca", "kpi_ca"]].copy()
    for c in ("heuristic", "param_ca", "kpi_ca"):
        t6[f"paper_{c}"] = [PAPER["table6"][r][c] for r in kuka]
    t6.index.name = "robot"

    nt = pr[[bool(_NOTIONAL.match(r)) for r in pr.index]]
    t7 = {}
    t8 = {}
    for cost in CRITERIA:
        if cost == "heuristic":
            noca, ca = pd.Series(dtype=float), nt["heuristic"] if len(nt) else pd.Series(dtype=float)
        else:
            noca, ca = nt[f"{cost}_noca"], nt[f"{cost}_ca"]
        t7[cost] = {"noca_min": noca.min(), "noca_max": noca.max(), "ca_min": ca.min(), "ca_max": ca.max()}
        t8[cost] = {"noca_mean": noca.mean(), "ca_mean": ca.mean(), "n_robots": len(ca.dropna())}
        for k, v in PAPER["table7"][cost].items():
            t7[cost][f"paper_{k}"] = _paper(v)
        for k, v in PAPER["table8"][cost].items():
            t8[cost][f"paper_{k}"] = _paper(v)
    t7 = pd.DataFrame.from_dict(t7, orient="index")
    t8 = pd.DataFrame.from_dict(t8, orient="index")
    t7.index.name = t8.index.name = "cost"
    return t6, t7, t8, pr


# ---------------------------------------------------------------------------------------------
# report


def _fmt(v, f="{:.3f}"):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f.format(v)


def _md_table(df: pd.DataFrame, f="{:.3f}") -> str:
    cols = [df.index.name or ""] + list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for idx, r in df.iterrows():
        vals = []
        for col, v in zip(df.columns, r.values, strict=True):
            if isinstance(v, bool | np.bool_):
                vals.append(str(bool(v)))
            elif (
                isinstance(v, int | np.integer)
                or (str(col).startswith("n_") or str(col).endswith("_draws"))
                and isinstance(v, float)
                and np.isfinite(v)
            ):
                vals.append(str(int(v)))
            else:
                vals.append(_fmt(v, f))
        lines.append("| " + " | ".join([str(idx)] + vals) + " |")
    return "\n".join(lines)


def ratios(t6: pd.DataFrame, t8: pd.DataFrame) -> pd.DataFrame:
    """kpi/heuristic, kpi/param, param/heuristic and ca/noca: ours and the paper's."""
    rows = {}
    for robot, r in t6.iterrows():
        rows[robot] = {
            "kpi/heuristic": r["kpi_ca"] / r["heuristic"],
            "paper kpi/heuristic": r["paper_kpi_ca"] / r["paper_heuristic"],
            "kpi/param": r["kpi_ca"] / r["param_ca"],
            "paper kpi/param": r["paper_kpi_ca"] / r["paper_param_ca"],
            "param/heuristic": r["param_ca"] / r["heuristic"],
            "paper param/heuristic": r["paper_param_ca"] / r["paper_heuristic"],
        }
    if "kpi" in t8.index and np.isfinite(t8.loc["kpi", "ca_mean"]):
        h, p, k = (t8.loc[c] for c in ("heuristic", "param", "kpi"))
        rows["notional (means)"] = {
            "kpi/heuristic": k["ca_mean"] / h["ca_mean"],
            "paper kpi/heuristic": k["paper_ca_mean"] / h["paper_ca_mean"],
            "kpi/param": k["ca_mean"] / p["ca_mean"],
            "paper kpi/param": k["paper_ca_mean"] / p["paper_ca_mean"],
            "param/heuristic": p["ca_mean"] / h["ca_mean"],
            "paper param/heuristic": p["paper_ca_mean"] / h["paper_ca_mean"],
            "kpi ca/noca": k["ca_mean"] / k["noca_mean"],
            "paper kpi ca/noca": k["paper_ca_mean"] / k["paper_noca_mean"],
            "param ca/noca": p["ca_mean"] / p["noca_mean"],
            "paper param ca/noca": p["paper_ca_mean"] / p["paper_noca_mean"],
        }
    out = pd.DataFrame.from_dict(rows, orient="index")
    out.index.name = "case"
    return out


def make_report(df, t6, t7, t8, pr, *, wall_s: float | None = None, title="Study") -> str:
    lines = [f"# {title}: KPI-based OED, paper Tables 6-8", ""]
    n_rob = df["robot"].nunique()
    lines.append(
        f"{n_rob} robots, {len(df)} designs ({int(df['error'].notna().sum())} failed). Values: average KPI "
        "variance tr(Cs)/3 [mm^2], noise 1 mm per coordinate. `paper_*`: Jost, Kudruss, Körkel and "
        "Walter 2017 (kpioed_drake.study.PAPER). Heuristic: mean over the seeded draws (feasible poses only)."
    )
    if wall_s is not None:
        lines.append(f"Wall time of this run: {wall_s:.0f} s.")
    lines += ["", "## Table 6: KUKA robots (with collision avoidance)", "", _md_table(t6), ""]
    lines += ["## Table 7: notional robots, min and max", "", _md_table(t7), ""]
    lines += ["## Table 8: notional robots, mean", "", _md_table(t8), ""]
    r = ratios(t6, t8)
    lines += ["## Ratios (ours next to the paper's)", "", _md_table(r), ""]
    share = pr[[c for c in pr.columns if c.endswith("_colliding_share")]]
    if len(share):
        allv = share.to_numpy(dtype=float).ravel()
        allv = allv[np.isfinite(allv)]
        lines += ["## Colliding poses of designs made without collision avoidance", ""]
        if allv.size:
            lines.append(
                f"Share of the poses that fail the Drake checker's collision or beam test: mean "
                f"{100 * allv.mean():.0f} %, range {100 * allv.min():.0f}-{100 * allv.max():.0f} % over "
                f"{allv.size} designs (paper: {100 * PAPER['colliding_share_noca'][0]:.0f}-"
                f"{100 * PAPER['colliding_share_noca'][1]:.0f} %)."
            )
        lines += [
            "",
            _md_table(share.rename(columns=lambda c: c.replace("_colliding_share", "")), "{:.2f}"),
            "",
        ]
    ca = df[(df["collision_avoidance"] == True) & df["error"].isna()]  # noqa: E712
    bad = ca[~ca["feasible"].astype(bool)]
    lines += ["## Feasibility of the designs made with collision avoidance", ""]
    lines.append(
        f"{len(ca) - len(bad)} of {len(ca)} designs pass the independent Drake checker at every pose."
        + (
            ""
            if bad.empty
            else " Failing: "
            + ", ".join(
                f"{a} {b} {c} ({d} poses)"
                for a, b, c, d in zip(
                    bad["robot"], bad["criterion"], bad["seed"], bad["n_infeasible_poses"], strict=True
                )
            )
        )
    )
    err = df[df["error"].notna()]
    if len(err):
        lines += ["", "## Failed tasks", ""]
        lines += [
            f"- {a} {b} {'ca' if c else 'noca'} seed {d}: {e}"
            for a, b, c, d, e in zip(
                err["robot"],
                err["criterion"],
                err["collision_avoidance"],
                err["seed"],
                err["error"],
                strict=True,
            )
        ]
    st = df[df["criterion"] != "heuristic"]
    if len(st):
        lines += ["", "## Optimiser", ""]
        lines.append(
            "Status counts: "
            + ", ".join(f"{k}: {v}" for k, v in st["status"].value_counts().items())
            + f". Solve time per design: median {st['solve_s'].median():.1f} s, "
            f"max {st['solve_s'].max():.1f} s."
        )
    lines.append("")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------


def write_outputs(out_dir: Path, rows: list[dict], *, wall_s=None, figures=True, title="Study"):
    out_dir = Path(out_dir)
    df = results_frame(rows)
    t6, t7, t8, pr = make_tables(df)
    designio.atomic_write_text(out_dir / "results.csv", df.to_csv(index=False, float_format="%.6g"))
    designio.atomic_write_text(out_dir / "per_robot.csv", pr.to_csv(float_format="%.6g"))
    designio.atomic_write_text(out_dir / "table6.csv", t6.to_csv(float_format="%.6g"))
    designio.atomic_write_text(out_dir / "table7.csv", t7.to_csv(float_format="%.6g"))
    designio.atomic_write_text(out_dir / "table8.csv", t8.to_csv(float_format="%.6g"))
    report = make_report(df, t6, t7, t8, pr, wall_s=wall_s, title=title)
    figs = []
    if figures:
        from kpioed_drake import study_plots

        figs = study_plots.make_figures(out_dir, df, pr)
        if figs:
            report += "\n## Figures\n\n" + "\n".join(f"![{p.stem}]({p.name})" for p in figs) + "\n"
    designio.atomic_write_text(out_dir / "report.md", report)
    return df, t6, t7, t8, report, figs


def run_study(
    out_dir: str | Path,
    *,
    quick: bool = False,
    jobs: int | None = None,
    scheduler=None,
    progress: bool = True,
    robots: Iterable[str] | None = None,
    n: int = 60,
    heuristic_draws: int | None = None,
    seed: int = 0,
    figures: bool = True,
    design_api=None,
) -> StudyResult:
    """Run (or resume) the study and write ``results.csv``, ``table6/7/8.csv``, ``report.md`` and the
    figures into ``out_dir``.

    Args:
        quick: KUKA robots + six notional robots, 3 heuristic draws (unless given).
        jobs: local worker processes (default: the number of CPUs); 1 runs inline.
        scheduler: Dask scheduler address (or a ``distributed.Client``): the tasks go there instead.
        robots: the robots to study (default: KUKA + all 90 notional, or the quick set).
        heuristic_draws: seeded heuristic designs per robot (default 10; quick 3).
        design_api: stand-in for :mod:`kpioed_drake.design` (tests).
    """
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    if n < 1:
        raise InputError(f"n must be a positive number of poses, got {n}")
    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {jobs}")
    robots = list(robots) if robots is not None else study_robots(quick)
    known = set(list_robots())
    unknown = [r for r in robots if r not in known]
    if unknown:
        raise InputError(f"unknown robot(s): {', '.join(unknown)}")
    draws = heuristic_draws if heuristic_draws is not None else (3 if quick else 10)
    tasks = make_tasks(robots, n=n, heuristic_draws=draws, seed=seed)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, n_run, n_skip = run_tasks(
        tasks, out_dir, jobs=jobs, scheduler=scheduler, progress=progress, design_api=design_api
    )
    wall = time.perf_counter() - t0
    title = "Quick study" if quick else "Study"
    df, t6, t7, t8, report, figs = write_outputs(out_dir, rows, wall_s=wall, figures=figures, title=title)
    return StudyResult(
        out_dir,
        df,
        t6,
        t7,
        t8,
        report,
        figs,
        len(tasks),
        n_run,
        n_skip,
        int(df["error"].notna().sum()),
        time.perf_counter() - t0,
    )
