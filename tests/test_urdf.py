"""URDF robots end to end: the UR5 twin calibrates like the YAML, lift7 (7 joints, a prismatic column)
designs, simulates and calibrates, gravity follows the base orientation, and bad URDF or sidecar
files exit 2 naming the file and element without writing anything."""

import json
import re
import shutil

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from kpioed_drake import calibration, simulation
from kpioed_drake.calibration.modelfile import calibrated_urdf_files
from kpioed_drake.cli import main
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.diagnosis import candidate_effects
from kpioed_drake.effects.gravity import gravity_torques
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.kinematics import forward_kinematics
from kpioed_drake.robot.models import MODELS_DIR, load_cell, load_robot
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.tracker.data import Measurements, read_measurements
from kpioed_drake.tracker.measurement import measure, nominal_model

ROBOTS = MODELS_DIR / "robots"
UR5_URDF = (ROBOTS / "ur5.urdf").read_text()
LIMIT = '<limit lower="-6.2831853071795862" upper="6.2831853071795862" effort="150" velocity="3.15"/>'


def _z_scores(rep, truth_model):
    res = rep.result
    z = (res.model.p[res.free] - truth_model.p[res.free]) / res.std
    r = res.model.layout.free_tracker_rotation
    z[r] = Rotation.from_matrix(res.model.R_WT.T @ truth_model.R_WT).as_rotvec() / res.std[r]
    return z


def test_twin_calibrates_the_same_data_as_the_yaml():
    """Noise-only data (the true robot is the nominal one, which both models contain): the same fit."""
    ur5, twin = load_robot("ur5"), load_robot(str(ROBOTS / "ur5.urdf"))
    q = np.random.default_rng(0).uniform(ur5.lower, ur5.upper, size=(40, 6))
    table, _ = simulation.simulate(
        ur5, q, simulation.SimulationOptions(sigma_mm=0.02, seed=1, geometric_errors=False)
    )
    a = calibration.calibrate(
        ur5, Measurements.from_table(table, ur5), calibration.CalibrationOptions(sigma_mm=0.02)
    )
    b = calibration.calibrate(
        twin, Measurements.from_table(table, twin), calibration.CalibrationOptions(sigma_mm=0.02)
    )
    assert a.result.converged and b.result.converged and a.dof == b.dof
    assert b.chi2 == pytest.approx(a.chi2, rel=1e-6)
    assert np.abs(b.kpi - a.kpi).max() < 1e-6
    assert np.trace(b.kpi_cov) == pytest.approx(np.trace(a.kpi_cov), rel=1e-6)


def test_lift7_recovers_the_true_parameters():
    robot = load_robot("lift7")
    q = heuristic_design(make_problem(robot, sigma_mm=0.02), n=40, seed=1)
    table, truth = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=0))
    rep = calibration.calibrate(
        robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=0.02)
    )
    assert rep.result.converged and rep.warnings == []
    assert rep.result.free.size == 29
    z = _z_scores(rep, truth["model"])
    assert np.max(np.abs(z)) < 3.0, z  # measured 2.08 (seeds 1-4: 2.26, 2.27, 1.93, 1.57)


@pytest.mark.slow
def test_lift7_cli_design_simulate_calibrate(tmp_path, capsys):
    d, m, c, t = (str(tmp_path / n) for n in ("d.csv", "m.csv", "c.json", "t.json"))
    # the certificate (a search of its own for lift7) is tests/test_design_start.py's
    assert (
        main(["design", "--robot", "lift7", "--criterion", "kpi", "--n", "12", "--no-certify", "--out", d])
        == 0
    )
    header = open(d).readline().strip().split(",")
    assert header[:7] == ["q1_mm"] + [f"q{i}_deg" for i in range(2, 8)]
    out = capsys.readouterr().out
    assert re.search(r"independent check: 12/12 poses feasible; 0 pose\(s\) collide", out), out
    assert main(["simulate", "--robot", "lift7", "--design", d, "--out", m, "--truth", t, "--seed", "2"]) == 0
    data = read_measurements(m, load_robot("lift7"))
    assert data.q.shape == (12, 7) and 0.0 <= data.q[:, 0].min() and data.q[:, 0].max() <= 500.0
    cal = str(tmp_path / "cal.urdf")
    assert main(["calibrate", "--robot", "lift7", m, "--json", c, "--out", cal, "--force"]) == 0
    rep = json.loads(open(c).read())
    assert rep["converged"] and rep["n_poses"] == 12
    # the calibrated model file (URDF + sidecar) predicts what the calibration's model predicts
    report = calibration.calibrate(load_robot("lift7"), data, calibration.CalibrationOptions(force=True))
    again = load_robot(cal)
    assert again.gauge == load_robot("lift7").gauge and again.p_FQ is not None
    model = nominal_model(again, load_cell(robot=again))
    assert np.abs(measure(model, data.q) - measure(report.model, data.q)).max() < 1e-8
    # a YAML file is refused for a URDF robot, before any work and without writing
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["calibrate", "--robot", "lift7", m, "--out", str(tmp_path / "x.yaml")]) == 2
    assert "is a URDF robot" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def _sideways(tmp_path):
    (tmp_path / "ur5s.urdf").write_text(UR5_URDF)
    side = (ROBOTS / "ur5.kpioed.yaml").read_text() + "base_rpy_deg: [90.0, 0.0, 0.0]\n"
    (tmp_path / "ur5s.kpioed.yaml").write_text(side.replace("name: ur5-urdf", "name: ur5-sideways"))
    return load_robot(str(tmp_path / "ur5s.urdf"))


def test_gravity_follows_the_base_orientation(tmp_path):
    upright, side = load_robot(str(ROBOTS / "ur5.urdf")), _sideways(tmp_path)
    q = np.random.default_rng(4).uniform(upright.lower, upright.upper, size=(30, 6))
    assert np.abs(gravity_torques(upright, q)[:, 0]).max() < 1e-9
    tau = gravity_torques(side, q)
    assert np.abs(tau[:, 0]).max() > 10.0  # [N m]: joint 1 horizontal, the arm's weight turns it
    data = Measurements.from_arrays(q, np.zeros((30, 3)), source="x")
    names = [e.name for e in candidate_effects(data, tau=tau)[0]]
    assert "joint_elasticity:1" in names
    names, notes = candidate_effects(data, tau=gravity_torques(upright, q))
    assert "joint_elasticity:1" not in [e.name for e in names] and any("joint 1" in n for n in notes)


BAD = {
    "malformed": ("<robot name='x'><link name='a'></robot>", r"malformed URDF \(XML error at line 1"),
    "not_urdf": ("<sdf/>", r"not a URDF"),
    "floating": (
        UR5_URDF.replace('name="elbow_joint" type="revolute"', 'name="elbow_joint" type="floating"'),
        r"joint 'elbow_joint': type 'floating' is not supported",
    ),
    "planar": (
        UR5_URDF.replace('name="wrist_1_joint" type="revolute"', 'name="wrist_1_joint" type="planar"'),
        r"joint 'wrist_1_joint': type 'planar'",
    ),
    "branch": (
        UR5_URDF.replace(
            "</robot>",
            '<link name="extra"/><joint name="side" type="revolute"><parent link="upper_arm_link"/>'
            '<child link="extra"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>'
            "</joint></robot>",
        ),
        r"link 'upper_arm_link': the tree branches",
    ),
    "no_parent": (
        UR5_URDF.replace('<parent link="forearm_link"/>', ""),
        r"joint 'wrist_1_joint': needs <parent",
    ),
    "bad_origin": (
        UR5_URDF.replace('xyz="-0.42499999999999999 0 0"', 'xyz="a b c"'),
        r"joint 'elbow_joint': xyz='a b c' is not a list of numbers",
    ),
    "prismatic_no_limits": (
        UR5_URDF.replace('name="elbow_joint" type="revolute"', 'name="elbow_joint" type="prismatic"').replace(
            LIMIT + '</joint>\n  <joint name="wrist_1_joint"',
            '</joint>\n  <joint name="wrist_1_joint"',
        ),
        r"prismatic joint 'elbow_joint' has no limits; give them in .*bad\.kpioed\.yaml",
    ),
}
BAD_SIDECAR = {
    "sidecar_unknown_field": ("reflector_offset_mm: [0, 0, 1]\n", r"bad\.kpioed\.yaml"),
    "sidecar_q_work": ("q_work: [0, 0, 0]\n", r"bad\.kpioed\.yaml: q_work: expected 6"),
    "sidecar_limit_joint": (
        "limits: [{joint: A9, lower: 0, upper: 1}]\n",
        r"limits: unknown joints \['A9'\]",
    ),
    "sidecar_capsule_link": (
        "capsules: [{link: 9, radius_mm: 10, a_mm: [0,0,0], b_mm: [0,0,1]}]\n",
        r"link must",
    ),
    "sidecar_pairs": ("self_collision_pairs: [[2, 3]]\n", r"self_collision_pairs"),
    "sidecar_mass_link": ("masses: [{link: 0, mass_kg: 1.0}]\n", r"masses\[0\]: link must be in 1..6"),
    "sidecar_mass_nan": (
        "masses: [{link: 2, mass_kg: .nan}]\n",
        r"masses\[0\]\.mass_kg: expected a finite number",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD) + sorted(BAD_SIDECAR))
def test_bad_urdf_or_sidecar_exits_2_and_writes_nothing(case, tmp_path, capsys):
    urdf, side = (BAD[case], None) if case in BAD else ((UR5_URDF, None), BAD_SIDECAR[case][0])
    text, pattern = (urdf[0], urdf[1]) if case in BAD else (UR5_URDF, BAD_SIDECAR[case][1])
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    if side is not None:
        (tmp_path / "bad.kpioed.yaml").write_text(side)
    shutil.copy(ROBOTS / "ur5.urdf", tmp_path / "good.urdf")
    design = tmp_path / "design.csv"
    design.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,-90,90,0,0,0\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    for argv in (
        ["info", "--robot", str(path)],
        ["simulate", "--robot", str(path), "--design", str(design), "--out", str(tmp_path / "m.csv")],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err
        line = [ln for ln in err.splitlines() if ln.startswith("kpioed:")][-1]
        assert str(tmp_path / "bad") in line and re.search(pattern, line), line
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_continuous_joints_take_the_sidecar_limits_or_one_turn(tmp_path):
    text = UR5_URDF.replace('name="wrist_3_joint" type="revolute"', 'name="wrist_3_joint" type="continuous"')
    (tmp_path / "c.urdf").write_text(text)
    robot = load_robot(str(tmp_path / "c.urdf"))
    assert robot.upper[5] == pytest.approx(2 * np.pi)  # URDF limits of a continuous joint are ignored
    (tmp_path / "c.kpioed.yaml").write_text("limits: [{joint: wrist_3_joint, lower: -90, upper: 270}]\n")
    robot = load_robot(str(tmp_path / "c.urdf"))
    assert np.rad2deg([robot.lower[5], robot.upper[5]]) == pytest.approx([-90.0, 270.0])


def test_sidecar_masses_override_the_urdf(tmp_path):
    (tmp_path / "m.urdf").write_text(UR5_URDF)
    (tmp_path / "m.kpioed.yaml").write_text(
        "masses: [{link: 2, mass_kg: 16.786, com_mm: [-100.0, 0.0, 136.0]}]\n"
    )
    heavy, ur5 = load_robot(str(tmp_path / "m.urdf")), load_robot(str(ROBOTS / "ur5.urdf"))
    assert heavy.masses[2] == pytest.approx(2 * ur5.masses[2]) and heavy.masses[3] == ur5.masses[3]
    assert heavy.coms[2] == pytest.approx([-100.0, 0.0, 136.0])
    q = np.random.default_rng(5).uniform(ur5.lower, ur5.upper, size=(5, 6))
    d = gravity_torques(heavy, q) - gravity_torques(ur5, q)
    assert np.abs(d[:, 1]).max() > 0.5 and np.abs(d[:, 2:]).max() < 1e-9  # joints beyond link 2 unchanged


def test_world_weld_fixed_joints_and_side_branches(tmp_path):
    """A URDF welded to "world" (tilted), a fixed joint inside the chain and a fixed tool0 leaf:
    the same chain as the sidecar's base pose, and the numpy kinematics agree with the parsed plant."""
    text = UR5_URDF.replace(
        '<robot name="ur5">',
        '<robot name="ur5"><link name="world"/><joint name="weld" type="fixed"><parent link="world"/>'
        '<child link="base_link"/><origin xyz="0.1 0.2 0.3" rpy="1.5707963267948966 0 0"/></joint>',
    )
    text = text.replace('<parent link="forearm_link"/>', '<parent link="forearm_mount"/>').replace(
        "</robot>",
        '<link name="forearm_mount"/><joint name="mount" type="fixed"><parent link="forearm_link"/>'
        '<child link="forearm_mount"/><origin xyz="0 0 0" rpy="0 0 0.3"/></joint>'
        '<link name="tool0"/><joint name="tool" type="fixed"><parent link="wrist_3_link"/>'
        '<child link="tool0"/><origin xyz="0 0 0.05" rpy="0 0 0"/></joint></robot>',
    )
    text = text.replace(
        '<origin xyz="-0.39224999999999999 0 0" rpy="0 0 0"/><axis',
        # the same joint frame in the mount's frame: Rz(-0.3) (-392.25, 0, 0) mm, turned back by 0.3 rad
        '<origin xyz="-0.37473073785951894 0.11591780106291043 0" rpy="0 0 -0.3"/><axis',
    )
    (tmp_path / "w.urdf").write_text(text)
    welded = load_robot(str(tmp_path / "w.urdf"))
    (tmp_path / "s.urdf").write_text(UR5_URDF)
    (tmp_path / "s.kpioed.yaml").write_text("base_xyz_mm: [100, 200, 300]\nbase_rpy_deg: [90, 0, 0]\n")
    side = load_robot(str(tmp_path / "s.urdf"))
    assert welded.n_joints == 6 and welded.joint_names == side.joint_names
    q = np.random.default_rng(6).uniform(side.lower, side.upper, size=(10, 6))
    fw, fs = forward_kinematics(welded, q), forward_kinematics(side, q)
    assert_allclose(fw.o, fs.o, atol=1e-9)
    assert_allclose(fw.R, fs.R, atol=1e-12)
    scene = build_scene(welded)
    for k in range(len(q)):
        scene.set_q(q[k])
        for i in range(7):
            assert_allclose(scene.X_WB(i).translation() / MM, fw.o[k, i], atol=1e-9)
    # the sideways base: gravity now loads joint 1
    assert np.abs(gravity_torques(welded, q)[:, 0]).max() > 10.0


def test_sidecar_capsules_replace_the_urdf_geometry(tmp_path):
    (tmp_path / "c.urdf").write_text(UR5_URDF)
    side = "capsules: [{link: 2, name: arm, radius_mm: 50, a_mm: [0, 0, 136], b_mm: [-425, 0, 136]}]\n"
    (tmp_path / "c.kpioed.yaml").write_text(side)
    robot = load_robot(str(tmp_path / "c.urdf"))
    assert [(c.name, c.frame, c.radius) for c in robot.capsules] == [("arm", 2, 50.0)]
    assert len(load_robot(str(ROBOTS / "ur5.urdf")).capsules) == 7  # the URDF's cylinders


def test_several_targets_of_a_urdf_robot(tmp_path):
    """targets_mm in the sidecar: the gauge sees every target (target 1 on joint 6's axis, the others
    off it: joint 6's wrist parameters are determined again), simulated data calibrates within 3
    sigma, and the calibrated URDF model keeps the targets."""
    (tmp_path / "t.urdf").write_text(UR5_URDF)
    side = "targets_mm: [[0, 0, 31], [60, 80, 40], [-40, 100, 30]]\n"
    (tmp_path / "t.kpioed.yaml").write_text(side + "q_work: [19.2, -63.3, 102.2, -41.1, 99.3, -0.9]\n")
    robot = load_robot(str(tmp_path / "t.urdf"))
    assert robot.n_targets == 3 and "off6" in robot.gauge  # turning joint 6 turns all free targets
    lay = nominal_model(robot, load_cell(robot=robot)).layout
    assert lay.n_free == 27 + 6  # 27 with one target off every axis, plus 3 for each further target
    q = np.random.default_rng(8).uniform(robot.lower, robot.upper, size=(30, 6))
    table, truth = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=3))
    rep = calibration.calibrate(
        robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=0.02)
    )
    assert rep.result.converged and np.max(np.abs(_z_scores(rep, truth["model"]))) < 3.0
    urdf, side_text = calibrated_urdf_files(rep)
    (tmp_path / "c.urdf").write_text(urdf)
    (tmp_path / "c.kpioed.yaml").write_text(side_text)
    again = load_robot(str(tmp_path / "c.urdf"))
    assert again.n_targets == 3
    assert_allclose(again.targets, rep.model.target_offsets, atol=1e-9)


def test_a_missing_sidecar_field_names_the_sidecar(tmp_path, capsys):
    (tmp_path / "n.urdf").write_text(UR5_URDF)  # no sidecar: no working pose
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["design", "--robot", str(tmp_path / "n.urdf"), "--criterion", "kpi", "--n", "10"]
    assert main(argv + ["--out", str(tmp_path / "d.csv")]) == 2
    assert "no q_work in its sidecar; pass --q-work" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_sidecar_joint_map(tmp_path):
    (tmp_path / "j.urdf").write_text(UR5_URDF)
    (tmp_path / "j.kpioed.yaml").write_text(
        "joint_map: {sign: [1, -1, 1, 1, 1, 1], offset_deg: [0, 90, 0, 0, 0, 0]}\n"
    )
    robot = load_robot(str(tmp_path / "j.urdf"))
    assert_allclose(robot.joint_map.to_model(np.zeros((1, 6)))[0], np.deg2rad([0, 90, 0, 0, 0, 0]))
    shutil.copy(ROBOTS / "lift7.urdf", tmp_path / "l.urdf")
    (tmp_path / "l.kpioed.yaml").write_text("joint_map: {sign: [1, -1, 1, 1, 1, 1]}\n")
    with pytest.raises(InputError, match=r"l\.kpioed\.yaml: joint_map with sign.*use controller_axes"):
        load_robot(str(tmp_path / "l.urdf"))
