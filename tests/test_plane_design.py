"""The KPI design of plane touches (issue 44): F1 rows and dF1/dq, poses on the planes, the design
and its certificate (kpioed_drake.design.contact)."""

from __future__ import annotations

import numpy as np
import pytest
from contact_helpers import drake_tool_points
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.pool import solve_pool
from kpioed_drake.design.approximate.search import dual_values, pose_rows
from kpioed_drake.design.contact import design as plane_opt
from kpioed_drake.design.contact.poses import ON_SURFACE_TOL_MM, contact_poses
from kpioed_drake.design.contact.problem import make_plane_problem
from kpioed_drake.design.contact.surfaces import FLANGE_CLEARANCE_MM
from kpioed_drake.errors import InputError
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.tracker.contactdata import PlaneData
from kpioed_drake.tracker.plane import plane_jacobian

# a table, two walls and a tilted plate, normals towards the free side (docs/contacts.md)
NORMALS = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0], [1, 1, 1]]) / np.array([[1], [1], [1], [3**0.5]])
OFFSETS = np.array([400.0, -900.0, -700.0, 1300.0])


@pytest.fixture(scope="module")
def problem():
    return make_plane_problem("kr16", NORMALS, OFFSETS, sigma_mm=0.01)


@pytest.fixture(scope="module")
def touches(problem):
    return contact_poses(problem, problem.surfaces, n=40, seed=3)


def test_the_problem_has_the_contact_gauge_and_one_row_per_pose(problem):
    names = problem.param_names
    assert problem.rows_per_pose == 1
    assert all(f"plane{k}_{p}" in names for k in (1, 2, 3, 4) for p in ("tx", "ty", "d"))
    assert not any(n.startswith("tracker_") for n in names)  # no tracker: its pose is not estimated
    for held in ("theta1", "d1", "reflector_z"):  # the points' gauge and the scale (the tool length)
        assert held in problem.gauge.names and held not in names


def test_rows_are_the_fits_plane_rows_and_their_joint_derivatives_match_differences(problem, touches):
    q, plane = touches
    assert_allclose(problem.surface_of(q), plane)
    F, dF = problem.F1(q, with_dq=True)
    r, H = plane_jacobian(problem.model, PlaneData.from_arrays(q, plane))
    assert_allclose(r, 0.0, atol=ON_SURFACE_TOL_MM)
    assert_allclose(F, H[:, problem.free] / problem.sigma, rtol=1e-12, atol=1e-9)
    assert dF.shape == (len(q), 6, 1, problem.n_params)
    sub = q[:6]
    fd = central_fd(lambda x: problem.F1(x), sub, 1e-6)  # (6, k, 6, nj)
    want = np.einsum("akbj->abjk", fd)[np.arange(6), np.arange(6)]  # (6, nj, k): pose a's own rows
    scale = np.abs(dF[:6, :, 0]).max()
    assert_allclose(dF[:6, :, 0], want, rtol=0, atol=1e-8 * scale)
    assert np.abs(dF[:6, :, 0]).max() > 0


def test_touches_are_on_their_planes_by_drakes_kinematics(problem, touches):
    q, plane = touches
    p = drake_tool_points(problem, q)
    assert_allclose(np.sum(NORMALS[plane] * p, axis=1), OFFSETS[plane], atol=1e-5)
    assert np.all((q >= problem.robot.lower) & (q <= problem.robot.upper))


def test_the_search_raises_g_and_keeps_each_pose_on_its_plane(problem, touches):
    q, plane = touches
    sol = solve_pool(pose_rows(problem, q), kpi_factor(problem))
    q_max, g = plane_opt.maximize_on_surfaces(problem, q[:8], plane[:8], sol.Y, collision=True)
    g0 = dual_values(pose_rows(problem, q[:8]), sol.Y)
    assert np.all(g >= g0) and np.any(g > g0 * 1.01)
    assert_allclose(g, dual_values(pose_rows(problem, q_max), sol.Y), rtol=1e-10)
    p = drake_tool_points(problem, q_max)
    assert_allclose(np.sum(NORMALS[plane[:8]] * p, axis=1), OFFSETS[plane[:8]], atol=1e-5)
    assert_allclose(problem.surface_of(q_max), plane[:8])


def test_a_small_design_is_certified_and_every_pose_touches_its_plane(problem):
    des = plane_opt.plane_design(problem, 36, pool=200, starts=8, rounds=3, verify=200, seed=0)
    assert des.q.shape == (36, 6)
    assert 0 < des.bound <= des.value and 0 < des.efficiency <= 1.0
    assert_allclose(des.value, problem.criteria(des.q)["kpi_avg_var_mm2"], rtol=1e-12)
    p = drake_tool_points(problem, des.q)
    assert_allclose(np.sum(NORMALS[des.plane] * p, axis=1), OFFSETS[des.plane], atol=1e-5)
    scene = build_scene(problem.robot)  # the flange on the plane's free side
    for qi, k in zip(des.q, des.plane, strict=True):
        scene.set_q(qi)
        o_F = scene.X_WB(problem.robot.n_joints).translation() / MM
        assert NORMALS[k] @ o_F - OFFSETS[k] >= FLANGE_CLEARANCE_MM - 1e-6


def test_an_untouched_plane_is_not_estimated_and_too_few_touches_are_refused(problem, touches):
    q, plane = touches
    keep = plane != 3
    use = problem.used_columns(q[keep])
    names = np.array(problem.param_names)
    assert set(names[~use]) == {"plane4_tx", "plane4_ty", "plane4_d"}
    Cp, _ = problem.covariances(q[keep])
    assert np.all(Cp[~use] == 0)
    with pytest.raises(InputError, match="touches do not determine"):
        problem.covariances(q[:20])


def test_the_exact_criterion_gradient_matches_differences_and_the_polish_lowers_it(problem, touches):
    q, plane = touches
    K = kpi_factor(problem)
    use = problem.used_columns(q)
    phi, grad = plane_opt._phi_and_grad(problem, q, K, use)
    assert_allclose(phi, problem.criteria(q)["kpi_avg_var_mm2"], rtol=1e-10)
    fd = central_fd(
        lambda x: plane_opt._phi_and_grad(problem, np.concatenate([x, q[4:]]), K, use)[0], q[:4], 1e-6
    )
    assert_allclose(grad[:4], fd, rtol=1e-5, atol=1e-6 * np.abs(grad).max())
    q_p = plane_opt.polish_on_surfaces(problem, q, plane, collision=True, steps=20)
    assert problem.criteria(q_p)["kpi_avg_var_mm2"] < phi
    p = drake_tool_points(problem, q_p)
    assert_allclose(np.sum(NORMALS[plane] * p, axis=1), OFFSETS[plane], atol=1e-5)


def test_a_plane_touched_once_or_twice_gives_its_touches_to_the_other_planes():
    plane = np.array([0, 0, 1, 1, 2, 2, 3])
    counts = np.array([3, 0, 2, 1, 3, 0, 1])  # plane 3 touched once: undetermined
    out = plane_opt._without_lone_surfaces(counts, plane)
    assert out.sum() == counts.sum() and out[6] == 0
    assert_allclose(out[:6] - counts[:6], [1, 0, 0, 0, 0, 0])
    assert_allclose(plane_opt._without_lone_surfaces(out, plane), out)
