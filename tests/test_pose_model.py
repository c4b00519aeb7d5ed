"""The orientation part of a 6-DoF probe's measurement (tracker/orientation.py): residual and
Jacobian against finite differences (kr16 DH, ur10, the lift7 URDF chain with a prismatic joint),
the first registration of the probe, the layout's probe segment and the gauge with orientations."""

import dataclasses

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.validate import validate
from kpioed_drake.cli import main
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.options import DesignOptions
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import estimate
from kpioed_drake.estimation.identifiability import check_identifiability
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.robot.parameters import PROBE_NAMES, parameter_layout
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import ORIENTATION_COLUMNS, simulate
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import measurement_jacobian, nominal_model
from kpioed_drake.tracker.orientation import (
    angular_jacobian,
    angular_jacobian_dq,
    chordal_mean,
    inverse_right_jacobian,
    orientation_jacobian,
    orientation_residuals,
    probe_orientation,
    registered_probe,
    rotation_log,
    with_probe,
)


def _model(name, seed):
    """A probe model of ``name`` with random errors on every parameter (tracker and probe rotations
    included) and a random probe orientation on the flange."""
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    model = with_probe(
        nominal_model(robot, load_cell(robot=robot)), Rotation.random(random_state=seed).as_matrix()
    )
    p = model.p.copy()
    angle = model.layout.is_angle
    p += np.where(angle, rng.normal(0, 0.01, p.size), rng.normal(0, 0.5, p.size))
    return model.with_params(p)


def _poses(robot, n, seed):
    return np.random.default_rng(seed).uniform(robot.lower, robot.upper, size=(n, robot.n_joints))


@pytest.mark.parametrize("name", ["kr16", "ur10", "lift7"])
def test_orientation_jacobian_matches_finite_differences(name):
    model = _model(name, 3)
    q = _poses(model.robot, 7, 4)
    rng = np.random.default_rng(5)
    R_meas = Rotation.from_rotvec(rng.normal(0, 0.3, (7, 3))).as_matrix() @ probe_orientation(model, q)
    e, H = orientation_jacobian(model, q, R_meas)
    assert np.all(np.linalg.norm(e, axis=1) > 0.05)  # residuals far from zero: Jr^-1 matters
    h = 1e-6
    fd = np.empty_like(H)
    for k in range(model.p.size):
        dp = np.zeros(model.p.size)
        dp[k] = h
        ep = orientation_residuals(model.with_params(model.p + dp), q, R_meas)
        em = orientation_residuals(model.with_params(model.p - dp), q, R_meas)
        fd[:, :, k] = -(ep - em) / (2 * h)  # de/dp = -H
    assert_allclose(H, fd, atol=1e-7, rtol=1e-6)
    lay = model.layout
    assert not np.any(H[:, :, lay.tracker_position]) and not np.any(H[:, :, lay.targets])
    assert np.abs(H[:, :, lay.probe_rotation]).max() > 0.5


def test_inverse_right_jacobian_near_zero_and_log_round_trip():
    rng = np.random.default_rng(1)
    e = np.concatenate([rng.normal(0, 1e-6, (3, 3)), rng.normal(0, 1.0, (3, 3))])
    Jinv = inverse_right_jacobian(e)
    d = rng.normal(0, 1e-7, (6, 3))
    R = Rotation.from_rotvec(e).as_matrix() @ Rotation.from_rotvec(d).as_matrix()
    assert_allclose(rotation_log(R) - e, np.einsum("nab,nb->na", Jinv, d), atol=1e-12)


def test_registered_probe_recovers_the_probe_orientation_from_exact_data():
    model = _model("kr16", 8)
    q = _poses(model.robot, 10, 9)
    R_TP = probe_orientation(model, q)
    start = registered_probe(with_probe(model.rebased(), np.eye(3)), q, R_TP)
    assert_allclose(start.R_FP_ref, model.rebased().R_FP, atol=1e-12)
    assert_allclose(orientation_residuals(start, q, R_TP), 0.0, atol=1e-12)
    Rs = Rotation.from_rotvec(np.random.default_rng(2).normal(0, 0.01, (50, 3))).as_matrix()
    assert np.linalg.norm(rotation_log(chordal_mean(Rs)[None])) < 0.01


def test_probe_layout_appends_three_rotations_and_drops_the_points_gauge():
    ur10 = load_robot("ur10")
    points = parameter_layout(ur10)
    pose = parameter_layout(ur10, probe=True)
    assert pose.names[: points.size] == points.names and pose.names[points.size :] == PROBE_NAMES
    assert {"theta5", "alpha5"} <= set(ur10.extra_gauge)
    assert {"theta5", "alpha5"} <= set(pose.free_names) and not {"theta5", "alpha5"} & set(points.free_names)
    assert pose.n_free == points.n_free + 3 + 2
    assert pose.is_angle[pose.probe_rotation].all() and points.probe_rotation == slice(
        points.size, points.size
    )


@pytest.mark.parametrize("name", ["kr16", "lift7"])
def test_pose_rows_determine_every_free_parameter_of_the_gauge(name):
    """With orientations, the free set of the probe layout has full rank on generic poses (nothing
    more to hold), and the probe model's position rows are the point model's."""
    model = _model(name, 11)
    q = _poses(model.robot, 40, 12)
    lay = model.layout
    _, H = measurement_jacobian(model, q)
    _, Hr = orientation_jacobian(model, q, probe_orientation(model, q))
    A = np.concatenate(
        [H[:, :, lay.free].reshape(-1, lay.n_free), 1000 * Hr[:, :, lay.free].reshape(-1, lay.n_free)]
    )
    A = A / np.linalg.norm(A, axis=0)
    s = np.linalg.svd(A, compute_uv=False)
    assert s[-1] > 1e-6 * s[0]


def test_chain_gauge_with_orientations():
    """lift7: the automatic gauge chosen on positions and orientations (the tracker's rotation turns
    the measured frame the opposite way) holds what the points' gauge holds: the probe's full pose
    on the last link absorbs what its point absorbed, and with the wrong sign of the tracker's
    orientation columns the base rotations rx1, ry1, rz1 would wrongly be freed."""
    robot = load_robot("lift7")
    assert robot.pose_gauge == robot.gauge
    assert {"rx1", "ry1", "rz1"} <= set(robot.pose_gauge)


# --- simulate -> calibrate ------------------------------------------------------------------------
def _pose_data(name, n, seed, *, orientation_sigma_deg=0.01, sigma_mm=0.02):
    """Simulated pose data of ``n`` random poses (``simulate`` with orientations) as Measurements
    (the Euler columns read as the UR10 files are: intrinsic XYZ), and the truth."""
    robot = load_robot(name)
    q = _poses(robot, n, seed)
    options = SimulationOptions(sigma_mm=sigma_mm, seed=seed, orientation_sigma_deg=orientation_sigma_deg)
    table, truth = simulate(robot, q, options)
    data = Measurements.from_table(table, robot)  # the native quaternion columns
    assert data.R_TP is not None
    return robot, data, truth


def _z_scores(report, truth):
    """Estimate minus truth over the a-priori std of every estimated parameter (the tracker's and the
    probe's small rotations as the rotation between the estimated and the true frame)."""
    res, true = report.result, truth["model"]
    lay = res.model.layout
    d = res.model.p - true.p
    d[lay.tracker_rotation] = rotation_log((true.R_WT.T @ res.model.R_WT)[None])[0]
    d[lay.probe_rotation] = rotation_log((res.model.R_FP @ true.R_FP.T)[None])[0]
    return dict(zip(lay.free_names, d[lay.free] / res.std[: lay.n_free], strict=True))


@pytest.mark.parametrize("name", ["kr16", "ur10"])
def test_simulate_then_calibrate_recovers_the_truth_within_three_sigma(name):
    robot, data, truth = _pose_data(name, 60, 7)
    report = calibrate(robot, data, CalibrationOptions(sigma_mm=0.02, sigma_deg=0.01))
    z = _z_scores(report, truth)
    assert report.result.converged and not report.held_at_nominal
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert 0.5 < np.mean(np.square(list(z.values()))) < 1.6
    assert 0.8 < report.chi2_per_dof < 1.2
    fig = report.orientation_figures()
    assert fig is not None and 0.005 < fig.rms_deg < 0.015  # the 0.01 deg noise, per component
    assert set(PROBE_NAMES) <= set(report.model.layout.free_names)


def test_orientations_determine_what_an_on_axis_point_leaves_undetermined():
    """ur10, probe origin on joint 6's axis (the model file's reflector (0, 0, 93) mm): positions alone
    hold theta5 and alpha5 (the file's extra gauge; without it the rank test finds them), the
    orientation rows estimate them within 3 sigma of the truth."""
    robot, data, truth = _pose_data("ur10", 60, 21)
    points = Measurements.from_arrays(data.q, data.eta)
    by_points = calibrate(robot, points, CalibrationOptions(sigma_mm=0.02))
    assert {"theta5", "alpha5"} & set(by_points.model.layout.free_names) == set()
    loose = dataclasses.replace(robot, extra_gauge=())
    unheld = calibrate(loose, points, CalibrationOptions(sigma_mm=0.02))
    assert {"theta5", "alpha5"} & set(unheld.held_at_nominal)
    by_pose = calibrate(robot, data, CalibrationOptions(sigma_mm=0.02, sigma_deg=0.01))
    z = _z_scores(by_pose, truth)
    assert abs(z["theta5"]) < 3 and abs(z["alpha5"]) < 3
    names = by_pose.model.layout.names
    for n in ("theta5", "alpha5"):  # the truth's errors there are far beyond the estimate's std
        i = names.index(n)
        error = truth["model"].p[i] - by_pose.nominal.p[i]
        assert abs(error) > 5 * by_pose.result.std[list(by_pose.model.layout.free).index(i)]


# --- what pose data refuse or note ------------------------------------------------------------------
def test_effects_and_diagnosis_refuse_pose_data_with_a_clear_message():
    robot, data, _ = _pose_data("kr16", 40, 3)
    with pytest.raises(InputError, match="orientations, and non-geometric effects"):
        calibrate(robot, data, CalibrationOptions(effects=("joint_elasticity:2",)))
    with pytest.raises(InputError, match="orientations, which the diagnosis"):
        diagnose(robot, data)
    with pytest.raises(InputError, match="orientation_sigma_deg with non-geometric effects"):
        simulate(
            robot, data.q, SimulationOptions(orientation_sigma_deg=0.01, effects=("joint_elasticity:2",))
        )


def test_validate_notes_orientations_a_model_cannot_predict():
    robot, data, _ = _pose_data("kr16", 40, 3)
    report = validate(robot, data, tracker_frame="cross")
    assert report.rot_residuals_W is None and report.orientation_figures() is None
    assert any("6-DoF orientations are not scored" in n for n in report.notes)


def test_simulate_cli_writes_the_orientation_columns(tmp_path):
    robot = load_robot("kr16")
    write_design(tmp_path / "d.csv", _poses(robot, 12, 1), robot=robot)
    args = [
        "simulate",
        "--robot",
        "kr16",
        "--design",
        str(tmp_path / "d.csv"),
        "--out",
        str(tmp_path / "o.csv"),
    ]
    assert main([*args, "--orientation-sigma-deg", "0"]) == 0
    table = pd.read_csv(tmp_path / "o.csv")
    assert list(table.columns[6:13]) == ["x_mm", "y_mm", "z_mm", *ORIENTATION_COLUMNS]
    qw, qx, qy, qz = table[list(ORIENTATION_COLUMNS)].to_numpy().T
    R = Rotation.from_quat(np.column_stack([qx, qy, qz, qw])).as_matrix()  # scipy: scalar last
    assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert main(args[:-1] + [str(tmp_path / "p.csv")]) == 0
    assert "qw" not in pd.read_csv(tmp_path / "p.csv")  # points only without the option


@pytest.mark.parametrize("name", ["kr16", "lift7"])
def test_angular_jacobian_dq_matches_finite_differences(name):
    model = _model(name, 13)
    q = _poses(model.robot, 5, 14)
    dOm = angular_jacobian_dq(model, q)
    h = 1e-6
    for j in range(model.robot.n_joints):
        dq = np.zeros_like(q)
        dq[:, j] = h
        fd = (angular_jacobian(model, q + dq) - angular_jacobian(model, q - dq)) / (2 * h)
        assert_allclose(dOm[:, j], fd, atol=1e-7, rtol=1e-6)
    assert np.abs(dOm).max() > 0.1


# --- the design problem with pose measurements ---------------------------------------------------
def test_pose_problem_rows_and_their_dq_against_finite_differences():
    """F1 of pose measurements: per pose 3 position rows (the point problem's, with zero probe
    columns) then 3 orientation rows over sigma_rot; dF1/dq against finite differences."""
    pose = make_problem("ur10", measure="pose", sigma_mm=0.02, sigma_deg=0.01)
    point = make_problem("ur10", sigma_mm=0.02)
    q = _poses(pose.robot, 6, 15)
    F, dF = pose.F1(q, with_dq=True)
    n, k = len(q), pose.n_params
    assert F.shape == (6 * n, k) and dF.shape == (n, 6, 6, k)
    assert k == point.n_params + 5  # theta5, alpha5 (no extra gauge) and the probe's three
    rows = F.reshape(n, 6, k)
    cols = [pose.param_names.index(c) for c in point.param_names]
    assert_allclose(rows[:, :3, cols], point.F1(q).reshape(n, 3, -1), rtol=1e-12, atol=1e-9)
    h = 1e-6
    for j in range(6):
        dq = np.zeros_like(q)
        dq[:, j] = h
        fd = (pose.F1(q + dq) - pose.F1(q - dq)).reshape(n, 6, k) / (2 * h)
        assert_allclose(dF[:, j], fd, rtol=1e-6, atol=1e-3)
    assert pose.min_poses() == int(np.ceil(k / 6))
    with pytest.raises(InputError, match="pose measurements: one probe"):
        make_problem("kr16", measure="pose", extend=["joint_elasticity:2"])
    with pytest.raises(InputError, match="measure must be one of"):
        make_problem("kr16", measure="orientation")


def test_a_kpi_design_with_pose_measurements_runs():
    """The exact KPI design (SNOPT, the heuristic start) of 12 poses for the ur10 with a 6-DoF probe:
    feasible, and the orientation rows shrink the KPI variance of the same poses."""
    pose = make_problem("ur10", measure="pose", sigma_mm=0.02, sigma_deg=0.01)
    report = optimize_design(pose, criterion="kpi", n=12, start="heuristic", collision=False)
    assert report.success
    kpi_pose = pose.criteria(report.q)["kpi_avg_var_mm2"]
    kpi_point = make_problem("ur10", sigma_mm=0.02).criteria(report.q)["kpi_avg_var_mm2"]
    assert 0 < kpi_pose < kpi_point


def test_design_cli_with_pose_measurements(tmp_path, capsys):
    args = ["design", "--robot", "ur10", "--criterion", "kpi", "--n", "12", "--measure", "pose"]
    args += ["--sigma-mm", "0.02", "--start", "heuristic", "--no-collision", "--no-certify"]
    assert main([*args, "--out", str(tmp_path / "d.csv")]) == 0
    assert "tr(Cs)/3" in capsys.readouterr().out and (tmp_path / "d.csv").is_file()
    with pytest.raises(InputError, match="measure: expected one of point, pose"):
        DesignOptions(measure="orientation")


def test_estimate_checks_the_orientation_inputs():
    robot, data, _ = _pose_data("kr16", 20, 3)
    model = nominal_model(robot, load_cell(robot=robot))
    with pytest.raises(InputError, match=r"R_TP \(n, 3, 3\) and sigma_rot \(n, 3\)"):
        estimate(model, data.q, data.eta, R_TP=data.R_TP)
    with pytest.raises(InputError, match="sigma_rot must be positive"):
        estimate(model, data.q, data.eta, R_TP=data.R_TP, sigma_rot=np.zeros((20, 3)))
    res = estimate(model, data.q, data.eta, R_TP=data.R_TP, sigma_rot=np.full((20, 3), 1.7e-4))
    assert res.J.shape == (6 * 20, res.n_params) and res.dof == 6 * 20 - res.n_params
    assert res.rot_residuals.shape == (20, 3)


@pytest.mark.parametrize(
    "name, n_points, n_pose", [("ur10", 25, 30), ("kr16", 27, 30), ("lift7", None, None)]
)
def test_rank_test_with_orientations(name, n_points, n_pose):
    """check_identifiability with measure pose: the probe layout's free parameters (the points' plus
    the extra gauge and the probe's three) all determined; with all parameters, the six-joint tables'
    SPEC gauge is still exactly what trades against the rest (6 of 36)."""
    robot = load_robot(name)
    cell = load_cell(robot=robot)
    points, pose = check_identifiability(robot, cell), check_identifiability(robot, cell, measure="pose")
    assert points.identifiable and pose.identifiable
    assert pose.n_candidates == points.n_candidates + 3 + len(robot.extra_gauge)
    if n_points is not None:
        assert (points.n_candidates, pose.n_candidates) == (n_points, n_pose)
        every = check_identifiability(robot, cell, measure="pose", all_params=True)
        assert every.n_candidates - every.rank == 6


def test_info_says_what_orientations_add():
    """``kpioed info``: the UR10's on-axis probe leaves theta5 and alpha5 to orientations, with the
    probe's three rotations; kr16 only the probe's rotations; several targets: no pose line."""
    from kpioed_drake import api

    ur10, kr16 = api.info("ur10")["pose"], api.info("kr16")["pose"]
    assert ur10["added"] == ["theta5", "alpha5", "probe_rx", "probe_ry", "probe_rz"]
    assert ur10["n_params"] == 30 and ur10["identifiable"]
    assert kr16["added"] == ["probe_rx", "probe_ry", "probe_rz"] and kr16["n_params"] == 30
    assert api.info("models/robots/humanoid18.urdf")["pose"] is None
