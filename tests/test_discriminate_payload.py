"""Payload plans (issue 13 item 5, "where conditions matter ... payload"): ``kpioed design
--discriminate "A|B" --condition-span 10kg`` for a pair with an effect that acts through the gravity
torque (joint elasticity, backlash, a column's or the base's compliance).

Block 2 carries the payload at the reflector point: the torque effect's signature changes at a fixed
pose, a joint effect's does not. Checked: the plan's non-centrality against the projector formula on
rows built from :func:`augmented_jacobian` at 0 and 10 kg, the rows' joint-angle derivative against
central differences, the span's parsing, the payload that gives the target power, the command line's
CSV and JSON, ``kpioed simulate --design`` adding the planned payload, and a simulated case: the
first data cannot tell a joint-2 elasticity from a joint-2 gear-ratio error, the plan's data names it.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake.cli import main
from kpioed_drake.design.discriminate import conditions as cd
from kpioed_drake.design.discriminate import explanations as ex
from kpioed_drake.design.discriminate import plan as plan_mod
from kpioed_drake.design.discriminate.design import discrimination_problem, explanation_indices
from kpioed_drake.design.discriminate.plan import plan_design
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.diagnosis.options import DiagnosisOptions
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.effects import augmented_jacobian
from kpioed_drake.errors import InputError, param_names
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.models import MODELS_DIR, load_robot
from kpioed_drake.simulation import SimulationOptions, simulate, table_csv_text
from kpioed_drake.study.synthetic import random_poses

SIGMA = 0.02
PAIR = "joint_elasticity:2|joint_scale:2"
ROBOTS = MODELS_DIR / "robots"


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16", sigma_mm=SIGMA)


def _plan(problem, text, spans, *, given=None):
    pair = ex.parse_pair(text, problem.model)
    zero = tuple(dataclasses.replace(h.effect, values=None) for h in pair)
    base = dataclasses.replace(problem, extensions=zero)
    return cd.plan_problem(discrimination_problem(base, pair), spans, given=given), base, pair


def _rows(problem, base, q, payload_kg):
    _, H, E = augmented_jacobian(problem.model, q, base.extensions, payload_kg=payload_kg)
    return (np.concatenate([H[:, :, problem.free], E], axis=2) / problem.sigma).reshape(-1, base.n_params)


@pytest.mark.parametrize("text", [PAIR, "backlash:3|gear_cyclic:3:1"])
def test_payload_plan_noncentrality_is_the_projector_formula(kr16, text):
    rng = np.random.default_rng(2)
    q1 = random_poses(kr16.robot, 15, rng)
    plan, base, pair = _plan(kr16, text, {"payload_kg": 10.0}, given=q1)
    q = random_poses(kr16.robot, 12, rng)
    F = np.concatenate([_rows(kr16, base, q1, None), _rows(kr16, base, q, 0.0), _rows(kr16, base, q, 10.0)])
    G = dataclasses.replace(plan, backlash_tau0=()).F1(np.concatenate([q1, q]))
    assert_allclose(G.T @ G, F.T @ F, rtol=1e-9, atol=1e-9 * np.max(np.abs(F.T @ F)))
    # the payload moves the torque effect's column (a backlash's only where the torque's sign
    # flips) and nothing else
    moved = np.abs(_rows(kr16, base, q, 10.0) - _rows(kr16, base, q, 0.0)).max(axis=0)
    idx = explanation_indices(base, pair)
    if text == PAIR:
        assert moved[idx[0]].min() > 1e-3 * np.abs(F[:, idx[0]]).max()
    assert moved[np.setdiff1d(np.arange(base.n_params), idx[0])].max() == 0.0
    lam = cd.plan_lambdas(plan, base, pair, np.concatenate([q1, q]))
    for k, (h, ix) in enumerate(zip(pair, idx, strict=True)):
        Z, X = F[:, np.setdiff1d(np.arange(F.shape[1]), ix)], F[:, ix]
        R = X - Z @ np.linalg.pinv(Z) @ X
        S = R.T @ R
        want = h.theta @ S @ h.theta if h.direction_known else h.theta @ h.theta * np.linalg.eigvalsh(S)[0]
        assert_allclose(lam[k], want, rtol=1e-5)


def test_payload_plan_rows_derivative_matches_central_differences(kr16):
    plan, _, _ = _plan(kr16, PAIR, {"payload_kg": 10.0})
    q = random_poses(kr16.robot, 6, np.random.default_rng(5))
    F, dF = plan.F1(q, with_dq=True)
    fd = central_fd(lambda x: plan.F1(x).reshape(6, 6, -1), q, 1e-6)
    for k in range(6):
        assert_allclose(
            dF[k].transpose(1, 2, 0), fd[k, :, :, k, :], rtol=1e-5, atol=1e-6 * np.max(np.abs(fd))
        )


def test_payload_span_parsing(kr16):
    pair = ex.parse_pair(PAIR, kr16.model)
    assert cd.parse_condition_span("10kg", pair) == {"payload_kg": 10.0}
    assert cd.plan_conditions(pair, {"payload_kg": 10.0}) == ["payload_kg"]
    assert cd.plan_conditions(pair, {}) == []  # opt-in: the poses alone without a span
    both = ex.parse_pair("joint_elasticity:3|thermal_expansion", kr16.model)
    assert cd.parse_condition_span("2K,5kg", both) == {"temperature_C": 2.0, "payload_kg": 5.0}
    assert cd.plan_conditions(both, {"temperature_C": 2.0, "payload_kg": 5.0}) == [
        "temperature_C",
        "payload_kg",
    ]
    with pytest.raises(InputError, match="need no payload_kg span"):
        cd.parse_condition_span("10kg", ex.parse_pair("thermal_expansion|tracker_scale", kr16.model))
    with pytest.raises(InputError, match="only for a discriminate pair with.*a payload"):
        cd.parse_condition_span("10kg", ex.parse_pair("joint_scale:2|gear_cyclic:2:1", kr16.model))
    with pytest.raises(InputError, match="expected a finite span >= 0"):
        cd.parse_condition_span("-3kg", pair)


def test_required_payload_gives_the_target_power(kr16):
    q1 = random_poses(kr16.robot, 12, np.random.default_rng(6))
    plan, base, pair = _plan(kr16, PAIR, {}, given=q1)
    q_all = np.concatenate([q1, heuristic_design(base, n=4, seed=0)])
    need = cd.required_spans(plan, base, pair, q_all, conditions=["payload_kg"])
    assert set(need) == {"payload_kg"} and 0 < need["payload_kg"] < 1e3
    lam = cd.plan_lambdas(cd.with_spans(plan, need), base, pair, q_all)
    assert_allclose(ex.power(lam[0], 1), ex.TARGET_POWER, rtol=1e-4)  # the elasticity sets the payload


@pytest.mark.slow
def test_cli_payload_plan_and_simulate_adds_the_payload(tmp_path, capsys):
    out, rec = tmp_path / "plan.csv", tmp_path / "plan.json"
    argv = ["design", "--robot", "kr16", "--discriminate", PAIR, "--n", "10", "--condition-span", "10kg"]
    assert main([*argv, "--sigma-mm", str(SIGMA), "--out", str(out), "--json", str(rec)]) == 0
    assert "payload_kg span 10 kg (given)" in capsys.readouterr().out
    plan = pd.read_csv(out)
    assert list(plan.columns[-2:]) == ["block", "payload_offset_kg"]
    assert_allclose(plan["payload_offset_kg"], np.repeat([0.0, 10.0], 10))
    (span,) = json.loads(rec.read_text())["discrimination"]["plan"]["spans"]
    assert (span["condition"], span["column"], span["span"], span["unit"]) == (
        "payload_kg",
        "payload_offset_kg",
        10.0,
        "kg",
    )
    sim = [
        "simulate",
        "--robot",
        "kr16",
        "--seed",
        "4",
        "--effect",
        "joint_elasticity:2",
        "--design",
        str(out),
    ]
    assert main([*sim, "--payload-kg", "1", "--out", str(tmp_path / "a.csv")]) == 0
    assert "the design's payload_offset_kg added" in capsys.readouterr().out
    a = pd.read_csv(tmp_path / "a.csv")
    assert_allclose(a["payload_kg"], np.repeat([1.0, 11.0], 10))
    lines = out.read_text().splitlines()
    lines[-1] = lines[-1].rsplit(",", 1)[0] + ",-20"  # block 2 lighter than nothing
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    assert main(["simulate", "--robot", "kr16", "--design", str(bad), "--out", str(tmp_path / "c.csv")]) == 2
    err = capsys.readouterr().err
    assert "pose 20: payload -20 kg after the plan's payload_offset_kg; expected >= 0" in err
    assert "Traceback" not in err and not (tmp_path / "c.csv").exists()


@pytest.mark.slow
def test_first_data_cannot_separate_elasticity_from_scale_and_the_payload_plan_does(kr16, tmp_path):
    """20 first poses: a joint-2 elasticity (0.1 mm at the tool) and a joint-2 gear-ratio error look
    alike (diagnose lists the latter as an alternative); 10 poses measured without and with 10 kg
    separate them, and diagnose on all names the elasticity alone."""
    rng = np.random.default_rng(11)
    q1 = random_poses(kr16.robot, 20, rng)
    res, _ = plan_design(kr16, PAIR, n=10, given=q1, seed=0, condition_span="10kg")
    rec = res.discrimination
    assert rec["before"]["joint_elasticity:2"]["power"] < 0.5
    assert rec["after"]["joint_elasticity:2"]["power"] > 0.99
    pay = np.concatenate([np.zeros(len(q1)), res.plan_columns["payload_offset_kg"]])
    truth = ex.parse_pair(PAIR, kr16.model)[0].effect  # the design's size: 0.1 mm at the tool
    table, _ = simulate(
        load_robot("kr16"),
        np.concatenate([q1, res.q]),
        SimulationOptions(sigma_mm=SIGMA, seed=1, effects=[truth]),
        payload_kg=pay,
    )
    (tmp_path / "first.csv").write_text(table_csv_text(table.iloc[: len(q1)]))
    (tmp_path / "all.csv").write_text(table_csv_text(table))
    first = diagnose(kr16.robot, tmp_path / "first.csv", DiagnosisOptions(sigma_mm=SIGMA))
    both = diagnose(kr16.robot, tmp_path / "all.csv", DiagnosisOptions(sigma_mm=SIGMA))
    # the first data: the elasticity with the gear-ratio error among its alternatives (not separated)
    assert any("joint_scale:2" in [a["name"] for a in c["alternatives"]] for c in first.causes)
    # the plan's data: the elasticity alone, no alternative
    assert [c["name"] for c in both.causes] == ["joint_elasticity:2"]
    assert both.causes[0]["alternatives"] == []


@pytest.mark.slow
def test_poses_only_design_says_what_payload_would_reach_the_power(kr16, capsys):
    """A poses-only design of a torque pair carries the payload advice; a plan with that payload
    reaches the target power (half the default elasticity: the poses alone do not)."""
    c = ex.parse_pair(PAIR, kr16.model)[0].effect.values[0] / 2
    text = f"joint_elasticity:2={c:.6g}|joint_scale:2"
    q1 = random_poses(kr16.robot, 20, np.random.default_rng(11))
    res, _ = plan_design(kr16, text, n=10, given=q1, seed=0)
    rec = res.discrimination
    assert rec["after"]["joint_elasticity:2"]["power"] < ex.TARGET_POWER
    kg = rec["payload"]["required_kg"]
    assert 0 < kg < 100
    planned, _ = plan_design(kr16, text, n=10, given=q1, seed=0, condition_span=f"{kg}kg")
    assert planned.discrimination["after"]["joint_elasticity:2"]["power"] >= ex.TARGET_POWER
    lines = plan_mod.payload_lines(rec)
    assert lines == [
        f"  payload: the designed poses measured again with {kg:g} kg at the reflector reach power 0.8 "
        f"(condition_span {kg:g}kg, within the rated 16 kg)"
    ]
    with param_names({"condition_span": "--condition-span"}):  # as the command line shows it
        assert f"(--condition-span {kg:g}kg, within" in plan_mod.payload_lines(rec)[0]
    # the default size: the repeated poses reach the power without a payload
    assert plan_design(kr16, PAIR, n=10, given=q1, seed=0)[0].discrimination["payload"]["required_kg"] == 0.0


def test_rated_payload_bounds_the_plan_and_the_advice(kr16, tmp_path):
    """The model file's ``rated_payload_kg`` (kr16: 16 kg): a larger payload span exits 2 naming it;
    advice beyond it says more poses instead; a bad value names the file and field."""
    assert kr16.robot.rated_payload_kg == 16.0
    with pytest.raises(InputError, match="^condition_span 20kg: more than kr16's rated payload of 16 kg"):
        plan_design(kr16, PAIR, n=10, condition_span="20kg")
    adv = {"required_kg": 690.0, "target_power": 0.8, "rated_payload_kg": 16.0}
    assert plan_mod.payload_lines({"payload": adv}) == [
        "  payload: the designed poses would need 690 kg at the reflector for power 0.8, more than the "
        "rated 16 kg: more poses instead"
    ]
    text = (ROBOTS / "kr16.yaml").read_text()
    for bad in ("-3", ".nan"):
        path = tmp_path / "kr16bad.yaml"
        path.write_text(text.replace("rated_payload_kg: 16.0", f"rated_payload_kg: {bad}"))
        with pytest.raises(
            InputError,
            match=r"kr16bad.yaml: rated_payload_kg: expected (the rated payload in kg|a finite number)",
        ):
            load_robot(str(path))
    assert load_robot(str(ROBOTS / "lift7.urdf")).rated_payload_kg == 16.0
