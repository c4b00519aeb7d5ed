"""Several targets (SMRs) per pose (issue 12, item 3): data, model, calibration, validation, design.

One offset per target in the flange frame, shared robot geometry and tracker frame. Targets come
from the robot model file (``targets_mm``; target 1 is the reflector), files number them 1..T in
a ``target`` column, and a calibrated model file carries them all.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from fd import central_fd
from numpy.testing import assert_allclose
from pydrake.geometry import (
    Capsule,
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    ProximityProperties,
    SceneGraph,
)
from pydrake.math import RigidTransform
from test_identifiability_warnings import WRIST, named

from kpioed_drake import api, calibration, simulation
from kpioed_drake.calibration import robust
from kpioed_drake.calibration.validate import validate as validate_model
from kpioed_drake.cli import main
from kpioed_drake.design import DesignConstraints, optimize_design
from kpioed_drake.design.approximate.design import rank3_changes
from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import identifiability
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot import models
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.plant import MM, capsule_pose
from kpioed_drake.scene3d.drawing import clearance_witness
from kpioed_drake.tracker import measurement
from kpioed_drake.tracker.data import Measurements, read_measurements
from kpioed_drake.tracker.feasibility import FeasibilityChecker

REPO = Path(__file__).resolve().parents[1]
SIGMA = 0.02
THREE = np.array([[-89.58, -2.84, 327.03], [60.0, 80.0, 300.0], [-40.0, 100.0, 280.0]])
"""Three SMRs on a plate at the flange; target 1 is the cell's reflector."""
ON_AXIS = np.array([[0.0, 0.0, 150.0], [60.0, 80.0, 300.0], [-40.0, 100.0, 280.0]])
"""Target 1 on joint 6's axis, targets 2 and 3 off it."""


def with_targets(robot, targets):
    return dataclasses.replace(robot, targets=np.asarray(targets, float), p_FQ=np.asarray(targets[0], float))


def robot_file(tmp_path: Path, targets, name="kr16_smr.yaml") -> Path:
    rows = ", ".join("[" + ", ".join(f"{v:g}" for v in t) + "]" for t in targets)
    path = tmp_path / name
    path.write_text((REPO / "models" / "robots" / "kr16.yaml").read_text() + f"targets_mm: [{rows}]\n")
    return path


@pytest.fixture(scope="module")
def design(kr16):
    return np.random.default_rng(20240601).uniform(kr16.lower, kr16.upper, size=(40, 6))


@pytest.fixture(scope="module")
def three(kr16, design):
    """kr16 with three SMRs, simulated (seed 7) and calibrated."""
    robot = with_targets(kr16, THREE)
    table, truth = simulation.simulate(robot, design, simulation.SimulationOptions(sigma_mm=SIGMA, seed=7))
    data = Measurements.from_table(table, robot)
    return (
        robot,
        data,
        truth["model"],
        calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=SIGMA)),
    )


# --- model ------------------------------------------------------------------------------------
def test_layout_and_model_file_targets(kr16, tmp_path):
    robot = models.load_robot(str(robot_file(tmp_path, THREE)))
    assert robot.n_targets == 3 and np.array_equal(robot.targets, THREE)
    model = measurement.nominal_model(robot, models.load_cell(robot=robot))
    lay = model.layout
    assert lay.n_targets == 3 and lay.size == 24 + 6 + 9 and lay.n_free == 27 + 6
    assert np.array_equal(model.target_offsets, THREE) and np.array_equal(model.p_FQ, THREE[0])
    assert (
        kr16.n_targets == 1
        and measurement.nominal_model(kr16, models.load_cell(robot=kr16)).layout.size == 33
    )


def test_rank_test_agrees_with_the_gauge_for_three_targets(kr16):
    """With three targets SPEC's gauge still holds: the 39 parameters have rank 33 (6 trade against
    others), and the 33 free ones are identifiable."""
    robot = with_targets(kr16, THREE)
    cell = models.load_cell(robot=robot)
    full = identifiability.check_identifiability(robot, cell, all_params=True)
    free = identifiability.check_identifiability(robot, cell)
    assert (full.n_candidates, full.rank, len(full.unidentifiable)) == (39, 33, 6)
    assert free.n_candidates == 33 and free.identifiable


def test_measurement_jacobian_with_targets_matches_finite_differences(kr16):
    robot = with_targets(kr16, THREE)
    nom = measurement.nominal_model(robot, models.load_cell(robot=robot))
    rng = np.random.default_rng(2)
    p = nom.p + 0.01 * rng.standard_normal(nom.p.size)
    model = nom.with_params(p)
    q = rng.uniform(kr16.lower, kr16.upper, size=(5, 6))
    target = np.array([2, 0, 1, 2, 1])
    h, H, dH = measurement.measurement_jacobian(model, q, with_dq=True, target=target)
    assert np.allclose(h, measurement.measure(model, q, target))
    eps = 1e-6
    fd = np.stack(
        [
            (
                measurement.measure(model.with_params(p + eps * e), q, target)
                - measurement.measure(model.with_params(p - eps * e), q, target)
            )
            / (2 * eps)
            for e in np.eye(p.size)
        ],
        axis=-1,
    )
    assert np.allclose(H, fd, atol=1e-5)
    for k, t in enumerate(target):  # only the row's own target offset moves it
        other = [s for s in range(3) if s != t]
        assert all(np.all(H[k][:, model.layout.target(s)] == 0) for s in other)
    num = central_fd(lambda qq: measurement.measurement_jacobian(model, qq, target=target)[1], q, 1e-6)
    for k in range(5):
        assert np.allclose(dH[k], np.moveaxis(num[k, :, :, k, :], -1, 0), atol=1e-4)


# --- calibration ----------------------------------------------------------------------------
def test_three_smrs_recover_tracker_and_every_target(three):
    """Simulated three-SMR data (kr16, seed 7): the tracker pose and each target offset within
    3 standard deviations of the truth, with the shared geometry."""
    _, data, truth, report = three
    res = report.result
    lay = res.model.layout
    assert data.n == 120 and data.n_targets == 3 and report.held_at_nominal == [] and not report.warnings
    assert res.n_params == 33
    std = res.std
    pos = lay.free_tracker_position
    z_pos = (res.model.p_WT - truth.p_WT) / std[pos]
    # orientation: truth = estimate @ small rotation r, r about the estimate's axes
    dR = res.model.R_WT.T @ truth.R_WT
    r = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2.0
    z_rot = r / std[lay.free_tracker_rotation]
    z_targets = [
        (res.model.target_offsets[t] - truth.target_offsets[t]) / std[lay.free_target(t)] for t in range(3)
    ]
    assert np.max(np.abs(np.concatenate([z_pos, z_rot, *z_targets]))) < 3.0
    robot_side = [i for i, n in enumerate(res.free_names) if not n.startswith("tracker")]
    z = (res.model.p[res.free] - truth.p[res.free]) / std
    assert np.max(np.abs(z[robot_side])) < 3.0
    d = report.to_dict()
    assert [t["target"] for t in d["targets"]] == [1, 2, 3] and d["reflector"]["p_FQ_mm"] == d["targets"][0][
        "p_FQ_mm"
    ]


def test_one_smr_on_axis_warns_three_off_axis_do_not(kr16, design):
    robot = with_targets(kr16, ON_AXIS)
    table, _ = simulation.simulate(
        robot, design, simulation.SimulationOptions(sigma_mm=SIGMA, seed=3, n_targets=1)
    )
    assert "target" not in table
    alone = calibration.calibrate(
        robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=SIGMA)
    )
    warning = next(w for w in alone.warnings if "do not determine" in w)
    wrist = [n for n in alone.held_at_nominal if n in WRIST]
    assert len(wrist) == 2 and named(warning, WRIST) == 2
    unused = {f"reflector_{a}{t}" for t in (2, 3) for a in "xyz"}  # targets 2, 3 have no rows
    assert set(alone.held_at_nominal) == set(wrist) | unused
    table, _ = simulation.simulate(robot, design, simulation.SimulationOptions(sigma_mm=SIGMA, seed=3))
    all3 = calibration.calibrate(
        robot,
        Measurements.from_table(table, robot),
        calibration.CalibrationOptions(sigma_mm=SIGMA, strict=True),
    )
    assert all3.held_at_nominal == [] and not any("do not determine" in w for w in all3.warnings)


def test_one_target_is_the_reflector_model(kr16, design):
    """A model file whose targets_mm is the reflector alone gives the numbers of the plain model."""
    q = design[:20]
    one = with_targets(kr16, models.load_cell(robot=kr16).p_FQ[None, :])
    a, _ = simulation.simulate(kr16, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=1))
    b, _ = simulation.simulate(one, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=1))
    assert a.equals(b)
    ra = calibration.calibrate(
        kr16, Measurements.from_table(a, kr16), calibration.CalibrationOptions(sigma_mm=SIGMA)
    )
    rb = calibration.calibrate(
        one, Measurements.from_table(b, one), calibration.CalibrationOptions(sigma_mm=SIGMA)
    )
    assert np.array_equal(ra.result.model.p, rb.result.model.p) and np.array_equal(ra.result.Cp, rb.result.Cp)


def test_cli_round_trip_calibrate_out_validate_per_target(tmp_path, design, capsys):
    rfile = robot_file(tmp_path, THREE)
    dfile, data, out, js, val = (
        tmp_path / n for n in ("d.csv", "data.csv", "cal.yaml", "cal.json", "val.json")
    )
    write_design(dfile, design[:30])
    assert (
        main(["simulate", "--robot", str(rfile), "--design", str(dfile), "--out", str(data), "--seed", "5"])
        == 0
    )
    assert "rows (3 targets per pose)" in capsys.readouterr().out
    rows = read_measurements(data, models.load_robot(str(rfile)))
    assert rows.n == 90 and list(rows.target[:6]) == [0, 1, 2, 0, 1, 2]
    assert main(["calibrate", "--robot", str(rfile), str(data), "--out", str(out), "--json", str(js)]) == 0
    cal = models.load_robot(str(out))
    report = json.loads(js.read_text())
    assert cal.n_targets == 3
    assert np.allclose(cal.targets, [t["p_FQ_mm"] for t in report["targets"]], atol=1e-9)
    assert main(["validate", "--robot", str(out), str(data), "--keep-tracker", "--json", str(val)]) == 0
    v = json.loads(val.read_text())
    assert v["n_poses"] == 30 and v["n_rows"] == 90 and [t["n_rows"] for t in v["targets"]] == [30, 30, 30]
    assert max(t["rms_mm"] for t in v["targets"]) < 2 * SIGMA
    out = capsys.readouterr().out
    assert "held-out on 30 poses (90 rows), tracker frame kept" in out and "  target 3 (30 rows): RMS" in out
    assert v["figures"]["n_poses"] == 30 and v["figures"]["n_rows"] == 90


# --- bad input ----------------------------------------------------------------------------
def _rewrite_targets(src: Path, dst: Path, values) -> None:
    lines = src.read_text().splitlines()
    j = lines[0].split(",").index("target")
    out = [lines[0]]
    for line, v in zip(lines[1:], values, strict=False):
        cells = line.split(",")
        cells[j] = str(v)
        out.append(",".join(cells))
    dst.write_text("\n".join(out) + "\n")


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ([1, 3] * 45, r"row 3, column 'target': target 3 is used but target 2 is not"),
        ([1, 2, 3] * 29 + [1, 2, 4], r"row 91, column 'target': target 4, but the robot model .* defines 3"),
        ([1, 2, 0] * 30, r"row 4, column 'target': 0 is not a target number"),
        ([1, 2, 1.5] * 30, r"row 4, column 'target': 1.5 is not a target number"),
        ([1, 2, -1] * 30, r"row 4, column 'target': -1 is not a target number"),
    ],
)
def test_bad_target_column_exit_2_nothing_written(tmp_path, design, capsys, values, match):
    rfile = robot_file(tmp_path, THREE)
    dfile, good, bad, out, js = (tmp_path / n for n in ("d.csv", "good.csv", "bad.csv", "o.yaml", "o.json"))
    write_design(dfile, design[:30])
    assert main(["simulate", "--robot", str(rfile), "--design", str(dfile), "--out", str(good)]) == 0
    _rewrite_targets(good, bad, values)
    capsys.readouterr()
    assert main(["calibrate", "--robot", str(rfile), str(bad), "--out", str(out), "--json", str(js)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and re.search(match, err), err
    assert not out.exists() and not js.exists()
    assert main(["validate", "--robot", str(rfile), str(bad), "--json", str(js)]) == 2
    assert not js.exists()


def test_target_beyond_plain_model_and_format_file(tmp_path, design, capsys):
    rfile = robot_file(tmp_path, THREE)
    dfile, data, js = tmp_path / "d.csv", tmp_path / "data.csv", tmp_path / "o.json"
    write_design(dfile, design[:30])
    assert main(["simulate", "--robot", str(rfile), "--design", str(dfile), "--out", str(data)]) == 0
    capsys.readouterr()
    assert main(["calibrate", "--robot", "kr16", str(data), "--json", str(js)]) == 2
    err = capsys.readouterr().err
    assert str(data) in err and "'target'" in err and "defines 1 target" in err and not js.exists()
    fmt = tmp_path / "fmt.yaml"
    fmt.write_text(
        "angles: model\njoints: [q1_deg, q2_deg, q3_deg, q4_deg, q5_deg, q6_deg]\n"
        "position: {x: x_mm, y: y_mm, z: z_mm}\ntarget: target\n"
    )
    assert api.calibrate(str(rfile), data, data_format=fmt).result.n_params == 33
    gaps = tmp_path / "gaps.csv"
    _rewrite_targets(data, gaps, [1, 3] * 45)
    assert main(["calibrate", "--robot", str(rfile), str(gaps), "--format", str(fmt), "--json", str(js)]) == 2
    err = capsys.readouterr().err
    assert str(gaps) in err and "column 'target'" in err and not js.exists()


def test_simulate_too_many_targets_and_bad_model_file(tmp_path, design, capsys):
    dfile, out = tmp_path / "d.csv", tmp_path / "o.csv"
    write_design(dfile, design[:20])
    assert (
        main(["simulate", "--robot", "kr16", "--design", str(dfile), "--out", str(out), "--targets", "3"])
        == 2
    )
    assert "--targets" in capsys.readouterr().err and not out.exists()
    text = (REPO / "models" / "robots" / "kr16.yaml").read_text()
    for extra, field in (
        ("targets_mm: [[1, 2], [3, 4, 5]]\n", "targets_mm[0]"),
        ("targets_mm: [[1, 2, 3]]\nreflector_position_mm: [0, 0, 3]\n", "reflector_position_mm"),
    ):
        bad = tmp_path / "bad.yaml"
        bad.write_text(text + extra)
        with pytest.raises(InputError, match=re.escape(field)) as exc:
            models.load_robot(str(bad))
        assert str(bad) in str(exc.value)


# --- design -------------------------------------------------------------------------------
@pytest.mark.slow
def test_design_two_targets_feasible_per_target(kr16):
    """A pose measures both targets: 6 rows per pose in F1 (their derivative checked by finite
    differences), one incidence row per target, and the design passes the independent checker."""
    robot = with_targets(kr16, [[-89.58, -2.84, 327.03], [-89.58, 60.0, 300.0]])
    pb = make_problem(robot, sigma_mm=SIGMA)
    rng = np.random.default_rng(4)
    q = robot.q_work + rng.uniform(-0.3, 0.3, size=(3, 6))
    F, dF = pb.F1(q, with_dq=True)
    assert F.shape == (18, 30) and dF.shape == (3, 6, 6, 30)
    num = central_fd(lambda qq: pb.F1(qq).reshape(3, 6, 30), q, 1e-6)
    for k in range(3):
        assert np.allclose(dF[k], np.moveaxis(num[k, :, :, k, :], -1, 0), atol=1e-5 * np.abs(dF).max())
    # target 1's rows are those of the one-reflector problem; they do not see target 2's offset
    rows = F.reshape(3, 2, 3, 30)
    assert np.allclose(
        rows[:, 0, :, :27], make_problem(kr16, sigma_mm=SIGMA).F1(q).reshape(3, 3, 27), rtol=1e-12
    )
    assert np.all(rows[:, 0, :, 27:] == 0) and np.all(rows[:, 1, :, 24:27] == 0)
    cons = DesignConstraints(pb, collision=False)
    assert cons.row_names == ("incidence1", "incidence2") and cons.evaluate(q)[0].shape == (3, 2)
    res = optimize_design(pb, criterion="kpi", n=12, seed=0)
    inc = np.rad2deg(np.arccos(measurement.incidence_cosines(pb.model, res.q)))
    limit = np.rad2deg(pb.cell.max_incidence)
    assert inc.shape == (12, 2) and np.all(inc <= limit + 1e-6)
    assert np.any(inc[:, 1] > limit - 0.01)  # target 2's row is active: imposed, not implied
    reports = FeasibilityChecker(robot, pb.cell).check(res.q)
    assert all(r.feasible for r in reports)
    assert np.allclose([r.incidence_deg for r in reports], inc.max(axis=1))


def test_rows_of_several_targets_reuse_the_poses_forward_kinematics(kr16):
    """With T targets F1 measures each pose T times; it repeats the poses' frames
    (:meth:`Frames.repeated`) instead of a forward kinematics of the repeated poses: the same rows,
    whether the caller passes the frames or not."""
    robot = with_targets(kr16, THREE)
    pb = make_problem(robot, sigma_mm=SIGMA)
    q = robot.q_work + np.random.default_rng(5).uniform(-0.4, 0.4, size=(4, 6))
    frames = forward_kinematics(robot, q, pb.model.geometry)
    again = forward_kinematics(robot, np.repeat(q, 3, axis=0), pb.model.geometry)
    for name in ("R", "o", "elem_u", "elem_o", "joint_axes", "joint_points"):
        assert_allclose(getattr(frames.repeated(3), name), getattr(again, name), rtol=0, atol=1e-12)
    assert frames.repeated(1) is frames
    target = np.tile(np.arange(3), 4)
    H = measurement.measurement_jacobian(pb.model, np.repeat(q, 3, axis=0), target=target)[1]
    F, dF = pb.F1(q, with_dq=True)
    assert_allclose(F, (H[:, :, pb.free] / SIGMA).reshape(F.shape), rtol=0, atol=1e-9 * np.abs(F).max())
    F_given, dF_given = pb.F1(q, with_dq=True, frames=frames)
    assert_allclose(F_given, F, rtol=0, atol=0)
    assert_allclose(dF_given, dF, rtol=0, atol=0)


def test_diagnose_three_targets_finds_the_effect(kr16):
    """The diagnosis fits the shared geometry, the three target offsets and the effects."""
    robot = with_targets(kr16, THREE)
    q = np.random.default_rng(1).uniform(kr16.lower, kr16.upper, size=(20, 6))
    table, _ = simulation.simulate(
        robot, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=2, effects=["joint_elasticity:2"])
    )
    report = diagnose(robot, Measurements.from_table(table, robot), DiagnosisOptions(sigma_mm=SIGMA))
    assert report.n_poses == 20 and report.n_rows == 60, report.summary()
    assert report.cause_names == {"joint_elasticity:2"}, report.summary()


@pytest.mark.slow
def test_design_and_evaluate_cli_with_two_targets(tmp_path, capsys, quick_certificate):
    """The commands take a several-target model: the approximate start (its cones hold a pose's 6
    rows) and the certificate (the smaller search: still rigorous), whose bound is below the
    design's value."""
    rfile = robot_file(tmp_path, [[-89.58, -2.84, 327.03], [-89.58, 60.0, 300.0]])
    out, js = tmp_path / "des.csv", tmp_path / "des.json"
    base = ["design", "--robot", str(rfile), "--criterion", "kpi", "--n", "10", "--out", str(out)]
    assert main([*base, "--json", str(js)]) == 0
    rec = json.loads(js.read_text())
    assert rec["start"] == "approximate" and rec["feasible"]
    value = rec["values"]["kpi_avg_var_mm2"]
    assert 0 < rec["bound_mm2"] <= value and 0 < rec["efficiency"] <= 1
    ev = tmp_path / "ev.json"
    assert main(["evaluate", "--robot", str(rfile), "--design", str(out), "--json", str(ev)]) == 0
    assert "feasible: True" in capsys.readouterr().out
    assert 0 < json.loads(ev.read_text())["bound_mm2"] <= value * (1 + 1e-9)


def test_exchange_changes_with_two_targets_are_exact():
    """The exchange's rank-6 updates (a pose's rows of two targets) equal Phi recomputed."""
    rng = np.random.default_rng(11)
    F = rng.standard_normal((7, 6, 9))
    K = rng.standard_normal((9, 3))
    M = np.einsum("iak,ial->kl", F[:4], F[:4]) + np.eye(9)
    phi = float(np.trace(K.T @ np.linalg.solve(M, K)))
    added = [float(np.trace(K.T @ np.linalg.solve(M + f.T @ f, K))) for f in F]
    removed = [float(np.trace(K.T @ np.linalg.solve(M - f.T @ f, K))) for f in F[:4]]
    np.testing.assert_allclose(rank3_changes(F, M, K, 1.0), phi - np.array(added), rtol=1e-9)
    np.testing.assert_allclose(rank3_changes(F[:4], M, K, -1.0), np.array(removed) - phi, rtol=1e-9)


def test_in_memory_data_naming_unknown_targets_are_refused(kr16, design):
    """Measurements built in Python (no file check) naming a target the model lacks: InputError
    from calibrate and validate, naming the field."""
    table, _ = simulation.simulate(kr16, design[:20], simulation.SimulationOptions(sigma_mm=SIGMA, seed=1))
    data = Measurements.from_table(table, kr16)
    bad = dataclasses.replace(data, target=np.arange(20) % 2)
    with pytest.raises(InputError, match="field 'target'.*defines 1"):
        calibration.calibrate(kr16, bad, calibration.CalibrationOptions(sigma_mm=SIGMA))
    with pytest.raises(InputError, match="field 'target'"):
        validate_model(kr16, bad)
    with pytest.raises(InputError, match="target"):
        Measurements.from_arrays(data.q, data.eta, target=np.full(20, -1))


# --- every target's beam is clear (optimiser rows and independent checker) ------------------
TWO = [[-89.58, -2.84, 327.03], [-89.58, 60.0, 300.0]]
BLOCKED_DEG = [112.6, -131.9, -1.0, -256.9, -64.0, -4.8]
"""A kr16 pose where target 2's beam passes through the wrist, target 1's clears it by ~24 mm."""


def _drake_capsule_distance(a1, b1, r1, a2, b2, r2) -> float:
    """Signed distance [mm] of two capsules (axis end points, radius [mm]) by Drake's query."""
    sg = SceneGraph()
    src = sg.RegisterSource("beam")
    frame = sg.RegisterFrame(src, GeometryFrame("beam"))
    ids = []
    for a, b, r in ((a1, b1, r1), (a2, b2, r2)):
        X, length = capsule_pose(a, b)
        inst = GeometryInstance(X, Capsule(r * MM, length), f"capsule{len(ids)}")
        gid = sg.RegisterGeometry(src, frame, inst) if not ids else sg.RegisterAnchoredGeometry(src, inst)
        sg.AssignRole(src, gid, ProximityProperties())
        ids.append(gid)
    context = sg.CreateDefaultContext()
    poses = FramePoseVector()
    poses.set_value(frame, RigidTransform())
    sg.get_source_pose_port(src).FixValue(context, poses)
    query = sg.get_query_output_port().Eval(context)
    return query.ComputeSignedDistancePairClosestPoints(ids[0], ids[1]).distance / MM


def test_blocked_second_beam_is_infeasible_for_optimiser_and_checker(kr16):
    """Target 2's beam through the wrist: a clearance row ``beam2 vs wrist`` < 0 in the design
    constraints and a ``beam`` failure of the Drake checker; with target 1 alone the pose's
    clearances all pass. The numpy value agrees with Drake's capsule-capsule distance."""
    robot = with_targets(kr16, TWO)
    cell = models.load_cell(robot=robot)
    q = np.deg2rad(BLOCKED_DEG)
    one = ClearanceModel(kr16, models.load_cell(robot=kr16))
    v1 = dict(zip(one.rows.names, one.values(q[None])[0], strict=True))
    assert "beam vs wrist" in v1 and min(v1.values()) > 20.0
    cons = DesignConstraints(make_problem(robot, sigma_mm=SIGMA))
    v = dict(zip(cons.row_names, cons.evaluate(q[None])[0][0], strict=True))
    # the one-target rows, target 1's beam renamed beam1, then target 2's beam rows
    renamed = [n.replace("beam vs", "beam1 vs") for n in one.rows.names]
    beam2 = [n.replace("beam vs", "beam2 vs") for n in one.rows.names if n.startswith("beam vs")]
    assert list(cons.clearance.rows.names) == renamed + beam2
    assert all(v[r] == x for r, x in zip(renamed, v1.values(), strict=True))
    assert v["beam2 vs wrist"] < -15.0 and min(v[n] for n in renamed) > 20.0
    # the independent checker
    fr = forward_kinematics(robot, q[None])
    wrist = next(c for c in robot.capsules if c.name == "wrist")
    A, B = (fr.o[0, wrist.frame] + fr.R[0, wrist.frame] @ p for p in (wrist.a, wrist.b))
    p_Q = flange_point(fr, np.asarray(TWO[1]))[0]
    drake = _drake_capsule_distance(p_Q, cell.p_WT, cell.beam_radius, A, B, wrist.radius)
    assert abs(v["beam2 vs wrist"] - drake) < 0.05, (v["beam2 vs wrist"], drake)
    checker = FeasibilityChecker(robot, cell)
    clear = checker.clearances(q)
    assert {k for k in clear if k.startswith("beam")} == {n for n in v if n.startswith("beam")}
    assert abs(clear["beam2 vs wrist"] - drake) < 0.05
    report = checker.check_pose(q)
    failed = {(f["check"], f["name"]) for f in report.failures if f["check"] in ("beam", "collision")}
    assert not report.feasible and failed == {("beam", "beam2 vs wrist")}
    assert report.min_clearance_pair == "beam2 vs wrist"
    p_A, p_B = clearance_witness(checker.scene, robot, cell, q, "beam2 vs wrist")  # 3-D pages
    assert np.linalg.norm(p_A - p_B) == pytest.approx(-clear["beam2 vs wrist"], abs=1e-6)
    alone = FeasibilityChecker(kr16, models.load_cell(robot=kr16)).check_pose(q)
    assert not any(f["check"] in ("beam", "collision") for f in alone.failures)


@pytest.mark.slow
def test_two_target_design_clears_every_beam(kr16):
    """An optimised two-target design (collision rows on) passes the checker, which tests the
    beam of each target (rows beam1 .. and beam2 ..) of every pose."""
    robot = with_targets(kr16, TWO)
    pb = make_problem(robot, sigma_mm=SIGMA)
    res = optimize_design(pb, criterion="kpi", n=8, seed=1)
    checker = FeasibilityChecker(robot, pb.cell)
    assert all(r.feasible for r in checker.check(res.q))
    for qk in res.q:
        clear = checker.clearances(qk)
        per_target = [[d for k, d in clear.items() if k.startswith(f"beam{t} vs")] for t in (1, 2)]
        assert all(len(d) == 7 and min(d) >= -checker.tol_mm for d in per_target)


def test_calibration_summary_counts_rows_and_poses(three):
    """Several targets: the summary and the JSON say poses and rows (40 poses x 3 targets = 120 rows)."""
    text = three[3].summary()
    assert "40 poses (120 rows, 3 targets), 120 rows used" in text.splitlines()[0], text
    assert "fit on 40 poses (120 rows), tracker frame estimated in the fit:" in text, text
    d = three[3].to_dict()
    assert (d["n_poses"], d["n_rows"], d["n_used"]) == (40, 120, 120)
    assert [t["n_rows"] for t in d["figures"]["fit"]["targets"]] == [40, 40, 40]


def test_a_pose_whose_targets_agree_is_kept_one_whose_targets_disagree_is_removed(kr16, design):
    """Outliers per pose with several targets: all three SMRs of pose 5 moved by the same 1.5 mm (a
    model error at that pose: the targets still agree with each other) are kept, one SMR of pose 12
    moved by 1.5 mm (a bumped reflector: they disagree) is removed."""
    robot = with_targets(kr16, THREE)
    table, _ = simulation.simulate(robot, design, simulation.SimulationOptions(sigma_mm=SIGMA, seed=7))
    data = Measurements.from_table(table, robot)
    eta = data.eta.copy()
    eta[15:18] += [1.5, 0.0, 0.0]  # pose 5 (rows 15-17): a rigid shift of all three targets
    eta[37] += [0.0, 1.5, 0.0]  # pose 12, target 2 only
    bad = dataclasses.replace(data, eta=eta)
    report = calibration.calibrate(robot, bad, calibration.CalibrationOptions(sigma_mm=SIGMA))
    removed = {int(data.rows[i]) for i in report.outliers}
    assert int(data.rows[37]) in removed
    assert not removed & {int(data.rows[i]) for i in range(15, 18)}
    assert any("targets agree with each other" in w for w in report.warnings)
    assert_allclose(robust.pose_groups(bad)[::3], np.arange(40), atol=0)
