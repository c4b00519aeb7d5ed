"""Online calibration (``kpioed next``): with the estimate at nominal it is ``design --given``; done
exactly when the measured tr(Cs)/3 is at most the target; the a-posteriori noise when the fit
rejects; bad inputs exit 2 and write nothing; a reduced closed loop stops with the truth inside."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.design.report import DesignError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design, write_design
from kpioed_drake.online import NextOptions, closed_loop, next_poses, step
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate, table_csv_text
from kpioed_drake.tracker.data import Measurements

SIGMA = 0.02


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def measured(kr16, tmp_path_factory):
    """30 random poses of the nominal kr16, noise free (the estimate is the nominal model)."""
    work = tmp_path_factory.mktemp("online")
    q = np.random.default_rng(3).uniform(kr16.lower, kr16.upper, size=(30, 6))
    write_design(work / "given.csv", q)
    table, _ = simulate(
        kr16, read_design(work / "given.csv", kr16), SimulationOptions(sigma_mm=0.0, geometric_errors=False)
    )
    (work / "data.csv").write_text(table_csv_text(table))
    return work


def _now(kr16, measured) -> float:
    data = Measurements.from_table(pd.read_csv(measured / "data.csv"), kr16)
    return next_poses(kr16, data, NextOptions(target_var_mm2=1e9, sigma_mm=SIGMA)).kpi_avg_var_mm2


def test_next_at_nominal_is_design_given(kr16, measured):
    """A target the next batch reaches: the plan is the batch, ``design --given`` of n poses."""
    target = 0.9 * _now(kr16, measured)
    rec = api.next("kr16", measured / "data.csv", target_var_mm2=target, n=5, sigma_mm=SIGMA, certify=False,
                   out=measured / "next.csv")  # fmt: skip
    assert not rec["done"] and rec["n_measured"] == 30 and not rec["aposteriori"]
    assert rec["n_planned"] == 5
    res = api.design("kr16", criterion="kpi", n=5, sigma_mm=SIGMA, given=measured / "given.csv",
                     certify=False, out=measured / "design.csv")  # fmt: skip
    assert np.array_equal(
        read_design(measured / "next.csv", kr16), read_design(measured / "design.csv", kr16)
    )
    assert rec["predicted_kpi_avg_var_mm2"] == pytest.approx(res.kpi_avg_var_mm2, rel=1e-12)
    assert rec["predicted_kpi_avg_var_mm2"] <= target


def test_a_farther_target_is_planned_and_the_most_useful_poses_come_first(kr16, measured):
    """The plan is ``design --given`` of the poses still needed; the batch its n most useful."""
    target = 0.4 * _now(kr16, measured)
    rec = api.next("kr16", measured / "data.csv", target_var_mm2=target, n=3, sigma_mm=SIGMA, certify=False,
                   out=measured / "next3.csv")  # fmt: skip
    h = rec["n_planned"]
    assert 3 < h <= NextOptions().max_plan
    plan = api.design("kr16", criterion="kpi", n=h, sigma_mm=SIGMA, given=measured / "given.csv",
                      certify=False, out=measured / "plan.csv")  # fmt: skip
    q_plan, q_next = read_design(measured / "plan.csv", kr16), read_design(measured / "next3.csv", kr16)
    rows = [int(np.flatnonzero(np.all(np.isclose(q_plan, x, atol=1e-9), axis=1))[0]) for x in q_next]
    assert len(set(rows)) == 3
    # every other choice of 3 plan poses lowers tr(Cs)/3 less than the first one chosen does
    given = read_design(measured / "given.csv", kr16)
    problem = make_problem(kr16, sigma_mm=SIGMA)
    one = [problem.criteria(np.vstack([given, q_plan[[i]]]))["kpi_avg_var_mm2"] for i in range(h)]
    assert one[rows[0]] == pytest.approx(min(one), rel=1e-9)
    assert rec["predicted_kpi_avg_var_mm2"] == pytest.approx(
        problem.criteria(np.vstack([given, q_next]))["kpi_avg_var_mm2"], rel=1e-12
    )
    assert plan.kpi_avg_var_mm2 <= rec["predicted_kpi_avg_var_mm2"]


def test_done_exactly_when_the_variance_is_at_most_the_target(kr16, measured):
    data = Measurements.from_table(__import__("pandas").read_csv(measured / "data.csv"), kr16)
    now = next_poses(kr16, data, NextOptions(target_var_mm2=1.0, sigma_mm=SIGMA)).kpi_avg_var_mm2
    assert next_poses(kr16, data, NextOptions(target_var_mm2=now, sigma_mm=SIGMA)).done
    below = next_poses(
        kr16, data, NextOptions(target_var_mm2=now * (1 - 1e-9), sigma_mm=SIGMA, certify=False)
    )
    assert not below.done and below.q_next.shape == (5, 6)


def test_the_aposteriori_noise_is_used_when_the_fit_rejects(kr16, measured):
    q = read_design(measured / "given.csv", kr16)
    table, _ = simulate(kr16, q, SimulationOptions(sigma_mm=0.2, seed=4))
    data = Measurements.from_table(table, kr16)
    step = next_poses(kr16, data, NextOptions(target_var_mm2=10.0, sigma_mm=SIGMA))
    rep = step.report
    assert rep.rejects and step.aposteriori
    assert step.kpi_avg_var_mm2 == pytest.approx(np.trace(rep.kpi_cov) / 3 * rep.chi2_per_dof, rel=1e-12)
    assert step.sigma_used_mm == pytest.approx(SIGMA * np.sqrt(rep.chi2_per_dof), rel=1e-12)


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--target-var", "0"], "--target-var:"),
        (["--target-var", "-1"], "--target-var:"),
        (["--target-var", "0.1", "--n", "0"], "--n:"),
        (["--target-var", "0.1", "--max-plan", "0"], "--max-plan:"),
        (["--target-var", "0.1", "--n", "100000"], "--n 100000: expected at most --max-plan (60)"),
        (["--target-var", "0.1", "--n", "8", "--max-plan", "6"], "--n 8: expected at most --max-plan (6)"),
    ],
)
def test_bad_input_exits_2_and_writes_nothing(measured, tmp_path, capsys, extra, match):
    out = tmp_path / "next.csv"
    assert main(["next", "--robot", "kr16", str(measured / "data.csv"), *extra, "--out", str(out)]) == 2
    assert match in capsys.readouterr().err and not out.exists()


def test_no_poses_yet_exits_2(tmp_path, capsys):
    empty = tmp_path / "empty.csv"
    empty.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n")
    out = tmp_path / "next.csv"
    assert main(["next", "--robot", "kr16", str(empty), "--target-var", "0.1", "--out", str(out)]) == 2
    assert "empty.csv" in capsys.readouterr().err and not out.exists()


def test_cli_writes_the_json_record_and_nothing_when_done(measured, tmp_path):
    out, rec = tmp_path / "next.csv", tmp_path / "next.json"
    args = ["next", "--robot", "kr16", str(measured / "data.csv"), "--out", str(out), "--json", str(rec)]
    assert main([*args, "--target-var", "100"]) == 0
    d = json.loads(rec.read_text())
    assert d["done"] and d["next_q_deg"] == [] and not out.exists()


@pytest.mark.slow
def test_a_reduced_closed_loop_stops_at_the_target(kr16):
    """kr16, sigma 1 mm, V = 0.1 mm^2 (the paper's setting), 10 heuristic poses then 5 per round."""
    r = closed_loop(kr16, seed=0, target_var_mm2=0.1, sigma_mm=1.0)
    assert r["done"] and r["kpi_avg_var_mm2"] <= 0.1
    assert 35 <= r["n_poses"] <= 60 and (r["n_poses"] - 10) % 5 == 0
    assert r["mahalanobis2"] >= 0 and r["inside_95"] == (r["mahalanobis2"] <= 7.815)


def test_a_solver_failure_is_retried_from_heuristic_poses(kr16, measured, monkeypatch):
    """The first design fails (DesignError): the retry takes the next seed from heuristic poses (no
    new certified search) and its poses are returned; a failure of every retry is reported."""
    calls = []
    real = step.optimize_design

    def failing_first(*args, **kwargs):
        calls.append((kwargs["seed"], kwargs.get("start")))
        if len(calls) == 1:
            raise DesignError("SNOPT failed (test)")
        return real(*args, **kwargs)

    monkeypatch.setattr(step, "optimize_design", failing_first)
    data = Measurements.from_table(pd.read_csv(measured / "data.csv"), kr16)
    target = 0.9 * _now(kr16, measured)
    res = next_poses(kr16, data, NextOptions(target_var_mm2=target, sigma_mm=SIGMA, certify=False))
    assert calls == [(0, None), (1, "heuristic")] and res.q_next.shape == (5, 6)

    def always(*args, **kwargs):
        raise DesignError("SNOPT failed (test)")

    monkeypatch.setattr(step, "optimize_design", always)
    with pytest.raises(DesignError):
        next_poses(kr16, data, NextOptions(target_var_mm2=target, sigma_mm=SIGMA, certify=False))


def test_poses_measured_a_rounding_beyond_a_joint_limit_are_taken(kr16, measured):
    """A pose designed at a joint limit comes back from the file in degrees up to a rounding beyond
    it: the measured poses enter only through their information, so the step designs on."""
    q = read_design(measured / "given.csv", kr16)
    q[0, 1], q[1, 2] = kr16.upper[1], kr16.lower[2]
    table, _ = simulate(kr16, q, SimulationOptions(sigma_mm=0.0, geometric_errors=False))
    data = Measurements.from_table(table, kr16)
    q[0, 1], q[1, 2] = kr16.upper[1] + 5e-12, kr16.lower[2] - 5e-12
    beyond = dataclasses.replace(data, q=q)
    opts = NextOptions(target_var_mm2=0.9 * _now(kr16, measured), sigma_mm=SIGMA, certify=False)
    res = next_poses(kr16, beyond, opts)
    assert res.q_next.shape == (5, 6)
    assert np.all(res.q_next >= kr16.lower) and np.all(res.q_next <= kr16.upper)
