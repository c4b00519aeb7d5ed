"""The robot's joint names in the reports, the index second: calibrate's parameter table and summary,
the effects it estimates, and diagnose's causes (JSON and summary)."""

import dataclasses

import numpy as np
import pytest

from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.robot.models import load_robot
from kpioed_drake.robot.parameters import joint_label, parameter_joint
from kpioed_drake.study.synthetic import synthetic_case
from kpioed_drake.tracker.data import as_measurements


@pytest.mark.parametrize(
    "name, joint",
    [("theta2", 2), ("alpha6", 6), ("beta2", 2), ("px11", 11), ("off1", 1), ("tracker_rx", None),
     ("reflector_x", None), ("a", None)],
)  # fmt: skip
def test_parameter_joint(name, joint):
    assert parameter_joint(name) == joint


@pytest.fixture(scope="module")
def named():
    """kr16 with the joints named as a controller might (not A1..A6)."""
    names = ("base_yaw", "shoulder", "elbow", "wrist_roll", "wrist_pitch", "flange_roll")
    return dataclasses.replace(load_robot("kr16"), joint_names=names)


@pytest.fixture(scope="module")
def case(named):
    return synthetic_case(named, np.random.default_rng(4), ["joint_elasticity:3=4e-6"], n_poses=60)


def test_calibrate_names_the_joints(named, case):
    data = as_measurements(case.data, named)
    rep = calibrate(named, data, CalibrationOptions(effects=("joint_elasticity:3",)))
    rows = {p["name"]: p for p in rep.to_dict()["parameters"]}
    assert rows["theta2"]["joint_name"] == "shoulder" and rows["tracker_x"]["joint_name"] is None
    assert rep.to_dict()["effects"][0]["joint_name"] == "elbow"
    text = rep.summary()
    assert "joint_elasticity:3 [elbow]" in text
    assert any("(" in line and ")" in line for line in text.splitlines() if "+-" in line)
    assert joint_label(named, 5) == "wrist_pitch (joint 5)" and joint_label(named, None) == ""


def test_diagnose_names_the_joint_of_a_cause(named, case):
    rep = diagnose(named, as_measurements(case.data, named), DiagnosisOptions(max_effects=1))
    (cause,) = rep.causes
    assert cause["joint"] == 3 and cause["joint_name"] == "elbow"
    assert "[elbow, joint 3]" in rep.summary()
