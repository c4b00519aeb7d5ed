"""The shipped test robots of URDFs and joint maps as they come: ``column8`` (lift7 as URDFs are
published: a telescoping column of a commanded joint and a ``<mimic>`` of it, a movable tilt-sensor
branch and fixed drill-tip and prism branches, a sidecar of two lines) and ``fanuc6`` (six joints
with a Fanuc-style J2/J3 coupling and a sign flip in its joint map): simulated data recover their
parameters within 3 sigma."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from kpioed_drake import calibration, simulation
from kpioed_drake.cli import main
from kpioed_drake.robot.models import MODELS_DIR, load_robot
from kpioed_drake.tracker.data import Measurements

ROBOTS = MODELS_DIR / "robots"


def _z_scores(rep, truth_model):
    res = rep.result
    lay = res.model.layout
    z = (res.model.p[res.free] - truth_model.p[res.free]) / res.std
    free = set(res.free.tolist())
    axes = [k for k, i in enumerate(range(lay.size)[lay.tracker_rotation]) if i in free]
    rot = Rotation.from_matrix(res.model.R_WT.T @ truth_model.R_WT).as_rotvec()
    z[lay.free_tracker_rotation] = rot[axes] / res.std[lay.free_tracker_rotation]
    return z


def _commandable(robot, n, seed):
    """Poses the controller can command: its axes uniform in the limits of the joints they drive."""
    jm = robot.joint_map
    rng = np.random.default_rng(seed)
    first = np.argmax(jm.A != 0, axis=0)
    f = jm.A[first, np.arange(jm.A.shape[1])]
    lo, up = np.sort(
        np.stack([(robot.lower[first] - jm.b[first]) / f, (robot.upper[first] - jm.b[first]) / f]), 0
    )
    q = jm.to_model(rng.uniform(lo, up, size=(n, jm.A.shape[1])) * 0.9)
    return np.clip(q, robot.lower, robot.upper)


def test_column8_as_published_loads_from_a_two_line_sidecar():
    assert (ROBOTS / "column8.kpioed.yaml").read_text().count("\n") == 2
    robot = load_robot("column8")
    assert robot.joint_names == ("lift", "lift2", "A1", "A2", "A3", "A4", "A5", "A6")  # no tilt joint
    assert robot.joint_map.axes == ("lift", "A1", "A2", "A3", "A4", "A5", "A6")
    q = robot.joint_map.to_model(np.array([[200.0, 0, 0, 0, 0, 0, 0]]))
    assert_allclose(q[0, :2], [200.0, 100.0])  # lift2 follows lift with multiplier 0.5


def test_column_tree_mimics_follow_a_commanded_joint_off_the_chain():
    """The column as some makers ship it: the commanded prismatic joint drives a pseudo-tip link, the
    chain's two stages mimic it (multiplier 0.5, offsets -0.706 and -0.736 m); a two-line sidecar."""
    assert (ROBOTS / "column_tree.kpioed.yaml").read_text().count("\n") == 2
    robot = load_robot("column_tree")
    assert robot.joint_names[:2] == ("column_lower_joint", "column_middle_joint")
    assert robot.joint_map.axes == ("column_prismatic_joint", "A1", "A2", "A3", "A4", "A5", "A6")
    q = robot.joint_map.to_model(np.array([[1800.0, 0, 0, 0, 0, 0, 0]]))
    assert_allclose(q[0, :2], [0.5 * 1800 - 706, 0.5 * 1800 - 736], rtol=0, atol=1e-9)


def test_a_mimic_of_a_missing_joint_is_refused_naming_it(tmp_path, capsys):
    text = (
        (ROBOTS / "column_tree.urdf")
        .read_text()
        .replace(
            'mimic joint="column_prismatic_joint" multiplier="0.5" offset="-0.736"',
            'mimic joint="column_prism_joint" multiplier="0.5" offset="-0.736"',
        )
    )
    (tmp_path / "c.urdf").write_text(text)
    (tmp_path / "c.kpioed.yaml").write_text("name: c\ntip_link: prism\n")
    assert main(["info", "--robot", str(tmp_path / "c.urdf")]) == 2
    err = capsys.readouterr().err
    assert (
        "c.urdf" in err and "'column_middle_joint' mimic element specifies joint 'column_prism_joint'" in err
    )


@pytest.mark.parametrize("name, n", [("column8", 60), ("fanuc6", 40), ("column_tree", 60)])
def test_simulated_data_recover_the_parameters_within_3_sigma(name, n):
    robot = load_robot(name)
    q = _commandable(robot, n, 0)
    table, truth = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=1))
    data = Measurements.from_table(table, robot, source=name)
    rep = calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=0.02))
    assert rep.result.converged and 0.7 < rep.chi2 / rep.dof < 1.3
    z = _z_scores(rep, truth["model"])
    # measured max |z| 2.47 (column8, 30 parameters), 2.25 (fanuc6, 27) and column_tree (31); pose
    # seeds 1-3 give 3.26, 2.51, 2.19 and 1.39, 1.78, 2.75 (the largest of 27-30 normal scores)
    assert np.max(np.abs(z)) < 3.0, z


def test_a_bad_targets_entry_exits_2_naming_the_field_and_writes_nothing(tmp_path, capsys):
    (tmp_path / "r.urdf").write_text((ROBOTS / "humanoid18.urdf").read_text())
    side = (ROBOTS / "humanoid18.kpioed.yaml").read_text().replace("link: hand_left", "link: left_hand")
    (tmp_path / "r.kpioed.yaml").write_text(side)
    out = tmp_path / "d.csv"
    code = main(
        ["design", "--robot", str(tmp_path / "r.urdf"), "--criterion", "kpi", "--n", "30", "--out", str(out)]
    )
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "r.kpioed.yaml: targets[1].link 'left_hand' is not a link of the URDF" in err


def test_column8_calibrates_and_validates_without_a_working_pose(tmp_path, capsys):
    """The two-line sidecar has no q_work: calibrate takes the measured pose nearest the data's mean
    for the KPI (and says so), writes the model, and validate predicts fresh poses at the noise."""
    robot = load_robot("column8")
    q = _commandable(robot, 100, 0)
    table, _ = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=1))
    table.iloc[:60].to_csv(tmp_path / "fit.csv", index=False)
    table.iloc[60:].to_csv(tmp_path / "fresh.csv", index=False)
    model = str(tmp_path / "c8.urdf")
    assert main(["calibrate", "--robot", "column8", str(tmp_path / "fit.csv"), "--out", model]) == 0
    assert (
        "no working pose (q_work); the KPI is the TCP at the measured pose nearest" in capsys.readouterr().out
    )
    assert (
        main(["validate", "--robot", model, str(tmp_path / "fresh.csv"), "--json", str(tmp_path / "v.json")])
        == 0
    )
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["mean_error_mm"] < 2.0 * 0.02 * np.sqrt(3)  # measured 0.032 mm
