"""Plane contacts and distances from files (issue 44, docs/contacts.md): simulated touches and
lengths of one true robot written as CSVs, ``kpioed calibrate`` on some rows, ``kpioed validate`` on
the others: the calibrated model's held-out plane distances at most half the nominal model's (whose
planes are fitted to the held-out rows, the robot held); the fit's own files validated reproduce
its residuals; hostile files refused with messages naming the file, row and column."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.robot.jointmap import q_columns, q_to_file
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation.contacts import simulate_distances, simulate_planes
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import measure, nominal_model, reflector_world

NORMALS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Three planes with linearly independent normals (a table and two walls)."""
PER_PLANE = 40
"""Touches per plane (shared by the targets); every 4th row is held out."""


def _inside(robot, rng, n: int) -> np.ndarray:
    """(n, n_joints) uniform poses 15 % of each range inside the limits (the touch moves them a little)."""
    margin = 0.15 * (robot.upper - robot.lower)
    return rng.uniform(robot.lower + margin, robot.upper - margin, (n, robot.n_joints))


def _touch_poses(robot, model, rng, targets: int):
    """Commanded poses within 20 mm of each plane (the tool on the plane's free side), the planes'
    offsets the median of the nominal tool points along their normals: (q, plane, target, offsets)."""
    q = _inside(robot, rng, 40000)
    rows, planes, tgts = [], [], []
    offsets = np.zeros(len(NORMALS))
    points = [reflector_world(model, q, np.full(len(q), t)) for t in range(targets)]
    for k, n in enumerate(NORMALS):
        offsets[k] = np.median(np.concatenate([p @ n for p in points])) + 150.0
        for t in range(targets):
            link = model.target_links(np.full(len(q), t))
            o = model.frames(q).at_link(link)[1]
            p = points[t]
            near = (np.abs(p @ n - offsets[k]) < 20.0) & ((o - p) @ n > 0)
            idx = np.flatnonzero(near)[: PER_PLANE // targets]
            rows.append(idx)
            planes.append(np.full(idx.size, k))
            tgts.append(np.full(idx.size, t))
    plane = np.concatenate(planes)
    assert np.all(np.bincount(plane, minlength=len(NORMALS)) >= PER_PLANE // 2), np.bincount(plane)
    return q[np.concatenate(rows)], plane, np.concatenate(tgts), offsets


def _write_planes(path, robot, data, rows):
    frame = pd.DataFrame(q_to_file(robot, data.q[rows]), columns=q_columns(robot))
    frame["plane"] = data.plane[rows] + 1
    if data.target is not None:
        frame["target"] = data.target[rows] + 1
    frame.to_csv(path, index=False)


def _scenario(tmp_path, name: str, targets: int, points: bool = False, seed: int = 0):
    """Simulated touches (and tracker points) of one true robot, written as fit and held-out CSVs."""
    robot = load_robot(name)
    model = nominal_model(robot, load_cell(robot=robot))
    rng = np.random.default_rng(seed)
    q, plane, target, offsets = _touch_poses(robot, model, rng, targets)
    data, truth = simulate_planes(
        robot,
        q,
        plane,
        normals=NORMALS,
        offsets=offsets,
        sigma_mm=0.01,
        seed=seed + 1,
        target=target if targets > 1 else None,
    )
    held = np.arange(data.n) % 4 == 0
    files = {"fit": tmp_path / "planes.csv", "held": tmp_path / "held.csv"}
    _write_planes(files["fit"], robot, data, ~held)
    _write_planes(files["held"], robot, data, held)
    if points:
        qp = _inside(robot, rng, 30)
        qp, tp = np.repeat(qp, targets, axis=0), np.tile(np.arange(targets), 30)
        eta = measure(truth["model"], qp, tp) + rng.normal(0.0, 0.02, (qp.shape[0], 3))
        Measurements.from_arrays(qp, eta, target=tp).to_frame(robot).to_csv(
            tmp_path / "points.csv", index=False
        )
        files["points"] = tmp_path / "points.csv"
    return robot, data, truth, files


def _calibrate_and_validate(tmp_path, robot, files, **extra):
    """(fit report, validation of the calibrated file, of the nominal model, of the fit's own rows)."""
    out = tmp_path / ("cal.urdf" if robot.urdf is not None else "cal.yaml")
    name = robot.source or robot.name
    rep = api.calibrate(name, files.get("points"), planes=files["fit"], out=out, **extra)
    held = api.validate(str(out), planes=files["held"])
    nominal = api.validate(name, planes=files["held"])
    own = api.validate(str(out), planes=files["fit"])
    return rep, held, nominal, own


@pytest.mark.parametrize(
    ("name", "targets", "points"),
    [
        ("kr16", 1, False),
        ("models/robots/humanoid18.urdf", 2, False),
        ("models/robots/humanoid18.urdf", 2, True),
    ],
    ids=["kr16-planes", "humanoid18-two-arms-planes", "humanoid18-two-arms-planes-and-points"],
)
def test_held_out_planes_at_most_half_the_nominal(tmp_path, name, targets, points):
    robot, data, truth, files = _scenario(tmp_path, name, targets, points)
    rep, held, nominal, own = _calibrate_and_validate(tmp_path, robot, files)
    fit = rep.figures()["planes"]
    assert fit["rms_mm"] < 0.02  # the noise is 0.01 mm
    assert ("points" in rep.figures()) == points
    assert held.label == "held-out" and not held.fitted
    assert nominal.fitted and "fitted to these rows with the robot held" in nominal.summary()
    h, n = held.figures()["planes"], nominal.figures()["planes"]
    assert h["n"] == n["n"] == int(np.count_nonzero(np.arange(data.n) % 4 == 0))
    assert h["rms_mm"] <= 0.5 * n["rms_mm"], (h, n)
    assert h["max_mm"] <= 0.5 * n["max_mm"], (h, n)
    # the fit's own rows through its model file: the fit's residuals, nothing fitted
    assert_allclose(own.plane_residuals, rep.result.contacts.plane_residuals, rtol=0, atol=1e-9)
    summary = rep.summary()
    assert "[fit]" in summary and "plane 3: normal" in summary
    assert ("no tracker rows" in summary) != points  # the base frame is held without a tracker


def _write_pairs(path, robot, data, rows, bar: bool = False):
    cols = q_columns(robot)
    frame = pd.DataFrame(q_to_file(robot, data.q[rows]), columns=[f"a_{c}" for c in cols])
    frame[[f"b_{c}" for c in cols]] = q_to_file(robot, data.q_other[rows])
    frame["length_mm"] = data.length[rows]
    if bar:
        frame["bar"] = 1
    frame.to_csv(path, index=False)


def test_distances_and_planes_together(tmp_path):
    """A length bar (pairs of poses, known length) with the planes: calibrated together; held-out
    lengths and plane distances of the calibrated model below the nominal's."""
    robot, data, truth, files = _scenario(tmp_path, "kr16", 1)
    rng = np.random.default_rng(5)
    q_a, q_b = _inside(robot, rng, 60), _inside(robot, rng, 60)
    dist, _ = simulate_distances(robot, q_a, q_other=q_b, sigma_mm=0.01, seed=6, truth=truth["model"])
    held = np.arange(dist.n) % 4 == 0
    _write_pairs(tmp_path / "dist.csv", robot, dist, ~held)
    _write_pairs(tmp_path / "dist_held.csv", robot, dist, held)
    out = tmp_path / "cal.yaml"
    rep = api.calibrate("kr16", planes=files["fit"], distances=tmp_path / "dist.csv", out=out)
    assert set(rep.figures()) == {"planes", "distances"}
    # a length of known size fixes the scale: no length is held as the scale
    assert "held as the scale" not in rep.summary()
    val = api.validate(str(out), planes=files["held"], distances=tmp_path / "dist_held.csv")
    nom = api.validate("kr16", planes=files["held"], distances=tmp_path / "dist_held.csv")
    for k in ("planes", "distances"):
        assert val.figures()[k]["rms_mm"] <= 0.5 * nom.figures()[k]["rms_mm"], k
    own = api.validate(str(out), distances=tmp_path / "dist.csv")
    assert_allclose(own.distance_residuals, rep.result.contacts.distance_residuals, rtol=0, atol=1e-9)


def _planes_frame(robot, n: int = 9) -> pd.DataFrame:
    rng = np.random.default_rng(3)
    frame = pd.DataFrame(q_to_file(robot, _inside(robot, rng, n)), columns=q_columns(robot))
    frame["plane"] = np.arange(n) % 3 + 1
    return frame


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda f: f.drop(columns="plane"), "row 1 (header): missing column 'plane'"),
        (lambda f: f.drop(columns="q3_deg"), "row 1 (header): missing column 'q3_deg'"),
        (
            lambda f: f.assign(plane=f.plane.where(f.index != 4, 0)),
            "row 6, column 'plane': 0; expected a whole number",
        ),
        (lambda f: f.assign(plane=f.plane.where(f.index != 2, 2.5)), "row 4, column 'plane': 2.5; expected"),
        (
            lambda f: f.assign(plane=f.plane.where(f.index != 0, 5)),
            "column 'plane': plane 4 has no row but plane 5",
        ),
        (lambda f: f.assign(q2_deg=f.q2_deg.where(f.index != 6, np.nan)), "row 8"),
        (lambda f: f.assign(sigma_mm=-1.0), "row 2, column 'sigma_mm': -1; expected a number > 0"),
        (lambda f: f.iloc[:7], "column 'plane': plane 2 has 2 rows"),
    ],
    ids=["no-plane", "no-joint", "plane-0", "plane-2.5", "plane-gap", "nan-joint", "sigma", "few-rows"],
)
def test_hostile_plane_files(tmp_path, change, message):
    robot = load_robot("kr16")
    path = tmp_path / "planes.csv"
    change(_planes_frame(robot)).to_csv(path, index=False)
    with pytest.raises(InputError) as err:
        api.calibrate("kr16", planes=path)
    assert str(path) in str(err.value) and message in str(err.value), str(err.value)


def test_hostile_validation_and_distance_files(tmp_path):
    robot, data, truth, files = _scenario(tmp_path, "kr16", 1)
    out = tmp_path / "cal.yaml"
    api.calibrate("kr16", planes=files["fit"], out=out)
    frame = pd.read_csv(files["held"])
    frame.loc[2, "plane"] = 4  # the model file has 3 planes
    frame.to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(InputError, match=r"bad.csv: row 4, column 'plane': 4; expected a whole number 1..3"):
        api.validate(str(out), planes=tmp_path / "bad.csv")
    pd.DataFrame({"q1_deg": [0.0], "length_mm": [500.0]}).to_csv(tmp_path / "d.csv", index=False)
    with pytest.raises(InputError, match=r"d.csv: row 1 \(header\): missing column 'a_q1_deg'"):
        api.calibrate("kr16", distances=tmp_path / "d.csv")
    rng = np.random.default_rng(1)
    dist, _ = simulate_distances(robot, _inside(robot, rng, 10), q_other=_inside(robot, rng, 10), seed=2)
    _write_pairs(tmp_path / "pairs.csv", robot, dataclasses_replace_length(dist, 3, np.nan), np.arange(10))
    with pytest.raises(InputError, match=r"pairs.csv: row 5, column 'length_mm'"):
        api.calibrate("kr16", distances=tmp_path / "pairs.csv")
    with pytest.raises(InputError, match="data_path: give a measurement file, planes or distances"):
        api.calibrate("kr16")
    with pytest.raises(InputError, match="extend: not taken with planes or distances"):
        api.calibrate("kr16", planes=files["fit"], extend=["joint_elasticity:2"])


def dataclasses_replace_length(data, row: int, value: float):
    length = data.length.copy()
    length[row] = value
    return dataclasses.replace(data, length=length)


def test_pivot_rows_and_the_command_line(tmp_path, capsys):
    """Pivot rows (a ballbar's centre cup) through a file with the planes, by the command line: its
    JSON is the API's; held-out pivot lengths with the model file's pivot."""
    robot, data, truth, files = _scenario(tmp_path, "kr16", 1)
    rng = np.random.default_rng(7)
    q = _inside(robot, rng, 40)
    centre = reflector_world(truth["model"], q).mean(axis=0)
    dist, _ = simulate_distances(
        robot, q, pivot=np.zeros(40, int), pivots=centre[None], sigma_mm=0.01, seed=8, truth=truth["model"]
    )
    frame = pd.DataFrame(q_to_file(robot, dist.q), columns=q_columns(robot))
    frame["pivot"], frame["length_mm"] = 1, dist.length
    held = np.arange(dist.n) % 4 == 0
    frame[~held].to_csv(tmp_path / "pivot.csv", index=False)
    frame[held].to_csv(tmp_path / "pivot_held.csv", index=False)
    out = tmp_path / "cal.yaml"
    argv = [
        "calibrate",
        "--robot",
        "kr16",
        "--planes",
        str(files["fit"]),
        "--distances",
        str(tmp_path / "pivot.csv"),
    ]
    assert main([*argv, "--out", str(out), "--json", "-"]) == 0
    printed = json.loads(capsys.readouterr().out)
    direct = api.calibrate("kr16", planes=files["fit"], distances=tmp_path / "pivot.csv")
    assert printed == json.loads(json.dumps(direct.to_dict()))
    assert_allclose(printed["pivots_mm"][0], centre, rtol=0, atol=0.5)  # the pivot, in the fit's gauge
    assert main(["validate", "--robot", str(out), "--distances", str(tmp_path / "pivot_held.csv")]) == 0
    text = capsys.readouterr().out
    assert "length errors [held-out] (10 rows)" in text and "nothing fitted" in text
    val = api.validate(str(out), distances=tmp_path / "pivot_held.csv")
    nom = api.validate("kr16", distances=tmp_path / "pivot_held.csv")
    assert val.figures()["distances"]["rms_mm"] <= 0.5 * nom.figures()["distances"]["rms_mm"]


def test_nominal_validation_of_some_planes_only(tmp_path):
    """Held-out rows of planes 2 and 3 only: the nominal model's planes fitted to them (ids kept
    apart, no gap refused); a plane with 2 held-out rows cannot be fitted: refused, named."""
    robot, data, truth, files = _scenario(tmp_path, "kr16", 1)
    frame = pd.read_csv(files["held"])
    some = frame[frame.plane > 1]
    some.to_csv(tmp_path / "some.csv", index=False)
    nom = api.validate("kr16", planes=tmp_path / "some.csv")
    assert nom.fitted and nom.figures()["planes"]["n"] == len(some) > 0
    pd.concat([some, frame[frame.plane == 1].iloc[:2]]).to_csv(tmp_path / "two.csv", index=False)
    with pytest.raises(InputError, match=r"two.csv: column 'plane': plane 1 has 2 rows"):
        api.validate("kr16", planes=tmp_path / "two.csv")


def test_a_bar_of_unknown_length(tmp_path):
    """Pair rows sharing bar 1 (its length correction estimated, the bar's nominal length the
    scale): the correction written to the model file and used on held-out rows."""
    robot, data, truth, files = _scenario(tmp_path, "kr16", 1)
    rng = np.random.default_rng(9)
    q_a, q_b = _inside(robot, rng, 60), _inside(robot, rng, 60)
    dist, dtruth = simulate_distances(
        robot, q_a, q_other=q_b, bar=np.zeros(60, int), sigma_mm=0.01, seed=10, truth=truth["model"]
    )
    held = np.arange(dist.n) % 4 == 0
    _write_pairs(tmp_path / "bar.csv", robot, dist, ~held, bar=True)
    _write_pairs(tmp_path / "bar_held.csv", robot, dist, held, bar=True)
    out = tmp_path / "cal.yaml"
    rep = api.calibrate("kr16", planes=files["fit"], distances=tmp_path / "bar.csv", out=out)
    assert (
        "bar1_dL: no row measures a known length" in rep.summary()
        and "bar 1: length correction" in rep.summary()
    )
    assert rep.to_dict()["bars_dL_mm"] == [0.0]  # held as the scale: its nominal length
    val = api.validate(str(out), distances=tmp_path / "bar_held.csv")
    own = api.validate(str(out), distances=tmp_path / "bar.csv")
    assert_allclose(own.distance_residuals, rep.result.contacts.distance_residuals, rtol=0, atol=1e-9)
    nom = api.validate("kr16", distances=tmp_path / "bar_held.csv")  # its correction fitted
    assert nom.fitted and val.figures()["distances"]["rms_mm"] <= 0.5 * nom.figures()["distances"]["rms_mm"]
