"""The KPI design of a pivot ballbar (the tool ball on the sphere about the pivot) and the contact
designs from the command line (kpioed_drake.design.contact, ``kpioed design --measure plane|ballbar``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from contact_helpers import drake_tool_points
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake.cli import main
from kpioed_drake.design.contact import design as contact_opt
from kpioed_drake.design.contact.poses import ON_SURFACE_TOL_MM, contact_poses, surface_rows
from kpioed_drake.design.contact.problem import make_ballbar_problem
from kpioed_drake.design.contact.surfaces import BALLBAR
from kpioed_drake.errors import InputError
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.tracker.contactdata import DistanceData, read_distances, read_planes
from kpioed_drake.tracker.distance import distance_jacobian
from kpioed_drake.tracker.feasibility import TOL_MM, FeasibilityChecker

L_MM = 150.0


@pytest.fixture(scope="module")
def ballbar():
    """The kr16's ballbar problem (the pivot at its working TCP, the default; the bar L_MM long), 40
    feasible poses on its sphere and their pivot (0)."""
    problem = make_ballbar_problem("kr16", bar_length_mm=L_MM)
    return problem, *contact_poses(problem, problem.surfaces, n=40, seed=3)


def _on_the_sphere_and_in_the_cups(problem, q):
    """Drake's tool points at the bar's length from the pivot; the bar within the cups' angles."""
    c = problem.surfaces.centres[0]
    p = drake_tool_points(problem, q)
    assert_allclose(np.linalg.norm(p - c, axis=1), L_MM, atol=1e-5)
    scene = build_scene(problem.robot)
    for qi, pi in zip(q, p, strict=True):
        scene.set_q(qi)
        tool = pi - scene.X_WB(problem.robot.n_joints).translation() / MM
        bar = c - pi
        assert np.degrees(np.arccos(tool @ bar / np.linalg.norm(tool) / L_MM)) <= BALLBAR.cup_deg + 1e-6
        assert np.degrees(np.arcsin(-bar[2] / L_MM)) >= -BALLBAR.dip_deg - 1e-6


def test_the_ballbar_problem_estimates_the_pivot_and_its_known_length_fixes_the_scale(ballbar):
    problem = ballbar[0]
    names = problem.param_names
    assert problem.rows_per_pose == 1 and problem.measure == "ballbar"
    assert {"pivot1_x", "pivot1_y", "pivot1_z"} <= set(names)
    assert not any(n.startswith(("tracker_", "bar")) for n in names)  # no tracker; the length is known
    assert {"theta1", "d1", "theta6", "d6"} <= set(problem.gauge.names)  # the points' gauge
    assert "reflector_z" in names  # a known length fixes the scale: no tool length held
    frames = problem.model.frames(problem.q_works[:1])  # the default pivot: the working TCP
    tcp = frames.at_link(None)[1][0] + frames.at_link(None)[0][0] @ problem.model.p_FQ
    assert_allclose(problem.surfaces.centres[0], tcp, atol=1e-9)


def test_rows_are_the_fits_pivot_rows_and_their_joint_derivatives_match_differences(ballbar):
    problem, q, pivot = ballbar
    assert_allclose(problem.surface_of(q), 0)
    F, dF = problem.F1(q, with_dq=True)
    data = DistanceData.from_arrays(q, np.full(len(q), L_MM), pivot=pivot)
    r, H = distance_jacobian(problem.model, data)
    assert_allclose(r, 0.0, atol=ON_SURFACE_TOL_MM)  # on the sphere
    assert_allclose(F, H[:, problem.free] / problem.sigma, rtol=1e-12, atol=1e-9)
    sub = q[:6]
    fd = central_fd(lambda x: problem.F1(x), sub, 1e-6)  # (6, k, 6, nj)
    want = np.einsum("akbj->abjk", fd)[np.arange(6), np.arange(6)]  # (6, nj, k): pose a's own rows
    scale = np.abs(dF[:6, :, 0]).max()
    assert_allclose(dF[:6, :, 0], want, rtol=0, atol=1e-8 * scale)
    cols = [problem.param_names.index(f"pivot1_{a}") for a in "xyz"]
    assert np.abs(dF[:6, :, 0][..., cols]).max() > 0  # the bar's direction turns with the pose


def test_the_sphere_constraints_gradient_matches_differences(ballbar):
    problem, q, pivot = ballbar[0], ballbar[1][:5], ballbar[2][:5]
    _, g, rules = surface_rows(problem, q, pivot, problem.surfaces)
    fd = central_fd(lambda x: surface_rows(problem, x, pivot, problem.surfaces)[0], q, 1e-6)
    assert_allclose(g, np.einsum("aaj->aj", fd), rtol=1e-6, atol=1e-6)
    assert rules.all()


def test_poses_on_the_sphere_by_drakes_kinematics_within_the_limits_and_the_cups(ballbar):
    problem, q, _ = ballbar
    _on_the_sphere_and_in_the_cups(problem, q)
    assert np.all((q >= problem.robot.lower) & (q <= problem.robot.upper))


def test_a_small_ballbar_design_is_certified_on_the_sphere_and_collision_free(ballbar):
    problem, q_random, _ = ballbar
    des = contact_opt.ballbar_design(problem, 30, pool=200, starts=8, rounds=3, verify=200, seed=0)
    assert des.q.shape == (30, 6) and np.all(des.pivot == 0)
    assert 0 < des.bound <= des.value and 0 < des.efficiency <= 1.0
    assert_allclose(des.value, problem.criteria(des.q)["kpi_avg_var_mm2"], rtol=1e-12)
    assert des.value < problem.criteria(q_random[:30])["kpi_avg_var_mm2"]  # better than random poses
    _on_the_sphere_and_in_the_cups(problem, des.q)
    (cell,) = problem.surfaces.cells(problem.cell)  # Drake's signed distances; the bar as the beam
    checker = FeasibilityChecker(problem.robot, cell)
    clear = [checker.clearances(qi) for qi in des.q]
    assert any("pivot1_stand" in name for name in clear[0]) and any(n.startswith("beam") for n in clear[0])
    assert min(min(c.values()) for c in clear) >= -TOL_MM


def test_too_few_poses_and_another_system_are_refused(ballbar):
    problem = ballbar[0]
    with pytest.raises(InputError, match="10 poses cannot determine the 24 parameters"):
        contact_opt.ballbar_design(problem, 10)
    with pytest.raises(InputError, match="surfaces are pivots, not planes"):
        contact_opt.plane_design(problem, 40)
    with pytest.raises(InputError, match="bar_length_mm: expected a length > 0"):
        make_ballbar_problem("kr16", bar_length_mm=-1.0)


def _run(capsys, *argv):
    code = main(["design", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_command_line_ballbar_design_writes_a_distance_file(capsys, tmp_path):
    out, rec = tmp_path / "bb.csv", tmp_path / "bb.json"
    pivot = "1600,0,1300"
    code, text, err = _run(
        capsys, "--robot", "kr16", "--measure", "ballbar", "--pivot", pivot, "--bar-length-mm", "200",
        "--n", "30", "--rounds", "1", "--out", str(out), "--json", str(rec),
    )  # fmt: skip
    assert code == 0, err
    assert "efficiency" in text and "pivot 1 at [1600.0, 0.0, 1300.0] mm, bar 200 mm" in text
    data = read_distances(out, make_ballbar_problem("kr16").robot)  # a distance file of pivot rows
    assert data.n == 30 and np.all(data.pivot == 0) and np.all(data.length == 200.0)
    r = json.loads(rec.read_text())
    assert r["measure"] == "ballbar" and r["pivots"] == [
        {"pivot_mm": [1600.0, 0.0, 1300.0], "bar_length_mm": 200.0}
    ]
    assert 0 < r["efficiency"] <= 1 and r["bound_mm2"] <= r["kpi_avg_var_mm2"]
    assert len(r["poses"]) == 30 and min(p["min_clearance_mm"] for p in r["poses"]) >= -TOL_MM


def test_the_command_line_plane_design_reads_a_csv_plane_set(capsys, tmp_path):
    planes = tmp_path / "planes.csv"
    planes.write_text("nx,ny,nz,offset_mm\n0,0,2,400\n-1,0,0,-900\n0,-1,0,-700\n")  # (normalised)
    out, rec = tmp_path / "touches.csv", tmp_path / "touches.json"
    code, text, err = _run(
        capsys, "--robot", "kr16", "--measure", "plane", "--planes", str(planes), "--n", "30",
        "--rounds", "1", "--out", str(out), "--json", str(rec),
    )  # fmt: skip
    assert code == 0, err
    assert "touches of 3 planes" in text and "reflector_z" in text  # the scale the planes do not fix
    touches = read_planes(out, make_ballbar_problem("kr16").robot, renumber=True)  # a plane-contact file
    assert touches.n == 30
    r = json.loads(rec.read_text())
    assert r["planes"][0] == {"normal": [0.0, 0.0, 1.0], "offset_mm": 400.0}
    assert sum(r["poses_per_plane"]) == 30 and 0 < r["efficiency"] <= 1


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--measure", "ballbar", "--pivot", "1,2"], "--pivot: expected x,y,z"),
        (["--measure", "ballbar", "--pivot", "a,b,c"], "--pivot: expected x,y,z"),
        (["--measure", "ballbar", "--bar-length-mm", "0"], "--bar-length-mm: expected a finite number > 0"),
        (["--measure", "ballbar", "--planes", "p.yaml"], "--planes: not used by a ballbar design"),
        (["--measure", "plane", "--planes", "missing.yaml"], "missing.yaml: file not found"),
        (["--robot", "kr300", "--measure", "plane"], "kr300: no default plane set"),
        (["--measure", "plane", "--pivot", "1,2,3"], "--pivot: not used by a plane design"),
        (["--measure", "ballbar", "--given", "d.csv"], "--measure ballbar: a KPI design without a tracker"),
        (["--measure", "plane", "--criterion", "param"], "not with --criterion param"),
        (["--measure", "ballbar", "--n", "10"], "--n: 10 poses cannot determine"),
        (["--criterion", "kpi", "--pivot", "1,2,3"], "--pivot: only with --measure plane or ballbar"),
    ],
)
def test_bad_contact_design_arguments(capsys, tmp_path, argv, message):
    robot = [] if "--robot" in argv else ["--robot", "kr16"]
    code, _, err = _run(capsys, *robot, "--n", "30", *argv, "--out", str(tmp_path / "x.csv"))
    assert code == 2 and message in err, err
    assert not (tmp_path / "x.csv").exists()


def test_a_plane_set_file_with_a_bad_cell_names_its_row_and_column(capsys, tmp_path):
    planes = tmp_path / "planes.csv"
    planes.write_text("nx,ny,nz,offset_mm\n0,0,1,400\n0,0,x,100\n")
    code, _, err = _run(
        capsys,
        "--robot",
        "kr16",
        "--measure",
        "plane",
        "--planes",
        str(planes),
        "--out",
        str(tmp_path / "o.csv"),
    )
    assert code == 2 and "planes.csv: row 3, column 'nz': 'x' is not a number" in err
