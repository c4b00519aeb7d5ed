"""Data columns the model does not read: kept in the measurements, tested against the unexplained
rest, and named in the report with what to do (the tree stand-in: one arm's model, both arms' joints
in the file)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.diagnosis import report as rp
from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.robot.models import load_robot
from kpioed_drake.tracker.data import Measurements, read_measurements

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import humanoid  # noqa: E402

LEFT = [f"q{k}_deg" for k in range(12, 19)]


@pytest.fixture(scope="module")
def one_arm():
    return load_robot(str(humanoid.ROBOTS / "humanoid11.urdf"))


@pytest.fixture(scope="module")
def right_hand_table():
    """The two-arm stand-in's right-hand rows (elastic torso carrying both arms), its left arm's
    joints q12..q18 left in the file, and a seeded column of pure noise."""
    _, table, _, _ = humanoid._truth_table(150, 0, seed=3, sigma_mm=0.5, lateral=False, twin=True)
    right = table[table["target"] == 1].drop(columns=["target"]).reset_index(drop=True)
    right["noise_col"] = np.random.default_rng(5).normal(size=len(right))
    return right


def _rest(robot, data):
    prob = FitProblem(robot, data, 0.5)
    return rp.unexplained_rest(prob, prob.fit([]), alpha=0.01, robot=robot)


def test_the_rest_follows_the_other_arms_columns(one_arm, right_hand_table):
    """After the one-arm diagnosis (its own arm's and the torso's elasticity named) the rest follows
    the left arm's joints, which the model does not read: the report names them and says to describe
    the whole tree; the noise column is not named."""
    data = Measurements.from_table(right_hand_table, one_arm, source="right hand")
    assert [k for k, _ in data.extra] == LEFT + ["noise_col"]
    rep = diagnose(one_arm, data, DiagnosisOptions(sigma_mm=0.5))
    u = rep.unexplained
    named = [c["column"] for c in u["unused_columns"]]
    assert named and set(named) <= set(LEFT), named
    assert "describe the whole tree" in u["advice"] and named[0] in u["advice"]
    assert "which the model does not use" in rep.summary()
    assert rep.to_json()["unexplained"]["unused_columns"][0]["column"] == named[0]


def test_a_fixed_other_arm_names_no_column(one_arm, right_hand_table):
    """The same file with the left arm's columns constant (and the noise column): nothing to follow."""
    table = right_hand_table.copy()
    for c in LEFT:
        table[c] = 10.0
    data = Measurements.from_table(table, one_arm, source="fixed left arm")
    u = _rest(one_arm, data)
    assert [c["column"] for c in u["unused_columns"]] == []
    assert u["advice"] is None


def test_unused_columns_are_kept_through_files_and_subsets(one_arm, right_hand_table, tmp_path):
    """Read from a file (a text column is not data, numeric ones are kept), subset, written back."""
    table = right_hand_table.iloc[:40].copy()
    table["operator"] = "anna"
    path = tmp_path / "data.csv"
    table.to_csv(path, index=False)
    data = read_measurements(path, one_arm)
    assert [k for k, _ in data.extra] == LEFT + ["noise_col"]
    sub = data.subset(np.arange(5, 15))
    assert_allclose(dict(sub.extra)["noise_col"], table["noise_col"].to_numpy()[5:15], rtol=0, atol=0)
    back = sub.to_frame(one_arm)
    assert_allclose(back["q12_deg"].to_numpy(), table["q12_deg"].to_numpy()[5:15], rtol=0, atol=1e-12)
