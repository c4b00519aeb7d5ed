"""A written model predicts exactly what the fit that wrote it predicted.

For every effect kind, on a DH table robot (kr16), a tree with a coupled joint (humanoid18: two
hands, t4 follows t2 and t3) and a mimic robot (column8: lift2 a ``<mimic>`` of lift), the fit's
residual of every used row equals ``validate`` with the tracker kept of the file it wrote, on the same
rows. The effects' gravity torques, mass-free bases and pivots are evaluated on the geometry the fit
started from (:mod:`kpioed_drake.robot.reference`), not on the calibrated one the file holds.
"""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml, calibrated_urdf_files
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.validate import predicted_world, validate
from kpioed_drake.cli import main
from kpioed_drake.effects import model_effects
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.kinematics import forward_kinematics
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.robot.urdf.write import sidecar_of
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.study.synthetic import random_poses
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model

HUMANOID = "models/robots/humanoid18.urdf"
COLUMN = "models/robots/column8.urdf"
RTOL = 1e-9
"""The round trip's relative tolerance (what a YAML number's 17 digits and degree conversions leave)."""

# (robot, poses, the truth's effects, the effects fitted); every family at least once per robot kind
CASES = [
    ("kr16", 60, ["joint_elasticity:2", "gear_cyclic:3:1"], None),
    ("kr16", 60, ["backlash:3", "joint_scale:4", "joint_coupling:5:4"], None),
    ("kr16", 60, ["thermal_expansion", "tracker_drift", "tracker_scale"], None),
    ("kr16", 60, ["base_compliance", "lateral_compliance:2"], None),
    (
        "kr16",
        60,
        ["joint_elasticity:2", "joint_elasticity:3"],
        ["joint_elasticity_basis:2", "lateral_compliance_basis:3"],
    ),
    (
        HUMANOID,
        100,
        ["gear_cyclic:4:1", "joint_scale:5"],
        ["gear_cyclic:4:1", "joint_scale:5", "joint_elasticity_basis:2", "lateral_compliance_basis:3"],
    ),
    (
        HUMANOID,
        100,
        ["joint_coupling:4:2", "tracker_drift"],
        ["joint_coupling:4:2", "tracker_drift", "joint_elasticity_basis:9"],
    ),
    (COLUMN, 80, ["joint_elasticity:4", "gear_cyclic:5:1", "column_compliance:1"], None),
    (COLUMN, 80, ["backlash:4", "joint_scale:3", "joint_coupling:7:6", "lateral_compliance:4"], None),
    (COLUMN, 80, ["base_compliance", "thermal_expansion", "tracker_scale"], None),
    (
        COLUMN,
        80,
        ["joint_elasticity:4", "joint_elasticity:5"],
        ["joint_elasticity_basis:4", "lateral_compliance_basis:5"],
    ),
]


def _campaign(tmp_path, robot_name, n, truth, *, seed=1, payload_kg=None, fixed=()):
    """A simulated campaign of ``n`` random poses of ``robot_name`` with the effects ``truth``."""
    robot = load_robot(robot_name)
    q = random_poses(robot, n, np.random.default_rng(seed))
    for j in fixed:  # joints that do not move: parameters the poses cannot determine
        q[:, j] = q[0, j]
    write_design(tmp_path / "d.csv", q, robot=robot)
    sim = ["simulate", "--robot", robot_name, "--design", str(tmp_path / "d.csv"), "--seed", "3"]
    sim += [a for e in truth for a in ("--effect", e)]
    sim += [] if payload_kg is None else ["--payload-kg", str(payload_kg)]
    assert main([*sim, "--out", str(tmp_path / "data.csv")]) == 0
    return tmp_path / "data.csv"


def _round_trip(tmp_path, robot_name, data, fit, suffix):
    """The fit's report and ``validate --keep-tracker`` of the file it wrote, on the same data."""
    out = tmp_path / f"ext{suffix}"
    rep = api.calibrate(robot_name, data, extend=fit, out=out)
    val = api.validate(str(out), data, keep_tracker=True)
    return rep, val, out


def _assert_same_prediction(rep, val):
    used = rep.used
    fit_W = rep.result.residuals[used] @ rep.model.R_WT.T  # the fit's residuals, in W
    assert_allclose(val.residuals_W[used], fit_W, rtol=0.0, atol=RTOL * np.abs(fit_W).max())
    rms = np.sqrt(np.mean(val.residuals_W[used] ** 2))
    assert_allclose(rms, rep.rms_residual_mm, rtol=RTOL)


@pytest.mark.parametrize(("robot_name", "n", "truth", "fit"), CASES, ids=lambda x: str(x)[-24:])
def test_written_model_predicts_what_the_fit_predicted(tmp_path, robot_name, n, truth, fit):
    data = _campaign(tmp_path, robot_name, n, truth)
    suffix = ".urdf" if robot_name.endswith(".urdf") else ".yaml"
    rep, val, out = _round_trip(tmp_path, robot_name, data, fit or truth, suffix)
    assert len(rep.effects) == len(fit or truth) and val.effects == tuple(e.name for e in rep.effects)
    _assert_same_prediction(rep, val)
    written = load_robot(str(out))
    assert written.reference is not None  # its effects are evaluated on the fit's start
    assert_allclose(nominal_model(written, load_cell(robot=written)).geometry, rep.model.geometry, atol=1e-12)


def test_the_reference_geometry_matters(tmp_path):
    """Evaluated on the calibrated geometry instead (the file without its ``estimated_errors``), the
    same effects predict other positions: the round trip above is a test that can fail."""
    data = _campaign(tmp_path, "kr16", 60, ["joint_elasticity:2", "joint_elasticity:3"])
    rep, val, out = _round_trip(tmp_path, "kr16", data, ["joint_elasticity:2", "joint_elasticity:3"], ".yaml")
    written = load_robot(str(out))
    assert np.abs(written.geometry - written.reference.robot.geometry).max() > 1e-5  # the fit moved it
    bare = dataclasses.replace(written, estimated_errors=None)
    assert bare.reference is None
    p_bare, p_file = (
        predicted_world(nominal_model(r, load_cell(robot=r)), val.data, model_effects(r))
        for r in (bare, written)
    )
    assert np.abs(p_bare - p_file).max() > 1e-6


def test_payload_round_trip(tmp_path):
    """With a payload, the gravity torques act at the point the fit used (``payload_point_mm``, the
    start's reflector offset), in the fit and in the file alike."""
    data = _campaign(tmp_path, "kr16", 60, ["joint_elasticity:2", "base_compliance"], payload_kg=12)
    rep, val, out = _round_trip(tmp_path, "kr16", data, ["joint_elasticity:2", "base_compliance"], ".yaml")
    _assert_same_prediction(rep, val)
    written = load_robot(str(out))
    assert_allclose(written.payload_point, load_cell(robot=load_robot("kr16")).p_FQ, atol=1e-12)
    assert np.abs(written.p_FQ - written.payload_point).max() > 1e-3  # the reflector was estimated


def test_held_tracker_and_reflector_parameters_round_trip(tmp_path):
    """Poses with joints 1 and 6 fixed leave tracker and reflector parameters undetermined; the fit
    holds them and the model it writes still predicts what the fit did."""
    data = _campaign(tmp_path, "kr16", 80, ["joint_elasticity:2"], seed=4, fixed=(0, 5))
    rep, val, _ = _round_trip(tmp_path, "kr16", data, ["joint_elasticity:2"], ".yaml")
    held = rep.identifiability["at_nominal"] + rep.identifiability["at_solution"]
    assert any(h.startswith("tracker_") for h in held) and any(h.startswith("reflector_") for h in held)
    _assert_same_prediction(rep, val)


def test_a_reference_urdf_is_its_plant_and_gives_the_calibrated_frames(tmp_path):
    """The reference of a calibrated URDF (its errors folded out of the joints) is one geometry: its
    numpy chain is the plant Drake parses of its text, and with the errors it has the file's frames."""
    data = _campaign(tmp_path, HUMANOID, 100, ["gear_cyclic:4:1"])
    _, _, out = _round_trip(tmp_path, HUMANOID, data, ["gear_cyclic:4:1"], ".urdf")
    written = load_robot(str(out))
    ref = written.reference
    assert np.abs(ref.geometry).max() > 1e-6
    q = random_poses(written, 6, np.random.default_rng(7))
    cal, back = forward_kinematics(written, q), forward_kinematics(ref.robot, q, ref.geometry)
    assert_allclose(back.o, cal.o, atol=1e-9)
    assert_allclose(back.R, cal.R, atol=1e-12)
    scene, nominal = build_scene(ref.robot), forward_kinematics(ref.robot, q)
    for k in range(len(q)):
        scene.set_q(q[k])
        for i in range(ref.robot.n_joints + 1):
            assert_allclose(scene.X_WB(i).translation() / MM, nominal.o[k, i], atol=1e-9)


def test_bad_estimated_errors_name_the_file_and_field(tmp_path, capsys):
    data = _campaign(tmp_path, "kr16", 60, ["joint_elasticity:2"])
    _, _, out = _round_trip(tmp_path, "kr16", data, ["joint_elasticity:2"], ".yaml")
    text = out.read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("estimated_errors:\n- [", "estimated_errors:\n- [.nan, ", 1))
    assert main(["validate", "--robot", str(bad), str(data)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml: estimated_errors" in err and "finite" in err


def test_a_diagnosis_of_an_extended_urdf_file_fits_on_its_reference(tmp_path):
    """``diagnose --robot ext.urdf`` fits on the robot the file's fit started from (its estimated
    errors folded out), so its geometric fit is the nominal robot's to the last digits, not a fit whose
    errors are counted twice."""
    data = _campaign(tmp_path, HUMANOID, 100, ["gear_cyclic:4:1"])
    _round_trip(tmp_path, HUMANOID, data, ["gear_cyclic:4:1"], ".urdf")
    nominal = api.diagnose(HUMANOID, data).to_json()["baseline"]
    from_file = api.diagnose(str(tmp_path / "ext.urdf"), data).to_json()["baseline"]
    assert_allclose(from_file["rms_mm"], nominal["rms_mm"], rtol=1e-9)


def test_a_design_problem_of_an_extended_urdf_file_has_its_calibrated_frames(tmp_path):
    """The design problem of an extended URDF file is made at the file's calibrated geometry, the one
    its feasibility checker's plant has (not the reference's errors applied twice)."""
    data = _campaign(tmp_path, HUMANOID, 100, ["gear_cyclic:4:1"])
    _, _, out = _round_trip(tmp_path, HUMANOID, data, ["gear_cyclic:4:1"], ".urdf")
    written = load_robot(str(out))
    problem = make_problem(written)
    assert problem.robot is problem.model.robot
    q = random_poses(written, 4, np.random.default_rng(8))
    frames = forward_kinematics(problem.robot, q, problem.model.geometry)
    assert_allclose(frames.o, forward_kinematics(written, q).o, atol=1e-9)


@pytest.mark.parametrize("robot_name", ["ur10", "lift7"])
def test_pose_model_round_trip(tmp_path, robot_name):
    """6-DoF probe data: the written model keeps the probe's orientation (``probe_rpy_deg``), so that
    validate with the tracker kept of the fit's own rows reproduces the fit's position and orientation
    residuals (in W) to 1e-9 (ur10: a YAML table; lift7: a URDF chain with a prismatic joint)."""
    robot = load_robot(robot_name)
    q = random_poses(robot, 60, np.random.default_rng(4))
    table, truth = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=5, orientation_sigma_deg=0.01))
    data = Measurements.from_arrays(q, table[["x_mm", "y_mm", "z_mm"]].to_numpy(), R_TP=truth["R_TP"])
    report = calibrate(robot, data, CalibrationOptions(sigma_mm=0.02, sigma_deg=0.01, outlier_alpha=0))
    if robot.urdf is None:
        path = tmp_path / "cal.yaml"
        path.write_text(calibrated_robot_yaml(report))
    else:
        path = tmp_path / "cal.urdf"
        urdf, side = calibrated_urdf_files(report)
        path.write_text(urdf)
        sidecar_of(path).write_text(side)
    written = load_robot(str(path))
    assert written.R_FP is not None
    val = validate(written, data, tracker_frame="kept")
    R_WT = report.model.R_WT
    assert_allclose(val.residuals_W, report.result.residuals @ R_WT.T, rtol=0, atol=RTOL * robot.reach)
    assert_allclose(val.rot_residuals_W, report.result.rot_residuals @ R_WT.T, rtol=0, atol=RTOL)
    assert np.abs(val.rot_residuals_W).max() > 1e-5  # the noise, not zero
    fit, held_out = report.orientation_figures(), val.orientation_figures()
    assert fit is not None and held_out is not None
    assert_allclose(held_out.mean_error_deg, fit.mean_error_deg, rtol=1e-8)
