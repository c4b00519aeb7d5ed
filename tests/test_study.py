"""The study machinery (tasks, resume, process pool, Dask, tables, report, figures) with a stand-in
design function, and the paper's qualitative findings with the real optimiser."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from kpioed_drake import study
from kpioed_drake.cli import build_parser, main
from kpioed_drake.design import DESIGN_METHODS, approximate_design
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.tracker.feasibility import FeasibilityChecker
from kpioed_drake.tracker.measurement import incidence_cosine

COMMITTED = Path(__file__).resolve().parents[1] / "studies" / "results"


@dataclasses.dataclass
class _Result:
    q: np.ndarray
    feasible: bool
    solver: str = "fake"
    status: str = "fake"
    success: bool = True
    n_evals: int = 0
    solve_s: float = 0.0


class FakeDesign:
    """Stand-in for kpioed_drake.design: heuristic = feasible random poses; 'optimised' = the best of
    three heuristic draws by the criterion. Cheap and deterministic."""

    @staticmethod
    def heuristic_design(problem, *, n=60, seed=0, collision=True):
        rng = np.random.default_rng(seed)
        cm = ClearanceModel(problem.robot, problem.cell) if collision else None
        out = np.zeros((0, 6))
        while len(out) < n:
            q = rng.uniform(problem.robot.lower, problem.robot.upper, size=(2048, 6))
            ok = incidence_cosine(problem.model, q) >= np.cos(problem.cell.max_incidence)
            if cm is not None:
                ok[ok] = np.all(cm.evaluate(q[ok])[0] >= 1.0, axis=1)
            out = np.concatenate([out, q[ok]])
        return out[:n]

    @staticmethod
    def optimize_design(
        problem, *, criterion="kpi", n=60, collision=True, seed=0, allow_infeasible=False, **kw
    ):
        key = "kpi_avg_var_mm2" if criterion == "kpi" else "param_crit"
        best = min(
            (
                FakeDesign.heuristic_design(problem, n=n, seed=1000 * seed + k, collision=collision)
                for k in range(3)
            ),
            key=lambda q: problem.criteria(q)[key],
        )
        return _Result(q=best, feasible=True)

    @staticmethod
    def certified_design(problem, *, collision=True, seed=0):
        """A cheap search (one round over 300 poses): a valid, looser bound."""
        return approximate_design(problem, collision=collision, seed=seed, max_rounds=1, pool=300, starts=2,
                                  random_starts=1, first_working=300)  # fmt: skip


FAKE = FakeDesign()
ROBOTS = ["kr16", "notional-850-800"]


def _tables(d):
    return [pd.read_csv(d / f"table{k}.csv", index_col=0) for k in (6, 7, 8)]


def _check_outputs(res, robots, n, draws):
    d = res.out_dir
    for f in ("results.csv", "table6.csv", "table7.csv", "table8.csv", "report.md"):
        assert (d / f).is_file(), f
    df = pd.read_csv(d / "results.csv")
    need = [
        "robot",
        "criterion",
        "collision_avoidance",
        "seed",
        "kpi_avg_var_mm2",
        "param_crit",
        "q_work_deg",
        "n_colliding_poses",
        "feasible",
        "solve_s",
        "status",
    ]
    assert set(need) <= set(df.columns)
    assert len(df) == len(robots) * (4 + draws)
    assert df["error"].isna().all(), df["error"].dropna().tolist()
    assert len(df["q_work_deg"].iloc[0].split(",")) == 6
    t6, t7, t8 = _tables(d)
    kuka = [r for r in robots if r in study.KUKA]
    assert list(t6.index) == kuka
    assert {"heuristic", "param_ca", "kpi_ca", "paper_heuristic", "paper_param_ca", "paper_kpi_ca"} <= set(
        t6.columns
    )
    assert list(t7.index) == ["heuristic", "param", "kpi"]
    assert {"noca_min", "noca_max", "ca_min", "ca_max", "paper_ca_min"} <= set(t7.columns)
    assert {"noca_mean", "ca_mean", "paper_noca_mean", "paper_ca_mean"} <= set(t8.columns)
    assert t6.loc["kr16", "paper_kpi_ca"] == 0.33
    # designs reported feasible pass the independent checker; each design file matches its row
    for robot in robots:
        p = make_problem(robot)
        chk = FeasibilityChecker(p.robot, p.cell)
        for _, r in df[df["robot"] == robot].iterrows():
            q = read_design(d / "designs" / study.Task.from_row(r).design_name, p.robot)
            assert q.shape == (n, 6)
            assert p.criteria(q)["kpi_avg_var_mm2"] == pytest.approx(r["kpi_avg_var_mm2"], rel=1e-4)
            if r["feasible"]:
                assert all(x.feasible for x in chk.check(q))
            if r["collision_avoidance"]:
                assert r["n_colliding_poses"] == 0 or not r["feasible"]
    report = (d / "report.md").read_text()
    assert "Table 6" in report and "Ratios" in report and "kpi/heuristic" in report
    _check_efficiency(d, df, t6, t7, t8, robots)


def _check_efficiency(d, df, t6, t7, t8, robots):
    """One bound per robot; every design with collision avoidance has 0 < efficiency <= 1 and
    bound <= value (the bound covers its poses), none without; the tables carry them."""
    bounds = pd.read_csv(d / "bounds.csv")
    assert list(bounds["robot"]) == list(robots) and bounds["error"].isna().all()
    ca = df[df["collision_avoidance"]]
    assert ((ca["efficiency"] > 0) & (ca["efficiency"] <= 1)).all()
    assert (ca["bound_mm2"] <= ca["kpi_avg_var_mm2"]).all()
    assert np.allclose(ca["efficiency"], ca["bound_mm2"] / ca["kpi_avg_var_mm2"], rtol=1e-4)
    for robot, b in zip(bounds["robot"], bounds["bound_mm2"], strict=True):
        assert (ca[ca["robot"] == robot]["bound_mm2"] <= b * (1 + 1e-5)).all()
    assert df[~df["collision_avoidance"]]["efficiency"].isna().all()
    assert {"bound_mm2", "kpi_ca_efficiency", "param_ca_efficiency", "heuristic_efficiency"} <= set(
        t6.columns
    )
    assert "ca_efficiency_min" in t7.columns and "ca_efficiency_mean" in t8.columns
    assert "## Efficiency" in (d / "report.md").read_text()


@pytest.mark.slow
def test_study_machinery_fake(tmp_path):
    res = study.run_study(
        tmp_path, robots=ROBOTS, n=30, heuristic_draws=2, jobs=1, progress=False, design_api=FAKE
    )
    assert (res.n_tasks, res.n_run, res.n_skipped, res.n_errors) == (14, 14, 0, 0)
    _check_outputs(res, ROBOTS, 30, 2)
    assert {p.name for p in res.figures} == {"figure7_kr16.png", "figure8_notional.png"}
    assert len(list((tmp_path / "tasks").glob("*.json"))) == 14  # 12 designs, 2 bounds
    # one design file per task, and each row names its own task
    assert len(list((tmp_path / "designs").glob("*.csv"))) == 12
    tasks = study.make_tasks(ROBOTS, n=30, heuristic_draws=2)
    assert [study.Task.from_row(r) for _, r in res.results.iterrows()] == tasks
    # a second run resumes everything and changes nothing
    before = _tables(tmp_path)
    res2 = study.run_study(
        tmp_path,
        robots=ROBOTS,
        n=30,
        heuristic_draws=2,
        jobs=1,
        progress=False,
        design_api=FAKE,
        figures=False,
    )
    assert (res2.n_run, res2.n_skipped) == (0, 14)
    for a, b in zip(before, _tables(tmp_path), strict=True):
        pd.testing.assert_frame_equal(a, b)
    # the tables rebuilt from results.csv and designs/ alone (bounds computed again) are the same
    again = tmp_path / "again"
    again.mkdir()
    for name in ("results.csv", "report.md"):
        (again / name).write_text((tmp_path / name).read_text())
    (again / "designs").mkdir()
    for f in (tmp_path / "designs").glob("*.csv"):
        (again / "designs" / f.name).write_text(f.read_text())
    res3 = study.regenerate_tables(again, jobs=1, progress=False, design_api=FAKE, figures=False)
    assert (res3.n_tasks, res3.n_run, res3.n_errors) == (2, 2, 0)
    for a, b in zip(before, _tables(again), strict=True):
        pd.testing.assert_frame_equal(a, b)
    cols = ["robot", "criterion", "seed", "kpi_avg_var_mm2", "bound_mm2", "efficiency"]
    pd.testing.assert_frame_equal(res.results[cols], res3.results[cols], rtol=1e-5)
    with pytest.raises(InputError, match="results.csv"):
        study.regenerate_tables(tmp_path / "none", progress=False, design_api=FAKE)
    (again / "designs" / "kr16_kpi_ca.csv").unlink()
    with pytest.raises(InputError, match="kr16_kpi_ca.csv"):
        study.regenerate_tables(again, progress=False, design_api=FAKE)


def test_study_resume_after_interrupt_gives_same_tables(tmp_path):
    """An interrupted study (only some task files written) resumed = a study run in one go."""
    kw = dict(robots=ROBOTS, n=30, heuristic_draws=2, progress=False, design_api=FAKE, figures=False)
    full = study.run_study(tmp_path / "full", jobs=1, **kw)
    tasks = study.make_tasks(ROBOTS, n=30, heuristic_draws=2)
    study.run_tasks(tasks[::3], tmp_path / "part", jobs=1, progress=False, design_api=FAKE)
    # a half-written temporary file and a failed task are redone, not read
    (tmp_path / "part" / "tasks" / ".junk.json.tmp").write_text("{")
    failed = tasks[1]
    (tmp_path / "part" / "tasks" / f"{failed.task_id}.json").write_text(json.dumps({"error": "boom"}))
    resumed = study.run_study(tmp_path / "part", jobs=1, **kw)
    n_bounds = len(ROBOTS)
    assert resumed.n_skipped == len(tasks[::3]) and resumed.n_run == len(tasks) + n_bounds - len(tasks[::3])
    for a, b in zip(_tables(tmp_path / "full"), _tables(tmp_path / "part"), strict=True):
        pd.testing.assert_frame_equal(a, b)
    pd.testing.assert_frame_equal(
        full.results.drop(columns=["solve_s"]), resumed.results.drop(columns=["solve_s"])
    )


@pytest.mark.slow
def test_study_process_pool_same_numbers(tmp_path):
    kw = dict(n=30, heuristic_draws=2, progress=False, design_api=FAKE, figures=False, robots=["kr16"])
    a = study.run_study(tmp_path / "a", jobs=2, **kw)
    study.run_study(tmp_path / "b", jobs=1, **kw)
    for x, y in zip(_tables(tmp_path / "a"), _tables(tmp_path / "b"), strict=True):
        pd.testing.assert_frame_equal(x, y)
    assert a.n_errors == 0


def test_study_dask_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    tasks = study.make_tasks(["kr16"], n=30, heuristic_draws=2)
    tasks = [t for t in tasks if t.method == "heuristic"] + tasks[:1]
    with distributed.LocalCluster(
        n_workers=2,
        processes=False,
        protocol="tcp://",
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address=":0",
    ) as cluster:
        rows, n_run, n_skip = study.run_tasks(
            tasks, tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False, design_api=FAKE
        )
    local, _, _ = study.run_tasks(tasks, tmp_path / "local", jobs=1, progress=False, design_api=FAKE)
    assert (n_run, n_skip) == (3, 0)
    assert [r["kpi_avg_var_mm2"] for r in rows] == [r["kpi_avg_var_mm2"] for r in local]
    assert all(r["error"] is None for r in rows)
    assert len(list((tmp_path / "dask" / "tasks").glob("*.json"))) == 3


def test_study_cli_parser():
    a = build_parser().parse_args(["study", "--quick", "--jobs", "2", "--out", "x"])
    assert (
        a.quick
        and a.jobs == 2
        and a.out == "x"
        and a.scheduler is None
        and a.func.__module__.endswith("study")
    )


def test_study_bad_input(tmp_path):
    with pytest.raises(InputError, match="unknown robot"):
        study.run_study(tmp_path, robots=["kr17"], progress=False, design_api=FAKE)


def test_quick_robots_exist():
    names = set(study.study_robots(False))
    assert len(names) == 93 and set(study.study_robots(True)) <= names


def test_study_methods_are_design_methods():
    """The study's methods are design methods, in the row order of Tables 7 and 8."""
    assert set(study.METHODS) <= set(DESIGN_METHODS)
    assert {t.method for t in study.make_tasks(["kr16"])} == set(study.METHODS)


def test_task_names_unique_and_match_the_committed_study():
    """Task ids and design names are unique over the full study, the design names are the files the
    full study wrote, and every committed result row parses back to its task."""
    tasks = study.make_tasks(study.study_robots(False))
    assert len({t.task_id for t in tasks}) == len(tasks) == 93 * 14
    names = [t.design_name for t in tasks]
    assert len(set(names)) == len(tasks)
    assert set(names) == {p.name for p in (COMMITTED / "designs").glob("*.csv")}
    rows = pd.read_csv(COMMITTED / "results.csv")
    assert [study.Task.from_row(r) for _, r in rows.iterrows()] == tasks
    # the quick study's tasks are the full study's (a full study in the same folder reuses them)
    assert set(study.make_tasks(study.study_robots(True), heuristic_draws=3)) <= set(tasks)


# ------------------------------------------------------------------------------------------------
# the paper's qualitative findings, with the real optimiser


def _assert_findings(res):
    pr = study.per_robot(res.results)
    msgs = []
    for robot, r in pr.iterrows():
        # Table 6 / 8 ordering with collision avoidance: kpi < param < heuristic
        assert r["kpi_ca"] < r["param_ca"] < r["heuristic"], (robot, r[["kpi_ca", "param_ca", "heuristic"]])
        # dropping the collision constraints cannot hurt, up to the optimiser's local optimum
        for c in ("kpi", "param"):
            if r[f"{c}_noca"] > r[f"{c}_ca"]:
                msgs.append(f"{robot} {c}: noca {r[f'{c}_noca']:.4f} > ca {r[f'{c}_ca']:.4f}")
            assert r[f"{c}_noca"] <= 1.05 * r[f"{c}_ca"], (robot, c)
    df = res.results
    ca = df[df["collision_avoidance"] == True]  # noqa: E712
    assert ca["error"].isna().all()
    # CA designs the optimiser reports feasible pass the independent Drake checker (run_task's
    # `feasible`); re-check from the written design files
    claimed = ca[ca["design_feasible"].astype(bool)]
    assert claimed["feasible"].astype(bool).all(), claimed[~claimed["feasible"].astype(bool)]
    for robot in pr.index:
        p = make_problem(robot)
        chk = FeasibilityChecker(p.robot, p.cell)
        for _, r in claimed[claimed["robot"] == robot].iterrows():
            q = read_design(res.out_dir / "designs" / study.Task.from_row(r).design_name, p.robot)
            assert all(x.feasible for x in chk.check(q))
    # the heuristic draws are feasible by construction; an optimised CA design the optimiser did not
    # call feasible (e.g. SNOPT's iteration limit) is reported, not hidden
    assert ca[ca["criterion"] == "heuristic"]["feasible"].astype(bool).all()
    for _, r in ca[~ca["feasible"].astype(bool)].iterrows():
        msgs.append(f"{r['robot']} {r['criterion']} CA: {r['n_infeasible_poses']} poses fail ({r['status']})")
    return msgs


@pytest.mark.slow
def test_study_reduced_paper_findings(tmp_path):
    t0 = time.perf_counter()
    res = study.run_study(
        tmp_path, robots=ROBOTS, n=30, heuristic_draws=2, jobs=os.cpu_count(), progress=False
    )
    msgs = _assert_findings(res)
    # the real bounds: every design with collision avoidance below 1, the KPI designs the most efficient
    pr = study.per_robot(res.results)
    eff = pr[["heuristic_efficiency", "param_ca_efficiency", "kpi_ca_efficiency"]]
    assert ((eff > 0) & (eff <= 1)).all().all()
    assert (pr["kpi_ca_efficiency"] > pr["param_ca_efficiency"]).all()
    assert (pr["param_ca_efficiency"] > pr["heuristic_efficiency"]).all()
    print(f"reduced study: {time.perf_counter() - t0:.0f} s", *msgs, eff.to_string(), sep="\n")


@pytest.mark.slow
def test_quick_study(tmp_path):
    t0 = time.perf_counter()
    res = study.run_study(tmp_path, quick=True, progress=False)
    wall = time.perf_counter() - t0
    _check_outputs(res, study.study_robots(True), 60, 3)
    msgs = _assert_findings(res)
    print(f"quick study: {wall:.0f} s", *msgs, sep="\n")


def test_tables_only_on_a_folder_without_a_study_is_an_input_error(tmp_path, capsys):
    code = main(["study", "--out", str(tmp_path / "none"), "--tables-only", "--no-progress"])
    assert code == 2 and "results.csv" in capsys.readouterr().err
    assert not (tmp_path / "none").exists()
