"""Chain (URDF) robots: kinematics against Drake, closed-form derivatives against finite differences
(revolute and prismatic joints), the automatic gauge and the UR5's URDF twin."""

import dataclasses
import math

import numpy as np
import pytest
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake.design.exact.constraints import incidence_rows
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects.gravity import gravity_model, gravity_torques
from kpioed_drake.estimation.identifiability import check_identifiability
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.chain import chain_links
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.jointmap import commandable_projection
from kpioed_drake.robot.kinematics import (
    forward_kinematics,
    link_frames,
    point_jacobian,
    point_velocity_jacobian,
)
from kpioed_drake.robot.models import MODELS_DIR, load_cell, load_robot
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.tracker.measurement import incidence_cosines, measure, measurement_jacobian, nominal_model

UR5_URDF = str(MODELS_DIR / "robots" / "ur5.urdf")


@pytest.fixture(scope="module")
def lift7():
    return load_robot("lift7")


@pytest.fixture(scope="module")
def ur5_urdf():
    return load_robot(UR5_URDF)


def _poses(robot, n, seed):
    return np.random.default_rng(seed).uniform(robot.lower, robot.upper, size=(n, robot.n_joints))


def _perturbed(robot, seed):
    """The robot's nominal model with random placement errors on every joint parameter."""
    nom = nominal_model(robot, load_cell(robot=robot))
    rng = np.random.default_rng(seed)
    p = nom.p.copy()
    lay = nom.layout
    p[lay.joints] += np.where(lay.is_angle[lay.joints], 0.02, 2.0) * rng.standard_normal(lay.joints.stop)
    p[lay.tracker_rotation] = 0.01 * rng.standard_normal(3)
    return nom.with_params(p)


def test_loaded_chain_robots(lift7, ur5_urdf):
    assert lift7.n_joints == 7 and lift7.per_joint == 7
    assert list(lift7.prismatic) == [True] + [False] * 6
    assert lift7.upper[0] == pytest.approx(500.0) and lift7.lower[0] == 0.0  # mm
    assert lift7.joint_names[:2] == ("lift", "A1")
    # 4 per revolute, 2 per prismatic joint, 6 for the base (the tracker), 3 for the point: 29
    lay = nominal_model(lift7, load_cell(robot=lift7)).layout
    assert lay.n_free == 29 and lay.names[lay.joint_angle(1)] == "off1"
    assert not lay.is_angle[lay.joint_angle(1)] and lay.is_angle[lay.joint_angle(2)]
    # the UR5 twin: the reflector on joint 6's axis leaves 25 of 51 (as the YAML's 25 of 33)
    assert nominal_model(ur5_urdf, load_cell(robot=ur5_urdf)).layout.n_free == 25
    assert "off6" in ur5_urdf.gauge  # joint 6 cannot move a reflector on its axis


@pytest.mark.parametrize("name", ["lift7", UR5_URDF, "models/robots/humanoid18.urdf"])
def test_numpy_kinematics_agree_with_the_parsed_plant(name):
    """Every link frame of the numpy kinematics (a tree's too: the two-arm twin) is Drake's."""
    robot = load_robot(name)
    scene = build_scene(robot)
    q = _poses(robot, 8, 1)
    f = forward_kinematics(robot, q)
    for k in range(len(q)):
        scene.set_q(q[k])
        for i in range(robot.n_joints + 1):
            X = scene.X_WB(i)
            assert_allclose(X.translation() / MM, f.o[k, i], atol=1e-9)
            assert_allclose(X.rotation().matrix(), f.R[k, i], atol=1e-12)


def test_ur5_urdf_twin_has_the_yaml_kinematics_and_gravity(ur5_urdf):
    ur5 = load_robot("ur5")
    q = _poses(ur5, 20, 2)
    fy, fu = forward_kinematics(ur5, q), forward_kinematics(ur5_urdf, q)
    assert_allclose(fu.o[:, 6], fy.o[:, 6], atol=1e-9)
    assert_allclose(fu.R[:, 6], fy.R[:, 6], atol=1e-12)
    assert_allclose(gravity_torques(ur5_urdf, q), gravity_torques(ur5, q), atol=1e-9)


def test_twin_kpi_covariance_agrees(ur5_urdf):
    """Both parameterisations are complete: the KPI covariance of a design is the same."""
    ur5 = load_robot("ur5")
    q = _poses(ur5, 30, 3)
    cy = make_problem(ur5, sigma_mm=0.02).criteria(q)["kpi_avg_var_mm2"]
    cu = make_problem(ur5_urdf, sigma_mm=0.02).criteria(q)["kpi_avg_var_mm2"]
    assert cu == pytest.approx(cy, rel=1e-6)


@pytest.mark.parametrize("name", ["lift7", UR5_URDF])
def test_point_jacobian_columns_match_finite_differences(name):
    robot = load_robot(name)
    model = _perturbed(robot, 4)
    q = _poses(robot, 3, 5)
    _, H = measurement_jacobian(model, q)
    lay = model.layout
    h = 1e-6
    for i in range(lay.size):
        pp, pm = model.p.copy(), model.p.copy()
        pp[i] += h
        pm[i] -= h
        fd = (measure(model.with_params(pp), q) - measure(model.with_params(pm), q)) / (2 * h)
        assert_allclose(H[:, :, i], fd, atol=2e-6 * max(1.0, np.abs(fd).max()), err_msg=lay.names[i])
    # the joint offset's column is the derivative with respect to the joint variable
    for j in (1, 2):
        dq = np.zeros_like(q)
        dq[:, j - 1] = h
        fd = (measure(model, q + dq) - measure(model, q - dq)) / (2 * h)
        assert_allclose(H[:, :, lay.joint_angle(j)], fd, atol=1e-5)


def test_dJ_dq_and_point_velocity_match_finite_differences(lift7):
    model = _perturbed(lift7, 6)
    q = _poses(lift7, 2, 7)
    p_FQ = model.p_FQ
    fr = model.frames(q)
    _, J, dJ = point_jacobian(fr, p_FQ, with_dq=True)
    h = 1e-6

    def jac(qq):
        return np.stack([point_jacobian(model.frames(qq[k : k + 1]), p_FQ)[1][0] for k in range(len(qq))])

    fd = central_fd(jac, q, h)  # (n, 3, g+3, n, nj)
    for k in range(len(q)):
        assert_allclose(dJ[k], np.moveaxis(fd[k, :, :, k, :], -1, 0), atol=1e-5)
    # points on links 3 and 7 (moved by the lift and the revolute joints before them)
    pts = np.stack([fr.o[:, 3] + fr.R[:, 3] @ [10.0, 20.0, 30.0], fr.o[:, 7]], axis=1)
    v = point_velocity_jacobian(fr, pts, np.array([3, 7]))

    def points(qq):
        f = model.frames(qq)
        return np.stack([f.o[:, 3] + f.R[:, 3] @ [10.0, 20.0, 30.0], f.o[:, 7]], axis=1)

    fdp = central_fd(points, q, h)
    for k in range(len(q)):
        assert_allclose(v[k], np.moveaxis(fdp[k, :, :, k, :], -1, -2), atol=1e-5)


def test_clearance_and_incidence_gradients_with_a_prismatic_joint(lift7):
    cell = load_cell(robot=lift7)
    cm = ClearanceModel(lift7, cell)
    q = _poses(lift7, 2, 8)
    _, jac = cm.evaluate(q)
    fd = central_fd(lambda qq: cm.values(qq), q, 1e-6)
    for k in range(len(q)):
        assert_allclose(jac[k], fd[k, :, k, :], atol=1e-4)
    prob = make_problem(lift7, sigma_mm=0.02)
    _, ji = incidence_rows(prob, q)
    fdi = central_fd(lambda qq: incidence_rows(prob, qq)[0], q, 1e-6)
    for k in range(len(q)):
        assert_allclose(ji[k], fdi[k, k], atol=1e-7)


def test_gravity_with_a_prismatic_joint(lift7):
    q = _poses(lift7, 2, 9)
    g = gravity_model(lift7)
    tau, dtau = g.link_torques(q, with_dq=True)
    fd = central_fd(lambda qq: g.link_torques(qq), q, 1e-6)
    for k in range(len(q)):
        assert_allclose(dtau[k], fd[k, :, k, :], atol=1e-4)
    total = float(np.sum(lift7.masses[1:]))  # every link the lift carries [kg]
    assert tau[0, 0] == pytest.approx(-9.81 * total, rel=1e-9)  # a force [N]
    pay, dpay = g.payload_torques(q, 5.0, [0.0, 0.0, 100.0], with_dq=True)
    fdp = central_fd(lambda qq: g.payload_torques(qq, 5.0, [0.0, 0.0, 100.0]), q, 1e-6)
    for k in range(len(q)):
        assert_allclose(dpay[k], fdp[k, :, k, :], atol=1e-6)
    assert pay[0, 0] == pytest.approx(-9.81 * 5.0)


def test_gauge_choice_holds_only_redundant_parameters(lift7):
    """Holding the gauge loses nothing: the free columns have the rank of all columns."""
    model = nominal_model(lift7, load_cell(robot=lift7))
    q = _poses(lift7, 60, 10)
    _, H = measurement_jacobian(model, q)
    F = H.reshape(-1, H.shape[2])
    F = F / np.maximum(np.linalg.norm(F, axis=0), 1e-300)
    free = F[:, model.layout.free]
    s = np.linalg.svd(free, compute_uv=False)
    assert s[-1] / s[0] > 1e-6  # the free set is determined
    live = np.linalg.norm(H.reshape(-1, H.shape[2]), axis=0) > 1e-9
    assert np.linalg.matrix_rank(F[:, live], tol=1e-8) == model.layout.n_free
    bigger = dataclasses.replace(lift7, gauge=tuple(n for n in lift7.gauge if n != "py3"))
    free = F[:, nominal_model(bigger, load_cell(robot=bigger)).layout.free]
    s = np.linalg.svd(free, compute_uv=False)
    assert s[-1] / s[0] < 1e-10  # py3 trades against the others: not determined


def test_design_gradient_of_F1_with_an_extension(lift7):
    """dF1/dq (the design's gradient) with a prismatic joint and an elasticity column."""
    prob = make_problem(lift7, sigma_mm=0.02, extend=["joint_elasticity:3", "joint_scale:1"])
    q = _poses(lift7, 2, 11)
    F1, dF = prob.F1(q, with_dq=True)  # (3n, k), (n, nj, 3, k)
    fd = central_fd(lambda qq: prob.F1(qq).reshape(len(qq), 3, -1), q, 1e-6)  # (n, 3, k, n, nj)
    for k in range(len(q)):
        ref = np.moveaxis(fd[k, :, :, k, :], -1, 0)
        assert_allclose(dF[k], ref, atol=1e-6 * np.abs(ref).max())


@pytest.mark.parametrize("joint", [1, 3, 7])
def test_gravity_basis_regressor_with_a_prismatic_joint(lift7, joint):
    """The mass-moment regressor of the diagnosis' gravity basis reproduces Drake's torques (joint 1
    of lift7 is the lift: a force [N]) and its joint derivative matches finite differences."""
    q = _poses(lift7, 3, 12)
    Y, dY = gb.link_regressor(lift7, q, joint, with_dq=True)
    tau = gravity_torques(lift7, q)[:, joint - 1]
    assert_allclose(Y @ gb.link_moments(lift7, joint), tau, atol=1e-9 * max(1.0, np.abs(tau).max()))
    fd = np.einsum("npnj->njp", central_fd(lambda x: gb.link_regressor(lift7, x, joint), q, 1e-6))
    assert_allclose(dY, fd, atol=1e-6 * max(1.0, np.abs(fd).max()))


def test_a_rounded_right_angle_keeps_the_gauge(tmp_path):
    """A URDF as published writes pi/2 as ``1.571`` (2e-4 rad off): the automatic gauge holds the same
    parameters as with the exact angle, and all the rest stay identifiable."""
    src = MODELS_DIR / "robots"
    text = (src / "lift7.urdf").read_text()
    assert text.count("1.5707963267948966") >= 4
    (tmp_path / "lift7r.urdf").write_text(text.replace("1.5707963267948966", "1.571"))
    side = (src / "lift7.kpioed.yaml").read_text().replace("name: lift7", "name: lift7r")
    (tmp_path / "lift7r.kpioed.yaml").write_text(side)
    exact, rounded = load_robot("lift7"), load_robot(str(tmp_path / "lift7r.urdf"))
    assert rounded.gauge == exact.gauge
    rep = check_identifiability(rounded, load_cell(robot=rounded), seed=3)
    assert rep.identifiable and rep.rank == rep.n_candidates == 29


@pytest.mark.parametrize("name", ["lift7", "models/robots/humanoid18.urdf", "kr16"])
def test_link_frames_are_those_of_the_forward_kinematics_bit_for_bit(name):
    """The random pools' feasibility check uses the link frames alone: the same numbers."""
    robot = load_robot(name)
    q = _poses(robot, 300, 11)
    full, links = forward_kinematics(robot, q), link_frames(robot, q)
    np.testing.assert_array_equal(links.R, full.R)
    np.testing.assert_array_equal(links.o, full.o)
    model = nominal_model(robot, load_cell(robot=robot))
    np.testing.assert_array_equal(
        incidence_cosines(model, q, frames=links), incidence_cosines(model, q, frames=full)
    )
    if robot.chain is not None:  # no elements: these frames serve no Jacobian
        assert links.elem_u.shape[1] == 0 and links.joint_axes.shape[1] == 0


@pytest.mark.parametrize(("name", "skipped"), [("models/robots/humanoid18.urdf", 7), ("lift7", 0)])
def test_frames_on_a_path_are_those_of_all_links_bit_for_bit(name, skipped):
    """The pools compute a target's incidence from the links on its path alone: the same numbers,
    for all poses or a subset of them, and NaN off the path (the twin's other arm: 7 joints)."""
    robot = load_robot(name)
    q = _poses(robot, 300, 12)
    R, o = chain_links(robot.chain, q, robot.geometry)
    for link in robot.target_frames:
        on = np.flatnonzero(robot.chain.paths[link]) + 1
        off = np.setdiff1d(np.arange(1, robot.n_joints + 1), on)
        assert off.size == skipped
        for rows in (slice(None), slice(5, None, 7)):
            R_path, o_path = chain_links(robot.chain, q[rows], robot.geometry, path_to=int(link))
            np.testing.assert_array_equal(R_path[:, on], R[rows][:, on])
            np.testing.assert_array_equal(o_path[:, on], o[rows][:, on])
            np.testing.assert_array_equal(R_path[:, 0], R[rows][:, 0])
            assert np.isnan(R_path[:, off]).all() and np.isnan(o_path[:, off]).all()


def _all_frames_design(problem, n, seed, batch=4096):
    """The heuristic the earlier way: every link frame, every target's incidence of every draw."""
    robot = problem.robot
    rng = np.random.default_rng(seed)
    cm = ClearanceModel(robot, problem.cell)
    kept, n_kept = [], 0
    while n_kept < n:
        q = commandable_projection(robot, rng.uniform(robot.lower, robot.upper, size=(batch, robot.n_joints)))
        cos = incidence_cosines(problem.model, q, frames=link_frames(robot, q))
        ok = np.all(cos >= math.cos(problem.cell.max_incidence), axis=1)
        ok &= np.all((q >= robot.lower) & (q <= robot.upper), axis=1)
        ok[ok] = np.all(cm.values(q[ok]) >= 0.0, axis=1)
        kept.append(q[ok])
        n_kept += int(ok.sum())
    return np.concatenate(kept)[:n]


@pytest.mark.parametrize(
    ("name", "n"),
    [("models/robots/humanoid18.urdf", 300), ("kr16", 300), ("models/robots/column8.urdf", 200)],
)
def test_heuristic_keeps_the_poses_of_all_frames_and_all_targets(name, n):
    """Checked target by target on the links of each target's path (the twin: two hands, a coupled
    torso; column8: a mimic joint; kr16: DH), the heuristic keeps the same poses, bit for bit."""
    robot = load_robot(name)
    problem = make_problem(robot, q_work=np.zeros(robot.n_joints) if robot.q_work is None else None)
    q = heuristic_design(problem, n=n, seed=5, collision=True, margin_mm=0.0, max_draws=10**7)
    np.testing.assert_array_equal(q, _all_frames_design(problem, n, 5))
