"""The problem variants of the sensitivity study (kpioed_drake.study.variants) and a study run with one."""

from __future__ import annotations

import types

import numpy as np
import pandas as pd
import pytest

from kpioed_drake import api, study
from kpioed_drake.cli import build_parser
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.study.sensitivity import sensitivity_table, sensitivity_tasks
from kpioed_drake.study.tasks import _problem_and_checker


def _poses(problem, n=40, seed=3):
    rng = np.random.default_rng(seed)
    return rng.uniform(problem.robot.lower, problem.robot.upper, size=(n, 6))


@pytest.mark.parametrize("robot", ["kr16", "notional-850-800"])
def test_default_variant_is_todays_problem(robot):
    base, var = make_problem(robot), study.variant_problem(robot)
    assert np.array_equal(var.free, base.free) and var.param_names == base.param_names
    assert var.cell.max_incidence == base.cell.max_incidence
    assert np.array_equal(var.q_work, base.q_work) and np.array_equal(var.tool_offset, base.tool_offset)
    assert np.array_equal(var.scale, base.scale) and np.array_equal(var.model.p, base.model.p)
    q = _poses(base)
    assert var.criteria(q) == base.criteria(q)  # bit for bit
    assert study.get_variant(study.DEFAULT) is study.VARIANTS["default"]


def test_each_variant_changes_what_it_says():
    base = make_problem("kr16")
    q = _poses(base)
    crit = base.criteria(q)
    off = study.variant_problem("kr16", "offsets")
    assert off.n_params == 13 and base.n_params == 27
    assert [n for n in off.param_names if not n.startswith(("tracker", "reflector"))] == list(
        study.variants.JOINT_OFFSETS
    )
    inc = study.variant_problem("kr16", "incidence60")
    assert inc.cell.max_incidence == pytest.approx(
        np.deg2rad(60.0)
    ) and base.cell.max_incidence == pytest.approx(np.deg2rad(30.0))
    assert inc.criteria(q) == crit  # the limit changes the feasible poses, not the covariance
    _, checker = _problem_and_checker("kr16", "incidence60")
    assert checker.cell.max_incidence == inc.cell.max_incidence
    uns = study.variant_problem("kr16", "unscaled")
    assert np.all(uns.scale == 1.0) and np.any(base.scale > 1.0)
    assert uns.criteria(q)["kpi_avg_var_mm2"] == crit["kpi_avg_var_mm2"]
    assert uns.criteria(q)["param_crit"] < crit["param_crit"]
    tool = study.variant_problem("kr16", "tool")
    assert np.allclose(tool.tool_offset, -base.cell.p_FQ, atol=1e-9)  # the flange origin, Table 3
    assert tool.criteria(q)["kpi_avg_var_mm2"] > crit["kpi_avg_var_mm2"]
    flange = study.variant_problem("kr16", "flange")
    assert flange.kpi_point == "flange" and np.all(flange.tool_offset == 0)
    refl = flange.model.layout.free_target()
    assert np.all(flange.Js()[:, refl] == 0)  # the flange origin does not move with the reflector offset
    # the same point as `tool`: equal columns but the reflector's, which for `tool` are a rotation
    other = np.setdiff1d(np.arange(flange.n_params), refl)
    assert np.allclose(flange.Js()[:, other], tool.Js()[:, other])
    J_r = tool.Js()[:, refl]
    assert np.allclose(J_r.T @ J_r, np.eye(3))
    wrist = study.variant_problem("kr16", "pose-wrist")
    assert np.allclose(np.rad2deg(wrist.q_work - base.q_work), [0, 0, 0, 0, 60, 0])
    assert wrist.criteria(q)["kpi_avg_var_mm2"] != crit["kpi_avg_var_mm2"]
    # turning joint 1 (in the gauge) rotates Cs: its trace stays
    side = study.variant_problem("kr16", "pose-side")
    assert np.rad2deg(side.q_work[0] - base.q_work[0]) == pytest.approx(-90.0)
    assert side.criteria(q)["kpi_avg_var_mm2"] == pytest.approx(crit["kpi_avg_var_mm2"], rel=1e-9)


def test_combined_variant_makes_both_changes():
    both = study.variant_problem("kr16", "tool+offsets")
    assert both.n_params == 13 and np.any(both.tool_offset != 0)
    assert study.get_variant("tool+offsets").description.count(";") == 1
    closest = study.get_variant(study.variants.CLOSEST)
    assert closest.name in study.VARIANTS


@pytest.mark.parametrize("name", ["nope", "", "tool+nope", "tool+tool", None])
def test_unknown_or_conflicting_variant_is_input_error(name):
    with pytest.raises(InputError, match="^variant"):
        study.get_variant(name)


def test_bad_problem_options_are_input_errors():
    with pytest.raises(InputError, match="max_incidence_deg"):
        make_problem("kr16", max_incidence_deg=95.0)
    with pytest.raises(InputError, match="param_scaling"):
        make_problem("kr16", param_scaling="degrees")
    with pytest.raises(InputError, match="kpi_point"):
        make_problem("kr16", kpi_point="elbow")
    with pytest.raises(InputError, match="no tool offset"):
        make_problem("kr16", kpi_point="flange", tool_offset_mm=(0, 0, 10))
    with pytest.raises(InputError, match="fixed parameters not in the model"):
        make_problem("kr16", fixed=("theta9",))


class _Stub:
    """Stand-in for kpioed_drake.design: random poses from the joint box (cheap, deterministic)."""

    @staticmethod
    def heuristic_design(problem, *, n=60, seed=0, collision=True):
        return _poses(problem, n=n, seed=seed)

    @staticmethod
    def optimize_design(problem, *, criterion="kpi", n=60, collision=True, seed=0, allow_infeasible=False):
        q = _poses(problem, n=n, seed=100 + seed + (criterion == "kpi"))
        return types.SimpleNamespace(
            q=q, feasible=True, solver="stub", status="stub", success=True, n_evals=0
        )


def test_study_with_a_variant_writes_separate_task_files(tmp_path):
    kw = dict(
        robots=["kr16"], n=30, heuristic_draws=1, jobs=1, progress=False, figures=False, design_api=_Stub
    )
    var = study.run_study(tmp_path, variant="incidence60", **kw)
    default = study.run_study(tmp_path, **kw)
    assert (var.n_run, default.n_run, default.n_skipped) == (5, 5, 0)  # nothing shared
    files = sorted(p.name for p in (tmp_path / "tasks").glob("*.json"))
    assert len(files) == 10 and sum(f.endswith("_vincidence60.json") for f in files) == 5
    assert len(list((tmp_path / "designs").glob("*_vincidence60.csv"))) == 5
    assert set(var.results["variant"]) == {"incidence60"} and set(default.results["variant"]) == {"default"}
    assert "variant `incidence60`" in var.report and "variant" not in default.report.splitlines()[0]
    # results.csv of the last run holds its own variant's tasks only, and they parse back
    rows = pd.read_csv(tmp_path / "results.csv")
    assert [study.Task.from_row(r) for _, r in rows.iterrows()] == study.make_tasks(
        ["kr16"], n=30, heuristic_draws=1
    )
    again = study.run_study(tmp_path, variant="incidence60", **kw)
    assert (again.n_run, again.n_skipped) == (0, 5)
    assert again.results["kpi_avg_var_mm2"].tolist() == var.results["kpi_avg_var_mm2"].tolist()


def test_sensitivity_tasks_and_table():
    tasks = sensitivity_tasks("tool", heuristic_draws=2)
    assert len(tasks) == 3 * 4 and all(t.collision and t.variant == "tool" for t in tasks)
    rows = [
        dict(
            task_id=t.task_id,
            robot=t.robot,
            criterion=t.method,
            collision_avoidance=True,
            seed=t.seed,
            n=t.n,
            variant=t.variant,
            kpi_avg_var_mm2={"heuristic": 0.5 + 0.1 * t.seed, "param": 0.4, "kpi": 0.3}[t.method],
            feasible=True,
            error=None,
        )
        for t in tasks
    ]
    table = sensitivity_table(rows)
    assert list(table["robot"]) == list(study.KUKA)
    r = table.iloc[0]
    assert r["heuristic"] == pytest.approx(0.55) and r["gain_vs_heuristic"] == pytest.approx(1 - 0.3 / 0.55)
    assert r["gain_vs_param"] == pytest.approx(0.25) and r["paper_gain_vs_heuristic"] == pytest.approx(
        1 - 0.33 / 0.59
    )
    with pytest.raises(InputError):
        sensitivity_tasks("nope")


def test_cli_and_api_take_the_variant(tmp_path):
    a = build_parser().parse_args(["study", "--out", "x", "--variant", "tool"])
    assert a.variant == "tool"
    assert build_parser().parse_args(["study", "--out", "x"]).variant == study.DEFAULT
    with pytest.raises(InputError, match="^variant"):
        api.study(tmp_path / "s", robots=["kr16"], variant="nope", progress=False)
