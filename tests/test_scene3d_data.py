"""3-D pages of measured data beyond points (kpioed_drake.scene3d.probe, .contacts): a 6-DoF probe's
measured and predicted frames on calibrate and validate pages, and the planes, touches, pivots and
bars of a contact calibration and validation; ``--html`` on both commands.

The pages' scene commands are decoded as in ``test_scene3d.py``; the expected poses are computed
from the model files the commands wrote (their ``contact_environment``, ``probe_rpy_deg``) and the
forward kinematics, not from the page code.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
import yaml
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation
from test_contact_files import _inside, _scenario
from test_scene3d import colours_under, commands, hex_colour

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.robot.jointmap import q_columns, q_to_file
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.scene3d import external_references
from kpioed_drake.scene3d.contacts import ABOVE, BELOW, signed_colour
from kpioed_drake.scene3d.probe import AXIS_MM, MAX_TRIADS
from kpioed_drake.simulation.contacts import simulate_distances
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.study.synthetic import random_poses
from kpioed_drake.tracker.measurement import nominal_model, reflector_world

MM = 1e-3


def transforms(cmds) -> dict[str, np.ndarray]:
    """Path -> its 4 x 4 transform (metres) as set on the page."""
    return {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in cmds if c["type"] == "set_transform"}


def objects(cmds) -> dict[str, dict]:
    return {c["path"]: c["object"] for c in cmds if c["type"] == "set_object"}


def self_contained(path) -> str:
    page = path.read_text()
    assert page.lstrip().lower().startswith("<!doctype html") or "<html" in page[:500].lower()
    assert external_references(page) == []
    return page


# --- a 6-DoF probe --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pose_pages(tmp_path_factory):
    """kr16 pose data (positions and orientations, one simulated robot): ``kpioed calibrate --html``
    on 25 poses, ``api.validate(html=...)`` on 40 others."""
    w = tmp_path_factory.mktemp("pose")
    robot = load_robot("kr16")
    q = random_poses(robot, 65, np.random.default_rng(1))
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=1, orientation_sigma_deg=0.02))
    table.iloc[:25].to_csv(w / "fit.csv", index=False)
    table.iloc[25:].to_csv(w / "held.csv", index=False)
    cal = w / "cal.yaml"
    argv = [
        "calibrate",
        "--robot",
        "kr16",
        str(w / "fit.csv"),
        "--out",
        str(cal),
        "--html",
        str(w / "cal.html"),
    ]
    assert main(argv) == 0
    val = api.validate(str(cal), w / "held.csv", html=w / "val.html")
    return w, cal, val


def _probe_expected(cal, data_csv):
    """Predicted probe frames of the written model: (q, R_WP (n, 3, 3), p_WP (n, 3) [mm])."""
    robot = load_robot(str(cal))
    model = nominal_model(robot, load_cell(robot=robot))
    table = pd.read_csv(data_csv)
    q = np.deg2rad(table[[f"q{j + 1}_deg" for j in range(6)]].to_numpy())
    R_FP = Rotation.from_euler("xyz", yaml.safe_load(cal.read_text())["probe_rpy_deg"], degrees=True)
    R_WF = model.frames(q).at_link(None)[0]
    return q, R_WF @ R_FP.as_matrix(), reflector_world(model, q)


def test_calibration_page_draws_measured_and_predicted_probe_frames(pose_pages):
    w, cal, _ = pose_pages
    page = self_contained(w / "cal.html")
    cmds = commands(page)
    X, obj = transforms(cmds), objects(cmds)
    q, R_WP, p_WP = _probe_expected(cal, w / "fit.csv")
    for k in range(len(q)):  # 25 rows: every one drawn
        M = X[f"/probe/predicted/{k + 1:03d}"]
        assert_allclose(M[:3, :3], R_WP[k], rtol=0, atol=1e-9)
        assert_allclose(M[:3, 3] / MM, p_WP[k], rtol=0, atol=1e-6)
        for axis in "xyz":  # axes in the frame, AXIS_MM long
            assert obj[f"/probe/predicted/{k + 1:03d}/{axis}"]["geometries"][0]["height"] == pytest.approx(
                AXIS_MM * MM
            )
        assert f"/probe/measured/{k + 1:03d}" in X
    assert colours_under(cmds, "/probe/predicted/001/x") != colours_under(cmds, "/probe/predicted/001/y")
    assert "probe frame P, predicted" in page and "probe frame P, measured" in page
    assert "Largest orientation errors: pose" in page and "orientation error [deg]" in page


def test_validation_page_draws_the_worst_probe_frames(pose_pages):
    """40 rows: the 30 of the largest orientation errors drawn; the measured frame is the predicted
    one turned by the magnified error, at the tip of the magnified residual arrow."""
    w, cal, val = pose_pages
    page = self_contained(w / "val.html")
    cmds = commands(page)
    X = transforms(cmds)
    q, R_WP, p_WP = _probe_expected(cal, w / "held.csv")
    deg = np.rad2deg(np.linalg.norm(val.rot_residuals_W, axis=1))
    drawn = sorted(int(p.rsplit("/", 1)[1]) - 1 for p in X if re.fullmatch(r"/probe/predicted/\d{3}", p))
    assert len(drawn) == MAX_TRIADS < len(q)
    assert drawn == sorted(np.argsort(-deg)[:MAX_TRIADS].tolist())
    scale = float(re.search(r"arrow from predicted to measured, x([\d.]+)", page).group(1))
    turn = float(re.search(r"magnified x([\d.]+)", page).group(1))
    assert turn * deg[drawn].max() > 5.0  # hundredths of a degree made visible
    for k in drawn:
        M = X[f"/probe/measured/{k + 1:03d}"]
        R = Rotation.from_rotvec(turn * val.rot_residuals_W[k]).as_matrix() @ R_WP[k]
        assert_allclose(M[:3, :3], R, rtol=0, atol=1e-9)
        assert_allclose(M[:3, 3] / MM, p_WP[k] + scale * val.residuals_W[k], rtol=0, atol=1e-6)
        assert_allclose(X[f"/probe/predicted/{k + 1:03d}"][:3, :3], R_WP[k], rtol=0, atol=1e-9)
    worst = int(np.argmax(deg))
    assert f"Largest orientation errors: pose {worst + 1}: {deg[worst]:.4f} deg" in page
    assert "validation (tracker frame kept)" in page


# --- plane contacts and distances -----------------------------------------------------------------
@pytest.fixture(scope="module")
def contact_pages(tmp_path_factory):
    """kr16: 90 touches of three planes and 30 pivot rows calibrated by ``kpioed calibrate --html``;
    the held-out touches validated by ``kpioed validate --html``."""
    w = tmp_path_factory.mktemp("contacts")
    robot, _, truth, files = _scenario(w, "kr16", 1, points=True)
    q = _inside(robot, np.random.default_rng(7), 40)
    centre = reflector_world(truth["model"], q).mean(axis=0)
    dist, _ = simulate_distances(
        robot, q, pivot=np.zeros(40, int), pivots=centre[None], sigma_mm=0.01, seed=8, truth=truth["model"]
    )
    frame = pd.DataFrame(q_to_file(robot, dist.q), columns=q_columns(robot))
    frame["pivot"], frame["length_mm"] = 1, dist.length
    frame.to_csv(w / "pivot.csv", index=False)
    cal = w / "cal.yaml"
    argv = ["--robot", "kr16", "--planes", str(files["fit"])]
    assert (
        main(
            [
                "calibrate",
                *argv,
                "--distances",
                str(w / "pivot.csv"),
                "--out",
                str(cal),
                "--html",
                str(w / "cal.html"),
            ]
        )
        == 0
    )
    assert (
        main(["validate", "--robot", str(cal), "--planes", str(files["held"]), "--html", str(w / "val.html")])
        == 0
    )
    return w, cal, files


def _environment(cal):
    env = yaml.safe_load(cal.read_text())["contact_environment"]
    normals = np.array([p["normal"] for p in env["planes"]])
    offsets = np.array([p["offset_mm"] for p in env["planes"]])
    return normals, offsets, np.array(env["pivots_mm"])


@pytest.mark.parametrize("which", ["cal", "val"])
def test_plane_patches_are_the_estimated_planes(contact_pages, which):
    """Each patch: its normal (the box's z axis) and offset (n . centre) those of the model file's
    plane to 1e-9; it holds the projections of its touches; the touches are the model's tool points."""
    w, cal, files = contact_pages
    page = self_contained(w / f"{which}.html")
    cmds = commands(page)
    X, obj = transforms(cmds), objects(cmds)
    normals, offsets, _ = _environment(cal)
    rows = pd.read_csv(files["fit" if which == "cal" else "held"])
    robot = load_robot(str(cal))
    model = nominal_model(robot, load_cell(robot=robot))
    q = np.deg2rad(rows[[f"q{j + 1}_deg" for j in range(6)]].to_numpy())
    p_W = reflector_world(model, q)
    for k in range(3):
        M = X[f"/contacts/planes/plane {k + 1}/patch"]
        n, c = M[:3, 2], M[:3, 3] / MM
        assert_allclose(n, normals[k], rtol=0, atol=1e-9)
        assert float(n @ c) == pytest.approx(offsets[k], abs=1e-9)
        box = obj[f"/contacts/planes/plane {k + 1}/patch"]["geometries"][0]
        half = np.array([box["width"], box["height"], box["depth"]]) / MM / 2  # along x, y, z of M
        local = (p_W[rows.plane == k + 1] - c) @ M[:3, :3]
        assert np.all(np.abs(local[:, :2]) < half[:2]) and half[2] < 2.0
    touches = sorted(p for p in X if "/touches/" in p)
    assert len(touches) == len(rows)
    for i in range(len(rows)):
        path = f"/contacts/planes/plane {rows.plane[i]}/touches/{i + 1:03d}"
        assert_allclose(X[path][:3, 3] / MM, p_W[i], rtol=0, atol=1e-6)


def test_touches_coloured_by_their_signed_residual(contact_pages):
    """The validation page's touch of the largest |residual| is full red (above) or blue (below)."""
    w, cal, files = contact_pages
    res = api.validate(str(cal), planes=files["held"])
    r = res.plane_residuals
    cmds = commands((w / "val.html").read_text())
    rows = pd.read_csv(files["held"])
    k = int(np.argmax(np.abs(r)))
    path = f"/contacts/planes/plane {rows.plane[k]}/touches/{k + 1:03d}"
    assert colours_under(cmds, path) == {hex_colour(ABOVE if r[k] > 0 else BELOW)}
    j = int(np.argmin(np.abs(r)))
    path = f"/contacts/planes/plane {rows.plane[j]}/touches/{j + 1:03d}"
    assert colours_under(cmds, path) == {hex_colour(signed_colour(r[j], float(np.abs(r).max())))}
    assert f"residual +{np.abs(r).max():.4f} mm" in (w / "val.html").read_text()


def test_pivot_and_bars_on_the_calibration_page(contact_pages):
    """The pivot at the model file's pivot; each pivot row's rod from its tool point to the pivot."""
    w, cal, _ = contact_pages
    cmds = commands((w / "cal.html").read_text())
    X, obj = transforms(cmds), objects(cmds)
    _, _, pivots = _environment(cal)
    assert_allclose(X["/contacts/distances/pivots/pivot 1"][:3, 3] / MM, pivots[0], rtol=0, atol=1e-9)
    robot = load_robot(str(cal))
    model = nominal_model(robot, load_cell(robot=robot))
    q = np.deg2rad(pd.read_csv(w / "pivot.csv")[[f"q{j + 1}_deg" for j in range(6)]].to_numpy())
    p_W = reflector_world(model, q)
    n_planes = len(pd.read_csv(next(w.glob("planes.csv"))))
    for i in range(len(q)):
        path = f"/contacts/distances/rows/{n_planes + i + 1:03d}"
        assert_allclose(X[f"{path}/tool"][:3, 3] / MM, p_W[i], rtol=0, atol=1e-6)
        assert_allclose(X[f"{path}/bar"][:3, 3] / MM, 0.5 * (p_W[i] + pivots[0]), rtol=0, atol=1e-6)
        length = obj[f"{path}/bar"]["geometries"][0]["height"] / MM
        assert length == pytest.approx(np.linalg.norm(p_W[i] - pivots[0]), abs=1e-6)
    # the robot at every contact pose, no laser beams
    paths = set(obj)
    assert not any(p.endswith("/beam") for p in paths)
    assert f"/poses/pose {n_planes + len(q):03d}" in {c["path"] for c in cmds if c["type"] == "set_property"}


def test_tracker_points_with_contacts(contact_pages):
    """Tracker points validated with the touches: at the model file's predicted points, the
    residual arrows as on a calibration page."""
    w, cal, files = contact_pages
    assert main(["validate", "--robot", str(cal), str(files["points"]), "--planes", str(files["held"]),
                 "--html", str(w / "both.html")]) == 0  # fmt: skip
    cmds = commands(self_contained(w / "both.html"))
    X = transforms(cmds)
    robot = load_robot(str(cal))
    model = nominal_model(robot, load_cell(robot=robot))
    q = np.deg2rad(pd.read_csv(files["points"])[[f"q{j + 1}_deg" for j in range(6)]].to_numpy())
    p_W = reflector_world(model, q)
    for k in range(len(q)):
        assert_allclose(
            X[f"/contacts/tracker points/predicted/{k + 1:03d}"][:3, 3] / MM, p_W[k], rtol=0, atol=1e-6
        )
    assert sum(
        p.startswith("/contacts/tracker points/residuals/") and p.endswith("/shaft") for p in X
    ) == len(q)


def test_html_to_an_unwritable_path_is_one_line(contact_pages, pose_pages, capsys):
    w, cal, files = contact_pages
    (w / "afile").write_text("x")
    for argv in (
        ["calibrate", "--robot", "kr16", "--planes", str(files["fit"])],
        ["validate", "--robot", str(cal), "--planes", str(files["held"])],
        ["validate", "--robot", str(pose_pages[1]), str(pose_pages[0] / "held.csv")],
    ):
        assert main([*argv, "--html", str(w / "afile" / "page.html")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "afile" in err and "is a file, not a folder" in err, err
        assert main([*argv, "--html", str(w / "page.png")]) == 2
        assert "expected a file name ending in .html" in capsys.readouterr().err
    assert not (w / "page.png").exists()
