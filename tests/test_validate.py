"""``kpioed validate`` / ``api.validate``: prediction errors of a model on fresh data.

Nothing is fitted to the poses scored unless the report says so: a calibrated model keeps its
tracker frame, a model without one is cross-registered (registered on one half of the poses, scored
on the other), and in-sample registration is labelled optimistic. The figures are checked against a
hand computation of the frames (Kabsch by numpy's SVD on the halves).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.calibration.validate import validate
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import Measurements, read_measurements
from kpioed_drake.tracker.measurement import nominal_model, reflector_world

KEYS = ("n_poses", "rms_mm", "mean_error_mm", "p95_error_mm", "max_error_mm", "errors_mm")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """kr16 with random geometric errors (one seed: one true robot and tracker), measured twice:
    60 poses to calibrate, 20 fresh ones to validate."""
    d = tmp_path_factory.mktemp("validate")
    robot = load_robot("kr16")
    rng = np.random.default_rng(7)
    q_cal = robot.q_work + rng.uniform(-0.6, 0.6, size=(60, 6))
    q_val = robot.q_work + rng.uniform(-0.5, 0.5, size=(20, 6))
    simulate(robot, q_cal, SimulationOptions(sigma_mm=0.02, seed=4))[0].to_csv(d / "cal.csv", index=False)
    simulate(robot, q_val, SimulationOptions(sigma_mm=0.02, seed=4))[0].to_csv(d / "val.csv", index=False)
    status = main(["calibrate", "--robot", "kr16", str(d / "cal.csv"), "--out", str(d / "cal.yaml")])
    assert status == 0
    return d


def kabsch(p_W: np.ndarray, p_T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid frame (R, p) minimising |p_W - (R p_T + p)|^2, written out here by hand."""
    c_W, c_T = p_W.mean(axis=0), p_T.mean(axis=0)
    U, _, Vt = np.linalg.svd((p_T - c_T).T @ (p_W - c_W))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, c_W - R @ c_T


def predicted(robot, data) -> np.ndarray:
    """The model's reflector points in W at the data's poses."""
    return reflector_world(nominal_model(robot, load_cell(robot=robot)), data.q, data.target)


def cross_by_hand(p_W: np.ndarray, eta: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Residuals with the frame registered on the other half (odd / even pose numbers)."""
    half = pose % 2
    out = np.empty_like(p_W)
    for h in (0, 1):
        R, p = kabsch(p_W[half != h], eta[half != h])
        out[half == h] = eta[half == h] @ R.T + p - p_W[half == h]
    return out


def figures_by_hand(r: np.ndarray) -> dict:
    e = np.linalg.norm(r, axis=1)
    return {
        "rms_mm": np.sqrt(np.mean(r**2)),
        "rms_xyz_mm": np.sqrt(np.mean(r**2, axis=0)),
        "mean_error_mm": e.mean(),
        "p95_error_mm": np.percentile(e, 95),
        "max_error_mm": e.max(),
    }


def test_calibrated_model_predicts_fresh_data(work, capsys):
    nominal = api.validate("kr16", work / "val.csv", json_path=work / "nominal.json")
    main(
        [
            "validate",
            "--robot",
            str(work / "cal.yaml"),
            str(work / "val.csv"),
            "--json",
            str(work / "cal.json"),
        ]
    )
    capsys.readouterr()
    rep_nom = json.loads((work / "nominal.json").read_text())
    rep_cal = json.loads((work / "cal.json").read_text())
    for rep in (rep_nom, rep_cal):
        assert all(k in rep for k in KEYS) and rep["n_poses"] == 20 and len(rep["errors_mm"]) == 20
        e = np.asarray(rep["errors_mm"])
        assert rep["mean_error_mm"] == pytest.approx(e.mean()) and rep["max_error_mm"] == pytest.approx(
            e.max()
        )
        assert e.min() <= rep["p95_error_mm"] <= e.max()
    assert rep_nom["mean_error_mm"] == pytest.approx(float(np.mean(nominal.errors_mm)))
    # the nominal model has no tracker pose: cross-registered; the calibrated one keeps its own
    assert rep_nom["tracker"]["method"] == "cross-registered (2 halves)" and rep_nom["notes"]
    assert rep_cal["tracker"]["method"] == "kept" and not rep_cal["notes"]
    # calibration removes the geometric errors: the rest is noise (0.02 mm per coordinate)
    assert rep_cal["rms_mm"] < 0.04 < rep_nom["rms_mm"]
    assert rep_cal["mean_error_mm"] < rep_nom["mean_error_mm"] / 5


def test_kept_cross_and_in_sample_figures_equal_a_hand_computation(work):
    """Kept: the model file's tracker frame; cross: Kabsch on one half (alternate poses) scores the
    other; in-sample: Kabsch on all poses. Residuals and figures to 1e-9 mm."""
    robot = load_robot(str(work / "cal.yaml"))
    data = read_measurements(work / "val.csv", robot)
    p_W = predicted(robot, data)
    p_WT, R_WT = robot.X_WT
    kept = api.validate(str(work / "cal.yaml"), work / "val.csv")
    assert kept.method == "kept" and not kept.registered
    r_kept = data.eta @ R_WT.T + p_WT - p_W
    assert_allclose(kept.residuals_W, r_kept, rtol=0, atol=1e-9)
    d = kept.to_dict()
    for key, value in figures_by_hand(r_kept).items():
        assert_allclose(d[key], value, rtol=0, atol=1e-9, err_msg=key)
    assert d["figures"]["kind"] == "held-out" and d["figures"]["tracker"] == "kept"

    cross = api.validate(str(work / "cal.yaml"), work / "val.csv", tracker_frame="cross")
    r_cross = cross_by_hand(p_W, data.eta, np.arange(data.n))
    assert_allclose(cross.residuals_W, r_cross, rtol=0, atol=1e-9)
    d = cross.to_dict()
    for key, value in figures_by_hand(r_cross).items():
        assert_allclose(d[key], value, rtol=0, atol=1e-9, err_msg=key)
    assert d["tracker"]["method"] == "cross-registered (2 halves)" and len(d["tracker"]["frames"]) == 2
    assert d["tracker"]["halves"] == [1, 2] * 10
    assert "held-out on 20 poses, tracker frame cross-registered" in cross.summary()

    inside = api.validate(str(work / "cal.yaml"), work / "val.csv", tracker_frame="in-sample")
    R, p = kabsch(p_W, data.eta)
    assert_allclose(inside.residuals_W, data.eta @ R.T + p - p_W, rtol=0, atol=1e-9)
    assert inside.to_dict()["tracker"]["method"] == "registered in-sample"
    assert "(in-sample: optimistic)" in inside.summary()
    # the in-sample frame is the least-squares optimum over all frames, the kept one among them
    assert inside.to_dict()["rms_mm"] <= kept.to_dict()["rms_mm"]
    # the older flag means kept
    old = api.validate(str(work / "cal.yaml"), work / "val.csv", keep_tracker=True)
    assert_allclose(old.residuals_W, r_kept, rtol=0, atol=1e-9)


def test_a_moved_tracker_is_flagged_and_cross_registration_does_not_see_it(work, tmp_path):
    """The fresh poses measured from another tracker position (every point moved rigidly): kept, the
    errors grow and a warning says the tracker moved; cross-registered, they are the same."""
    robot = load_robot(str(work / "cal.yaml"))
    data = read_measurements(work / "val.csv", robot)
    c, s = np.cos(0.01), np.sin(0.01)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    moved = Measurements.from_arrays(data.q, data.eta @ R.T + [5.0, -3.0, 1.0], source="moved")
    kept = validate(robot, moved)
    assert kept.method == "kept" and np.mean(kept.errors_mm) > 5.0
    assert any("the tracker has probably moved" in w for w in kept.warnings), kept.warnings
    assert not any("moved" in w for w in validate(robot, data).warnings)
    cross_moved = validate(robot, moved, tracker_frame="cross")
    cross = validate(robot, data, tracker_frame="cross")
    assert_allclose(cross_moved.residuals_W, cross.residuals_W, rtol=0, atol=1e-9)


def test_keeping_a_tracker_pose_never_estimated_is_refused(work, capsys):
    """The nominal model's tracker pose is the cell file's: kept, it would report metres."""
    assert load_robot("kr16").X_WT is None
    for kwargs in ({"tracker_frame": "kept"}, {"keep_tracker": True}):
        with pytest.raises(InputError, match="no estimated tracker pose") as info:
            api.validate("kr16", work / "val.csv", **kwargs)
        assert "tracker_frame" in info.value.fields
    assert main(["validate", "--robot", "kr16", str(work / "val.csv"), "--keep-tracker"]) == 2
    err = capsys.readouterr().err
    assert "--tracker-frame kept" in err and "no estimated tracker pose" in err and "cross" in err
    res = api.validate("kr16", work / "val.csv")  # the default: cross-registered, with a note
    assert res.method == "cross" and "has no estimated tracker pose" in res.notes[0]
    assert res.to_dict()["max_error_mm"] < 10.0  # millimetres, not metres


def test_base_frame_data_keep_the_identity(work):
    """Data in the base frame with a model without a tracker pose: kept is the identity frame."""
    robot = load_robot("kr16")
    data = read_measurements(work / "val.csv", robot)
    p_W = predicted(robot, data)
    noisy = p_W + np.random.default_rng(3).normal(0.0, 0.05, size=p_W.shape)
    base = Measurements.from_arrays(data.q, noisy, source="base", frame="base")
    res = validate(robot, base)
    assert res.method == "kept" and not res.notes
    assert_allclose(res.residuals_W, noisy - p_W, rtol=0, atol=1e-9)


def test_two_targets_keep_a_pose_together_and_count_poses_and_rows(tmp_path, capsys):
    """Two SMRs per pose: the halves are of poses (both rows of a pose in one half), and the report
    counts poses and rows."""
    robot_file = tmp_path / "kr16-2smr.yaml"
    kr16 = Path(load_robot("kr16").source).read_text()
    robot_file.write_text(kr16 + "targets_mm: [[-89.58, -2.84, 327.03], [60, 80, 300]]\n")
    robot = load_robot(str(robot_file))
    q = robot.q_work + np.random.default_rng(5).uniform(-0.5, 0.5, size=(15, 6))
    table = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=2, n_targets=2))[0]
    table.to_csv(tmp_path / "two.csv", index=False)
    data = read_measurements(tmp_path / "two.csv", robot)
    assert data.n == 30 and np.array_equal(data.q[0], data.q[1])  # pose-major: a pose's rows adjacent
    res = api.validate(str(robot_file), tmp_path / "two.csv", json_path=tmp_path / "v.json")
    assert res.method == "cross"
    r = cross_by_hand(predicted(robot, data), data.eta, np.arange(data.n) // 2)
    assert_allclose(res.residuals_W, r, rtol=0, atol=1e-9)
    d = json.loads((tmp_path / "v.json").read_text())
    assert (d["n_poses"], d["n_rows"]) == (15, 30) and d["tracker"]["halves"][:4] == [1, 1, 2, 2]
    assert "held-out on 15 poses (30 rows)" in res.summary()
    assert [t["n_rows"] for t in d["figures"]["targets"]] == [15, 15]


def test_plots_and_stdout_json(work, capsys):
    status = main(
        ["validate", "--robot", "kr16", str(work / "val.csv"), "--plots", str(work / "plots"), "--json"]
    )
    out = capsys.readouterr().out
    assert status == 0 and json.loads(out)["n_poses"] == 20
    assert (work / "plots" / "validation_errors.png").stat().st_size > 1000


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"keep_tracker": "yes"}, "keep_tracker"),
        ({"tracker_frame": "moved"}, "tracker_frame: expected one of kept, cross, in-sample"),
        ({"tracker_frame": "cross", "keep_tracker": True}, "contradict"),
        ({"json_path": "VAL"}, "val.csv"),
        ({"data_format": "missing-format.yaml"}, "missing-format.yaml: file not found"),
    ],
)
def test_api_validate_refuses_bad_arguments(work, kwargs, needle):
    if kwargs.get("json_path") == "VAL":
        kwargs = {"json_path": work / "val.csv"}
    before = (work / "val.csv").read_bytes()
    with pytest.raises(InputError, match=needle):
        api.validate("kr16", work / "val.csv", **kwargs)
    assert (work / "val.csv").read_bytes() == before


def test_cli_validate_bad_data_exits_2_and_writes_nothing(work, tmp_path, capsys):
    text = (work / "val.csv").read_text().replace("x_mm", "x_mn", 1)
    (tmp_path / "bad.csv").write_text(text)
    status = main(
        ["validate", "--robot", "kr16", str(tmp_path / "bad.csv"), "--json", str(tmp_path / "o.json")]
    )
    err = capsys.readouterr().err
    assert status == 2 and "bad.csv" in err and "x_mm" in err
    assert not (tmp_path / "o.json").exists()
