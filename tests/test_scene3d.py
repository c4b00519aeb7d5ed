"""3-D pages (kpioed_drake.scene3d): content, colours, witness points, size, no network references.

The scene commands of a page are the msgpack messages that Meshcat's static export embeds as
``data:`` URLs; the tests decode them and look at paths, colours and poses.
"""

import base64
import gc
import re
import socket

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydrake.geometry import Meshcat

from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.robot.plant import build_scene
from kpioed_drake.scene3d import (
    INFEASIBLE,
    ROBOT,
    calibration_page,
    design_page,
    diagnosis_page,
    external_references,
    write_page,
)
from kpioed_drake.scene3d.canvas import Canvas, nice_scale
from kpioed_drake.scene3d.drawing import clearance_witness
from kpioed_drake.tracker.feasibility import FeasibilityChecker
from kpioed_drake.tracker.measurement import measure, nominal_model

msgpack = pytest.importorskip("msgpack")  # installed with the dask extra (make setup)

_DATA = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)')


def commands(page: str) -> list[dict]:
    """The Meshcat scene commands embedded in a static page."""
    return [msgpack.unpackb(base64.b64decode(b), strict_map_key=False) for b in _DATA.findall(page)]


def colours_under(cmds, prefix: str) -> set[int]:
    """Material colours (0xRRGGBB) of the objects set under ``prefix``."""
    out = set()
    for c in cmds:
        if c["type"] == "set_object" and c["path"].startswith(prefix):
            out |= {m["color"] for m in c["object"].get("materials", [])}
    return out


def hex_colour(rgba) -> int:
    """Meshcat's material colour of an Rgba (Drake truncates each channel times 255)."""
    return (int(rgba.r() * 255) << 16) + (int(rgba.g() * 255) << 8) + int(rgba.b() * 255)


@pytest.fixture(scope="module")
def kr16():
    robot = load_robot("kr16")
    cell = load_cell(robot=robot)
    q_bad = robot.q_work.copy()
    q_bad[1] += 1.2  # upper arm down into the floor / car
    q = np.array([robot.q_work, robot.q_work + [0.2, -0.1, 0.05, 0.0, 0.0, 0.5], q_bad])
    reports = FeasibilityChecker(robot, cell).check(q)
    assert [r.feasible for r in reports] == [True, True, False]  # the test's premise
    return robot, cell, q, reports


@pytest.fixture(scope="module")
def design(kr16):
    robot, cell, q, reports = kr16
    Cs = np.diag([0.04, 0.02, 0.01])
    compare = ("heuristic", q[:2] + 0.1, np.diag([0.09, 0.05, 0.03]))
    return design_page(robot, cell, q, reports=reports, Cs=Cs, compare=compare, title="kr16 test page")


def test_design_page_has_the_scene(kr16, design):
    robot, cell, q, reports = kr16
    cmds = commands(design)
    paths = {c["path"] for c in cmds if c["type"] == "set_object"}
    for k in range(3):
        group = f"/poses/pose {k + 1:03d}"
        assert {f"{group}/beam", f"{group}/reflector", f"{group}/clearance/segment"} <= paths
        assert sum(p.startswith(f"{group}/robot/") for p in paths) == sum(
            c.frame >= 1 for c in robot.capsules
        )
    for name in ("floor", "wall", "mount", "car_body", "car_cabin", "tracker/head"):
        assert f"/cell/{name}" in paths
    assert {"/kpi/ellipsoid 1", "/kpi/ellipsoid 2"} <= paths
    assert sum(p.startswith("/compare/reflectors/") for p in paths) == 2
    assert "<title>kr16 test page</title>" in design
    # 95 % semi-axes of Cs = diag(0.04, 0.02, 0.01) mm^2: sqrt(chi2_3(0.95) * eig) [mm], and the scale.
    assert "semi-axes 0.280, 0.395, 0.559 mm" in design
    assert "Ellipsoids magnified x200" in design  # 0.559 mm drawn at about 250 mm: a round x200
    assert external_references(design) == []


def test_design_page_colours_by_feasibility(kr16, design):
    cmds = commands(design)
    assert colours_under(cmds, "/poses/pose 001/robot/") == {hex_colour(ROBOT)}
    assert colours_under(cmds, "/poses/pose 002/robot/") == {hex_colour(ROBOT)}
    assert colours_under(cmds, "/poses/pose 003/robot/") == {hex_colour(INFEASIBLE)}
    assert hex_colour(ROBOT) != hex_colour(INFEASIBLE)


def test_design_page_poses_and_animation(kr16, design):
    """The robot links sit where the plant puts them, and frame k of the animation shows pose k only."""
    robot, cell, q, reports = kr16
    cmds = commands(design)
    scene = build_scene(robot, cell)
    scene.set_q(q[2])
    qo = scene.query_object()
    ids = {name: gid for gid, name in scene.geometry_names.items()}
    X = {c["path"]: c["matrix"] for c in cmds if c["type"] == "set_transform"}
    M = np.array(X["/poses/pose 003/robot/forearm"]).reshape(4, 4).T  # column-major
    assert_allclose(M, qo.GetPoseInWorld(ids["forearm"]).GetAsMatrix4(), atol=1e-12)
    anim = next(c for c in cmds if c["type"] == "set_animation")
    assert anim["options"]["play"] is False
    shown = {}
    for a in anim["animations"]:
        for track in a["clip"]["tracks"]:
            if track["name"] == ".visible":
                shown[a["path"]] = {key["time"]: key["value"] for key in track["keys"]}
    assert set(shown) == {f"/poses/pose {k + 1:03d}" for k in range(3)}
    for frame in range(3):
        visible = [p for p, keys in shown.items() if keys[max(t for t in keys if t <= frame)]]
        assert visible == [f"/poses/pose {frame + 1:03d}"]


def test_clearance_witness_points_match_the_checker(kr16):
    """For every checked pair (Drake pairs and beam pairs) the witness points are |clearance| apart."""
    robot, cell, q, _ = kr16
    checker = FeasibilityChecker(robot, cell)
    scene = build_scene(robot, cell)
    n_beam = 0
    for qk in q:
        for pair, d in checker.clearances(qk).items():
            p_A, p_B = clearance_witness(scene, robot, cell, qk, pair)
            assert np.linalg.norm(p_A - p_B) == pytest.approx(abs(d), abs=1e-6), pair
            n_beam += pair.startswith("beam")
    assert n_beam > 0


def arrow_length_mm(cmds, path: str) -> float:
    """Length of the arrow at ``path`` (shaft plus cone head) [mm]."""
    heights = [
        c["object"]["geometries"][0]["height"]
        for c in cmds
        if c["type"] == "set_object" and c["path"] in (f"{path}/shaft", f"{path}/head")
    ]
    assert len(heights) == 2, path
    return 1e3 * sum(heights)


def test_calibration_and_diagnosis_pages(kr16, tmp_path):
    robot, cell, q, _ = kr16
    model = nominal_model(robot, cell)
    h = measure(model, q)
    rng = np.random.default_rng(0)
    eta = h + rng.normal(0.0, 0.05, h.shape)
    eta[2] += [3.0, 0.0, 0.0]
    r = np.linalg.norm(eta - h, axis=1)
    page = calibration_page(robot, cell, model, q, eta, h, outliers=[2])
    cmds = commands(page)
    paths = {c["path"] for c in cmds if c["type"] == "set_object"}
    assert {"/calibration/residuals/001/shaft", "/calibration/residuals/002/head"} <= paths
    assert {"/calibration/outliers/003/shaft", "/calibration/outliers/003/halo"} <= paths
    assert not any(p.startswith("/calibration/residuals/003") for p in paths)
    scale = float(re.search(r"residuals x(\d+)", page).group(1))
    # The scale draws the longest kept residual at 100..250 mm (a round 1, 2, 5 x 10^k); the
    # arrows are that long, the outlier's longer by the ratio of the residuals.
    assert 100.0 <= scale * max(r[:2]) <= 250.0
    for k in range(3):
        group = "outliers" if k == 2 else "residuals"
        assert arrow_length_mm(cmds, f"/calibration/{group}/{k + 1:03d}") == pytest.approx(scale * r[k])
    assert external_references(page) == []
    page = diagnosis_page(robot, cell, model, q, eta - h, 0.1 * (eta - h), label="joint_elasticity")
    cmds = commands(page)
    scale = float(re.search(r"joint_elasticity, x(\d+)", page).group(1))
    for k in range(3):
        assert arrow_length_mm(cmds, f"/diagnosis/before/{k + 1:03d}") == pytest.approx(scale * r[k])
        assert arrow_length_mm(cmds, f"/diagnosis/after/{k + 1:03d}") == pytest.approx(0.1 * scale * r[k])
    out = write_page(tmp_path / "sub" / "d.html", page)
    assert out.read_text() == page


def test_page_size_and_no_meshcat_left(kr16, design):
    """A page is the ~2.2 MB viewer plus ~30 kB per pose; no Meshcat server outlives its page."""
    assert 2e6 < len(design) < 20e6
    robot, cell, q, reports = kr16
    small = design_page(robot, cell, q[:1], reports=reports[:1])
    per_pose = (len(design) - len(small)) / 2
    assert per_pose < 100e3  # 60 poses stay far below 20 MB
    gc.collect()
    assert not [o for o in gc.get_objects() if isinstance(o, Meshcat)]


def test_nice_scale():
    assert nice_scale(3.0, 200.0) == 50.0
    assert nice_scale(0.8, 250.0) == 200.0
    assert nice_scale(0.0, 200.0) == 1.0


def test_canvas_frees_its_port():
    """Each page runs one Meshcat server on an ephemeral localhost port, closed with the page."""
    canvas = Canvas("t")
    port = canvas.meshcat.port()
    with socket.socket() as s, pytest.raises(OSError):
        s.bind(("127.0.0.1", port))
    canvas.close()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
