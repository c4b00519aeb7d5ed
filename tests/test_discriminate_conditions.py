"""Measurement plans for explanations that need temperature or time (issue 13 item 5):
``kpioed design --discriminate "A|B" [--condition-span SPAN]`` with ``thermal_expansion``,
``tracker_scale`` or ``tracker_drift``.

The plan's non-centrality against the projector formula on independently built rows, the
derivative of the criterion against central differences, the default span against the target
power, the span option's parsing and bad inputs, the command line's CSV and JSON, and the simulated
case (a first data set within 0.3 K cannot separate thermal expansion from the tracker's air
refraction; the plan's data names the truth).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.design.discriminate import conditions as cd
from kpioed_drake.design.discriminate import explanations as ex
from kpioed_drake.design.discriminate.design import discrimination_problem, explanation_indices
from kpioed_drake.design.discriminate.plan import plan_design
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.diagnosis.options import DiagnosisOptions
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.effects import augmented_jacobian
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import design_csv_text
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate, table_csv_text
from kpioed_drake.study.synthetic import random_poses

SIGMA = 0.02
TEMP_PAIR = "thermal_expansion|tracker_scale"


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16", sigma_mm=SIGMA)


def _first_data(problem, n: int = 40, seed: int = 0):
    """A first data set: random poses, temperature within 0.3 K, 30 s per pose."""
    rng = np.random.default_rng(seed)
    q = random_poses(problem.robot, n, rng)
    return q, {"temperature_C": 20.0 + rng.uniform(-0.15, 0.15, n), "time_s": np.arange(n) * 30.0}


def _plan(problem, text, spans, *, given=None, given_conditions=None):
    pair = ex.parse_pair(text, problem.model)
    zero = tuple(dataclasses.replace(h.effect, values=None) for h in pair)
    base = dataclasses.replace(problem, extensions=zero)
    plan = cd.plan_problem(
        discrimination_problem(base, pair), spans, given=given, given_conditions=given_conditions
    )
    return plan, base, pair


def _rows(problem, base, q, temperature_C, time_s):
    """(n, 3, k) weighted rows of geometry and both explanations at these conditions, built from
    :func:`augmented_jacobian` alone."""
    _, H, E = augmented_jacobian(
        problem.model, q, base.extensions, temperature_C=temperature_C, time_s=time_s
    )
    return np.concatenate([H[:, :, problem.free], E], axis=2) / problem.sigma


@pytest.mark.parametrize(
    ("text", "spans"),
    [
        (TEMP_PAIR, {"temperature_C": 3.0}),
        ("tracker_drift|joint_scale:1", {"time_s": 600.0}),
        ("backlash:3|thermal_expansion", {"temperature_C": 2.0}),  # reported with the sign, not tanh
    ],
)
def test_plan_noncentrality_is_the_projector_formula_on_the_planned_rows(kr16, text, spans):
    q1, cond1 = _first_data(kr16, 15, seed=2)
    plan, base, pair = _plan(kr16, text, spans, given=q1, given_conditions=cond1)
    q = np.random.default_rng(3).uniform(kr16.robot.lower, kr16.robot.upper, size=(12, 6))
    T0, t0 = np.mean(cond1["temperature_C"]), np.max(cond1["time_s"])
    dT, dt = spans.get("temperature_C", 0.0), spans.get("time_s", 0.0)
    F = np.concatenate(
        [
            _rows(kr16, base, q1, cond1["temperature_C"], cond1["time_s"]).reshape(-1, base.n_params),
            _rows(kr16, base, q, T0, t0).reshape(-1, base.n_params),
            _rows(kr16, base, q, T0 + dT, t0 + dt).reshape(-1, base.n_params),
        ]
    )
    # the plan's rows: the same information (its rows are in another order, with zero rows)
    G = dataclasses.replace(plan, backlash_tau0=()).F1(np.concatenate([q1, q]))  # the sign, not tanh
    assert_allclose(G.T @ G, F.T @ F, rtol=1e-9, atol=1e-9 * np.max(np.abs(F.T @ F)))
    # the planned measurements as a sequence (block 1, block 2) with their conditions: the same rows
    seq = cd.sequence_problem(base, plan.sequence_conditions(len(q))).F1(np.concatenate([q, q]))
    assert_allclose(seq, F[3 * len(q1) :], rtol=1e-12, atol=1e-12 * np.max(np.abs(F)))
    lam = cd.plan_lambdas(plan, base, pair, np.concatenate([q1, q]))
    for k, (h, idx) in enumerate(zip(pair, explanation_indices(base, pair), strict=True)):
        others = np.setdiff1d(np.arange(F.shape[1]), idx)
        Z, X = F[:, others], F[:, idx]
        R = X - Z @ np.linalg.pinv(Z) @ X  # (I - P_[G, other]) J_h
        S = R.T @ R
        want = h.theta @ S @ h.theta if h.direction_known else h.theta @ h.theta * np.linalg.eigvalsh(S)[0]
        assert want > 0
        assert_allclose(lam[k], want, rtol=1e-5)


def test_plan_criterion_gradient_matches_central_differences(kr16):
    q1, cond1 = _first_data(kr16, 10, seed=4)
    plan, _, _ = _plan(kr16, "thermal_expansion|tracker_drift", {"temperature_C": 2.0, "time_s": 300.0})
    q = np.random.default_rng(5).uniform(kr16.robot.lower, kr16.robot.upper, size=(12, 6))
    F, dF = plan.F1(q, with_dq=True)
    assert F.shape == (6 * 12, plan.n_params) and dF.shape == (12, 6, 6, plan.n_params)
    fd = central_fd(lambda x: plan.F1(x).reshape(12, 6, -1), q, 1e-6)
    for k in range(12):  # rows of pose k depend on pose k only
        assert_allclose(
            dF[k].transpose(1, 2, 0), fd[k, :, :, k, :], rtol=1e-5, atol=1e-6 * np.max(np.abs(fd))
        )
    M0 = plan.F1(q1).T @ plan.F1(q1)
    obj = DesignObjective(plan, "kpi", fixed_information=M0)
    _, grads = obj.values_and_grads(q)
    fd_v = central_fd(lambda x: obj.values_and_grads(x)[0], q, 1e-6)
    assert_allclose(grads, fd_v, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd_v)))


def test_required_span_gives_the_target_power(kr16):
    q1, cond1 = _first_data(kr16, 20, seed=6)
    plan, base, pair = _plan(kr16, TEMP_PAIR, {}, given=q1, given_conditions=cond1)
    q = heuristic_design(base, n=12, seed=0)
    q_all = np.concatenate([q1, q])
    need = cd.required_spans(plan, base, pair, q_all)
    assert set(need) == {"temperature_C"} and 0 < need["temperature_C"] < 100
    lam = cd.plan_lambdas(cd.with_spans(plan, need), base, pair, q_all)
    powers = [ex.power(x, 1) for x in lam]
    assert_allclose(min(powers), ex.TARGET_POWER, rtol=1e-4)  # the harder explanation sets the span
    assert max(powers) >= ex.TARGET_POWER
    assert cd.nice_ceil(2.66) == 2.7 and cd.nice_ceil(13.2) == 14.0 and cd.nice_ceil(0.0301) == 0.031


def test_condition_span_parsing(kr16):
    pair = ex.parse_pair("thermal_expansion|tracker_drift", kr16.model)
    assert cd.parse_condition_span("3K, 10min", pair) == {"temperature_C": 3.0, "time_s": 600.0}
    assert cd.parse_condition_span("0.5 k,2h", pair) == {"temperature_C": 0.5, "time_s": 7200.0}
    assert cd.parse_condition_span(None, pair) == {}
    for bad, pattern in [
        ("3", "expected a number with a unit"),
        ("3C", "expected a number with a unit"),
        ("-1K", "expected a finite span >= 0"),
        ("nanK", "expected a finite span >= 0"),
        ("3K,4K", "given twice"),
    ]:
        with pytest.raises(InputError, match=rf"^condition_span.*{pattern}"):
            cd.parse_condition_span(bad, pair)
    temp_only = ex.parse_pair(TEMP_PAIR, kr16.model)
    with pytest.raises(InputError, match="need no time_s span"):
        cd.parse_condition_span("600s", temp_only)
    with pytest.raises(InputError, match="only for a discriminate pair with"):
        cd.parse_condition_span("3K", ex.parse_pair("joint_scale:2|gear_cyclic:2:1", kr16.model))


def _write_first(problem, path, n=40, seed=0):
    q1, cond1 = _first_data(problem, n, seed)
    table, _ = simulate(
        load_robot("kr16"),
        q1,
        SimulationOptions(sigma_mm=SIGMA, seed=9),
        temperature_C=cond1["temperature_C"],
        time_s=cond1["time_s"],
    )
    path.write_text(table_csv_text(table))
    return q1, cond1


@pytest.mark.slow
def test_cli_writes_the_planned_conditions_and_the_api_agrees(kr16, tmp_path, capsys):
    first = tmp_path / "first.csv"  # a measurement CSV: its temperature_C and time_s are the first data's
    q1, cond1 = _write_first(kr16, first, n=30)
    out, rec = tmp_path / "plan.csv", tmp_path / "plan.json"
    argv = ["design", "--robot", "kr16", "--discriminate", TEMP_PAIR, "--given", str(first), "--n", "12"]
    argv += ["--condition-span", "3K", "--sigma-mm", str(SIGMA), "--out", str(out), "--json", str(rec)]
    assert main([*argv, "--html", str(tmp_path / "plan.html")]) == 0  # the page: Cs of the planned rows
    assert (tmp_path / "plan.html").stat().st_size > 0
    text = capsys.readouterr().out
    assert "temperature_C span 3 K (given)" in text and "tracker_scale true: lambda" in text
    header = out.read_text().splitlines()[0].split(",")
    assert header[-2:] == ["block", "temperature_offset_K"] and "incidence_deg" in header
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape[0] == 24
    assert_allclose(data[:, -2], np.repeat([1, 2], 12))
    assert_allclose(data[:, -1], np.repeat([0.0, 3.0], 12))
    assert_allclose(data[:12, :6], data[12:, :6])  # each pose in both blocks
    d = json.loads(rec.read_text())
    plan = d["discrimination"]["plan"]
    assert plan["n_distinct_poses"] == 12 and plan["n_measurements"] == 24
    (span,) = plan["spans"]
    assert (span["condition"], span["span"], span["unit"], span["source"]) == (
        "temperature_C",
        3.0,
        "K",
        "given",
    )
    assert_allclose(
        plan["block1"]["temperature_C"], np.mean(cond1["temperature_C"]), atol=1e-4
    )  # the file: 6 digits
    assert [p["block"] for p in d["poses"]] == [1] * 12 + [2] * 12
    for name in d["discrimination"]["pair"]:
        b, a = d["discrimination"]["before"][name], d["discrimination"]["after"][name]
        assert a["lambda"] > 10 * b["lambda"]
    res = api.design("kr16", discriminate=TEMP_PAIR, given=first, n=12, sigma_mm=SIGMA, condition_span="3K")
    assert_allclose(np.rad2deg(res.q), data[:, :6], atol=1e-5)


@pytest.mark.parametrize(
    ("extra", "pattern"),
    [
        (
            ["--discriminate", TEMP_PAIR, "--condition-span", "3"],
            "--condition-span: expected a number with a unit",
        ),
        (
            ["--discriminate", TEMP_PAIR, "--condition-span=-2K"],
            "--condition-span: expected a finite span",
        ),
        (["--discriminate", TEMP_PAIR, "--condition-span", "60s"], "--condition-span 60s: thermal_expansion"),
        (["--discriminate", TEMP_PAIR, "--condition-span", "0K"], "temperature_C span of"),
        (["--discriminate", "joint_scale:2|gear_cyclic:2:1", "--condition-span", "3K"], "only for a"),
        (["--criterion", "kpi", "--condition-span", "3K"], "--condition-span goes with --discriminate"),
    ],
)
def test_bad_spans_exit_2_naming_the_option_and_write_nothing(tmp_path, capsys, extra, pattern):
    out, rec = tmp_path / "d.csv", tmp_path / "d.json"
    argv = ["design", "--robot", "kr16", "--n", "12", "--out", str(out), "--json", str(rec), *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert pattern in err and "Traceback" not in err
    assert not out.exists() and not rec.exists()


def _case(problem, tmp_path, pair, truth, *, n_first, n, sec=30.0, span=None):
    """First data, the plan, the truth simulated on both (one true robot, one noise draw; block
    times in the planned order), and diagnose on the first data and on all."""
    q1, cond1 = _first_data(problem, n_first, seed=0)
    cond1["time_s"] = np.arange(n_first) * sec
    res, _ = plan_design(problem, pair, n=n, given=q1, given_conditions=cond1, seed=0, condition_span=span)
    block1, m = res.discrimination["plan"]["block1"], res.n
    temp2 = block1.get("temperature_C", np.mean(cond1["temperature_C"]))
    temp2 = (
        temp2
        + res.plan_columns.get("temperature_offset_K", 0.0)
        + np.random.default_rng(7).normal(0, 0.02, m)
    )
    time2 = (
        cond1["time_s"][-1]
        + sec * (1 + np.tile(np.arange(m // 2), 2))
        + res.plan_columns.get("time_offset_s", 0.0)
    )
    table, _ = simulate(
        load_robot("kr16"),
        np.concatenate([q1, res.q]),
        SimulationOptions(sigma_mm=SIGMA, seed=1, effects=[truth]),
        temperature_C=np.concatenate([cond1["temperature_C"], temp2]),
        time_s=np.concatenate([cond1["time_s"], time2]),
    )
    (tmp_path / "first.csv").write_text(table_csv_text(table.iloc[:n_first]))
    (tmp_path / "all.csv").write_text(table_csv_text(table))
    first = diagnose(problem.robot, tmp_path / "first.csv", DiagnosisOptions(sigma_mm=SIGMA))
    both = diagnose(problem.robot, tmp_path / "all.csv", DiagnosisOptions(sigma_mm=SIGMA))
    return res.discrimination, first, both


def _named(report) -> set[str]:
    return {c["name"] for c in report.causes} | {a["name"] for c in report.causes for a in c["alternatives"]}


@pytest.mark.slow
def test_first_data_cannot_separate_temperature_effects_and_the_plan_does(kr16, tmp_path):
    """Reduced case (30 first poses within 0.3 K, 12 planned poses): the air's -0.93 ppm/K."""
    rec, first, both = _case(kr16, tmp_path, TEMP_PAIR, "tracker_scale=-0.93", n_first=30, n=12)
    for name in rec["pair"]:
        assert rec["before"][name]["power"] < 0.05  # the first data: (almost) the level, no power
    assert min(rec["after"][name]["power"] for name in rec["pair"]) >= ex.TARGET_POWER
    assert "tracker_scale" not in _named(first)
    assert both.cause_names == {"tracker_scale"}
    assert both.causes[0]["alternatives"] == []


@pytest.mark.slow
@pytest.mark.parametrize(
    ("pair", "truth", "sec"),
    [
        (TEMP_PAIR, "tracker_scale=-0.93", 30.0),
        ("tracker_drift|joint_scale:1", "tracker_drift=0.006,0.003,-0.002", 2.0),
    ],
)
def test_documented_cases_40_first_poses_20_planned(kr16, tmp_path, pair, truth, sec):
    """docs/diagnosis.md: 40 first poses, 20 planned poses, the default span."""
    rec, first, both = _case(kr16, tmp_path, pair, truth, n_first=40, n=20, sec=sec)
    effect = truth.split("=")[0]
    assert rec["before"][effect]["power"] < 0.05 and rec["after"][effect]["power"] > ex.TARGET_POWER
    assert effect not in _named(first)
    assert {c["name"] for c in both.causes} == {effect} and both.causes[0]["alternatives"] == []


def test_simulate_adds_the_plans_condition_offsets(kr16, tmp_path, capsys):
    """A plan's design CSV (block 2 after +3 K or a 600 s pause): ``kpioed simulate`` adds each row's
    offset to the simulated temperature and time; every seeded draw is the same as without a plan."""
    q = np.tile(random_poses(kr16.robot, 6, np.random.default_rng(3)), (2, 1))
    offsets = {"temperature_offset_K": np.repeat([0.0, 3.0], 6), "time_offset_s": np.repeat([0.0, 600.0], 6)}
    plan, plain = tmp_path / "plan.csv", tmp_path / "plain.csv"
    plan.write_text(design_csv_text(q, {"block": np.repeat([1, 2], 6), **offsets}))
    plain.write_text(design_csv_text(q))
    argv = ["simulate", "--robot", "kr16", "--seed", "4", "--effect", "thermal_expansion"]
    assert main([*argv, "--design", str(plan), "--out", str(tmp_path / "a.csv")]) == 0
    assert "measurement plan: the design's temperature_offset_K and time_offset_s" in capsys.readouterr().out
    assert main([*argv, "--design", str(plain), "--out", str(tmp_path / "b.csv")]) == 0
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert_allclose(a["temperature_C"] - b["temperature_C"], offsets["temperature_offset_K"], atol=2e-5)
    assert_allclose(a["time_s"] - b["time_s"], offsets["time_offset_s"], atol=1e-9)
    # the thermal expansion follows the planned temperature: block 2 moves, block 1 does not
    d = np.linalg.norm((a[["x_mm", "y_mm", "z_mm"]] - b[["x_mm", "y_mm", "z_mm"]]).to_numpy(), axis=1)
    assert np.all(d[:6] < 1e-5) and np.all(d[6:] > 1e-4)
    lines = plan.read_text().splitlines()
    lines[-1] = lines[-1].rsplit(",", 1)[0] + ",soon"  # the last row's time_offset_s
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    assert main(["simulate", "--robot", "kr16", "--design", str(bad), "--out", str(tmp_path / "c.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: row 13, column 'time_offset_s': 'soon' is not a number" in err and "Traceback" not in err
    assert not (tmp_path / "c.csv").exists()
