"""Designs that tell two explanations apart (``kpioed design --discriminate "A|B"``, issue 13 item 5).

The derivative of the criterion against central differences, the non-centrality against the
covariance of the extended model, the power, the condition spans, the simulated case (a first data
set that cannot separate a gear-ratio error from a harmonic gear error, a discrimination design
that can), the command line and its bad inputs.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import scipy.stats
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake import effects as fx
from kpioed_drake.cli import main
from kpioed_drake.design.discriminate import design as dc
from kpioed_drake.design.discriminate import explanations as ex
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.diagnosis.options import DiagnosisOptions
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.effects import T_REF_C, augmented_jacobian, gravity_torques
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import design_csv_text
from kpioed_drake.study.synthetic import random_poses, synthetic_case

PAIR = "joint_scale:2=300|gear_cyclic:2:1"
SIGMA = 0.02


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16", sigma_mm=SIGMA)


@pytest.fixture(scope="module")
def extended(kr16):
    return _extended(kr16, PAIR)


def _extended(problem, text):
    """The problem extended by both explanations (columns at zero, as in the design) and the pair."""
    pair = ex.parse_pair(text, problem.model)
    zero = tuple(dataclasses.replace(h.effect, values=None) for h in pair)
    return dataclasses.replace(problem, extensions=zero), pair


def _narrow_first_poses(problem, n: int, seed: int, width_deg: float = 10.0) -> np.ndarray:
    """A first data set whose joint 2 stays within +-width_deg of its working angle."""
    rng = np.random.default_rng(seed)
    q = random_poses(problem.robot, n, rng)
    q[:, 1] = problem.q_work[1] + np.deg2rad(width_deg) * rng.uniform(-1.0, 1.0, n)
    return q


def test_pair_parsing_sizes_and_directions(kr16):
    a, b = ex.parse_pair(PAIR, kr16.model)
    assert (a.effect.name, a.source, a.direction_known) == ("joint_scale:2", "given", True)
    assert_allclose(a.theta, [300e-6])
    assert (b.effect.name, b.source, b.direction_known) == ("gear_cyclic:2:1", "default", False)
    assert_allclose(np.linalg.norm(b.theta), np.deg2rad(ex.DEFAULT_SIZES["gear_cyclic"]))
    e, _ = ex.parse_pair("joint_elasticity:3|backlash:3", kr16.model)
    assert e.effect.values is not None and e.effect.values[0] > 0  # the tool displacement's c


def test_criterion_gradient_matches_central_differences(extended):
    base, pair = extended
    dprob = dc.discrimination_problem(base, pair)
    obj = DesignObjective(dprob, "kpi")
    assert obj.worst_case
    q = np.random.default_rng(3).uniform(base.robot.lower, base.robot.upper, size=(14, 6))
    values, grads = obj.values_and_grads(q)
    assert values.shape == (2,) and grads.shape == (2, 14, 6)
    fd = central_fd(lambda x: obj.values_and_grads(x)[0], q, 1e-6)
    for k in range(2):
        scale = np.max(np.abs(fd[k]))
        assert scale > 0
        assert_allclose(grads[k], fd[k], rtol=1e-5, atol=1e-6 * scale)


def test_backlash_is_smoothed_in_the_criterion_with_an_exact_gradient(kr16):
    base, pair = _extended(kr16, "joint_elasticity:3|backlash:3")
    dprob = dc.discrimination_problem(base, pair)
    ((col, joint, tau0),) = dprob.backlash_tau0
    assert joint == 3 and tau0 > 0
    q = np.random.default_rng(5).uniform(base.robot.lower, base.robot.upper, size=(10, 6))
    exact, smooth = base.F1(q).reshape(10, 3, -1), dprob.F1(q).reshape(10, 3, -1)
    others = np.arange(exact.shape[2]) != col
    assert_allclose(smooth[:, :, others], exact[:, :, others], rtol=0, atol=0)
    th = np.tanh(gravity_torques(base.robot, q, p_FP=base.model.p_FQ)[:, joint - 1] / tau0)
    assert_allclose(smooth[:, :, col], exact[:, :, col] * np.abs(th)[:, None], rtol=1e-12, atol=1e-12)
    F1, dF1 = dprob.F1(q, with_dq=True)
    assert_allclose(F1, dprob.F1(q), rtol=1e-14)
    fd = central_fd(lambda x: dprob.F1(x).reshape(10, 3, -1)[:, :, col], q, 1e-6)  # (10, 3, 10, 6)
    for k in range(10):  # a row of pose k depends on pose k only: dF1[k, j, a] = d F1[k, a] / d q[k, j]
        assert_allclose(dF1[k, :, :, col].T, fd[k, :, k, :], rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))
    obj = DesignObjective(dprob, "kpi")
    _, grads = obj.values_and_grads(q)
    fd_v = central_fd(lambda x: obj.values_and_grads(x)[0], q, 1e-6)
    assert_allclose(grads, fd_v, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd_v)))


@pytest.mark.slow
def test_elasticity_against_backlash_design_raises_both_noncentralities(kr16):
    """The issue's pair "backlash or elasticity" (about 30-90 s: the elasticity's d tau / d q)."""
    res, _ = dc.discrimination_design(kr16, "joint_elasticity:3|backlash:3", n=30, seed=0)
    assert res.success and res.feasible
    rec = res.discrimination
    for name in rec["pair"]:
        assert rec["after"][name]["lambda"] > 3 * rec["before"][name]["lambda"]
        assert rec["after"][name]["power"] > 0.999


def test_noncentrality_is_the_schur_complement_and_bounds_the_criterion(extended):
    base, pair = extended
    q = np.random.default_rng(4).uniform(base.robot.lower, base.robot.upper, size=(20, 6))
    F1 = base.F1(q)
    idx = dc.explanation_indices(base, pair)
    lam = ex.noncentralities(F1, idx, pair)
    Cp = np.linalg.inv(F1.T @ F1)
    a, b = pair
    lam_a = a.theta @ np.linalg.solve(Cp[np.ix_(idx[0], idx[0])], a.theta)
    S_b = np.linalg.inv(Cp[np.ix_(idx[1], idx[1])])
    lam_b = (b.theta @ b.theta) * np.linalg.eigvalsh(S_b)[0]
    assert_allclose(lam, [lam_a, lam_b], rtol=1e-6)
    # the design criterion: 1/v_A = lambda_A (one parameter), 1/v_B <= lambda_B (worst direction)
    v = dc.discrimination_problem(base, pair).kpi_variances(q)
    assert_allclose(1.0 / v[0], lam[0], rtol=1e-6)
    assert 1.0 / v[1] <= lam[1] * (1 + 1e-9)


def test_power_is_the_noncentral_chi_square_tail():
    assert_allclose(ex.power(0.0, 1, 0.01), 0.01, rtol=1e-6)
    assert ex.power(5.0, 2) < ex.power(10.0, 2) < ex.power(10.0, 1)
    lam = ex.lambda_for_power(0.8, 2, 0.01)
    crit = scipy.stats.chi2.ppf(0.99, 2)
    assert_allclose(scipy.stats.ncx2.sf(crit, 2, lam), 0.8, rtol=1e-8)


def test_condition_span_reaches_the_target_power(kr16):
    pair = ex.parse_pair("thermal_expansion|tracker_scale", kr16.model)
    q = heuristic_design(kr16, n=30, seed=0)
    spans = ex.condition_spread(kr16, pair, q)
    assert [s["condition"] for s in spans] == ["temperature_C", "temperature_C"]
    # recompute lambda with the ramp of the span found for each explanation: the target power
    for h, s in zip(pair, spans, strict=True):
        ramp = np.linspace(-0.5, 0.5, len(q)) * s["span"]
        effs = [dataclasses.replace(x.effect, values=None) for x in pair]
        _, H, E = augmented_jacobian(kr16.model, q, effs, temperature_C=T_REF_C + ramp)
        F1 = np.concatenate([H[:, :, kr16.free], E], axis=2).reshape(3 * len(q), -1) / kr16.sigma
        k0 = kr16.model.layout.n_free
        lam = ex.noncentralities(F1, [np.array([k0]), np.array([k0 + 1])], pair)
        own = 0 if h is pair[0] else 1
        assert_allclose(ex.power(lam[own], 1), ex.TARGET_POWER, rtol=1e-6)
    with pytest.raises(InputError, match=r"^discriminate: .*temperature_C span of"):
        dc.discrimination_design(kr16, "thermal_expansion|tracker_scale", n=30)


def _fit_costs(robot, data, names):
    prob = FitProblem(robot, data, SIGMA)
    fits = {c: prob.fit([fx.parse_effect(c)]) for c in names}
    hold = {c: float(np.sqrt(np.mean(prob.holdout(f) ** 2))) for c, f in fits.items()}
    return {c: f.cost for c, f in fits.items()}, hold


def test_first_data_cannot_separate_the_pair_and_the_design_does(kr16, extended):
    """Simulated: joint 2 has a 300 ppm gear-ratio error. A first data set with joint 2 within
    +-10 deg cannot tell it from a harmonic gear error; 20 designed poses more can."""
    base, pair = extended
    q1 = _narrow_first_poses(kr16, 40, seed=0)
    res, ext = dc.discrimination_design(kr16, PAIR, n=20, given=q1, seed=0)
    assert res.success and res.feasible and res.criterion == "discriminate"
    rec = res.discrimination
    a, b = rec["pair"]
    for name in (a, b):
        assert rec["before"][name]["power"] < 0.011  # the level: no power at all
    assert rec["after"][a]["power"] > 0.99 and rec["after"][b]["power"] > 0.8
    # 20 heuristic poses instead of the design: far less power for the harder direction
    heur = dc.assessment(base, pair, np.concatenate([q1, heuristic_design(kr16, n=20, seed=0)]))
    assert rec["after"][b]["lambda"] > 4 * heur[b]["lambda"]
    # simulate the truth (A) at all poses; the first 40 are the first data set
    q_all = np.concatenate([q1, res.q])
    case = synthetic_case(kr16.robot, np.random.default_rng(100), ["joint_scale:2=300"], q=q_all, sigma=SIGMA)
    cost1, hold1 = _fit_costs(kr16.robot, case.data.subset(np.arange(len(q1))), [a, b])
    assert abs(cost1[a] - cost1[b]) < 1.0  # likelihood ratio of the two explanations: none
    assert abs(hold1[a] - hold1[b]) < 0.05 * hold1[a]
    cost2, hold2 = _fit_costs(kr16.robot, case.data, [a, b])
    assert cost2[b] - cost2[a] > 100.0  # B's fit is far worse: chi^2 difference
    assert hold2[a] < 1.3 * SIGMA and hold2[b] > 1.5 * hold2[a]
    # diagnose (all its candidates): the first data leaves B among the explanations; all data names A alone
    first = diagnose(kr16.robot, case.data.subset(np.arange(len(q1))), DiagnosisOptions(sigma_mm=SIGMA))
    named = {c["name"] for c in first.causes} | {x["name"] for c in first.causes for x in c["alternatives"]}
    assert b in named
    both = diagnose(kr16.robot, case.data, DiagnosisOptions(sigma_mm=SIGMA))
    assert both.cause_names == {"joint_scale:2"}
    assert both.causes[0]["alternatives"] == []


def test_cli_writes_the_record_and_the_api_agrees(kr16, tmp_path, capsys):
    first = tmp_path / "first.csv"
    first.write_text(design_csv_text(_narrow_first_poses(kr16, 40, seed=1)))
    out, rec = tmp_path / "d.csv", tmp_path / "d.json"
    argv = ["design", "--robot", "kr16", "--discriminate", PAIR, "--given", str(first), "--n", "20"]
    argv += ["--sigma-mm", str(SIGMA), "--out", str(out), "--json", str(rec)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "joint_scale:2 true: lambda" in text and "power" in text
    d = json.loads(rec.read_text())
    assert d["criterion"] == "discriminate" and d["n_poses"] == 20
    disc = d["discrimination"]
    assert disc["pair"] == ["joint_scale:2", "gear_cyclic:2:1"]
    assert [s["size_source"] for s in disc["assumed"]] == ["given", "default"]
    for key in ("before", "after"):
        for name in disc["pair"]:
            assert set(disc[key][name]) >= {"lambda", "power", "df"}
    assert disc["after"]["gear_cyclic:2:1"]["power"] > disc["before"]["gear_cyclic:2:1"]["power"]
    for inv_v, name in zip(disc["criterion_inverse_v"], disc["pair"], strict=True):
        assert 0 < inv_v <= disc["after"][name]["lambda"] * (1 + 1e-9)
    res = api.design("kr16", discriminate=PAIR, given=first, n=20, sigma_mm=SIGMA)
    assert_allclose(np.rad2deg(res.q), np.loadtxt(out, delimiter=",", skiprows=1)[:, :6], atol=1e-5)


@pytest.mark.parametrize(
    ("pair", "pattern"),
    [
        ("joint_scale:2", "expected two explanations"),
        ("joint_scale:2|", "expected two explanations"),
        ("foo:2|gear_cyclic:2:1", "unknown effect 'foo'"),
        ("joint_scale:2|joint_scale:2=200", "the same effect"),
        ("joint_elasticity:1|gear_cyclic:2:1", "joint 1 turns about the vertical axis"),
        ("joint_scale:7|gear_cyclic:2:1", "joint must be 1..6"),
    ],
)
def test_bad_pairs_exit_2_naming_the_option_and_write_nothing(tmp_path, capsys, pair, pattern):
    out, rec = tmp_path / "d.csv", tmp_path / "d.json"
    argv = ["design", "--robot", "kr16", "--discriminate", pair, "--n", "12", "--out", str(out)]
    assert main([*argv, "--json", str(rec)]) == 2
    err = capsys.readouterr().err
    assert "--discriminate" in err and pattern in err and "Traceback" not in err
    assert not out.exists() and not rec.exists()


@pytest.mark.parametrize(
    ("extra", "pattern"),
    [
        (["--criterion", "param"], "--discriminate replaces --criterion"),
        (["--target-var", "0.1"], "--discriminate takes no --target-var"),
        (["--start", "approximate"], "--discriminate: the optimiser starts from the heuristic"),
        (["--extend", "gear_cyclic:2:1"], "--discriminate: gear_cyclic:2:1 is also given to --extend"),
    ],
)
def test_options_that_do_not_go_with_discriminate_exit_2(tmp_path, capsys, extra, pattern):
    out = tmp_path / "d.csv"
    argv = ["design", "--robot", "kr16", "--discriminate", PAIR, "--n", "12", "--out", str(out), *extra]
    assert main(argv) == 2
    assert pattern in capsys.readouterr().err
    assert not out.exists()


def test_design_without_criterion_or_discriminate_exits_2(tmp_path, capsys):
    assert main(["design", "--robot", "kr16", "--out", str(tmp_path / "d.csv")]) == 2
    assert "--criterion is required" in capsys.readouterr().err
