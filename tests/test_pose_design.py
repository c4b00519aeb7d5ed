"""The KPI design with a 6-DoF probe's pose measurements (issue 44): F1's 6 rows per pose and their
joint derivatives, the TCP's orientation KPI, the objective's gradient, the certificate with 6 rows
per pose, the predicted TCP orientation variance against simulated fits, and ``kpioed design
--measure pose``."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from kpioed_drake import api
from kpioed_drake.cli import build_parser
from kpioed_drake.design import format_summary, heuristic_design
from kpioed_drake.design.approximate import certcache
from kpioed_drake.design.approximate.certificate import certify, pool_certificate
from kpioed_drake.design.approximate.design import approximate_design
from kpioed_drake.design.exact.objective import DesignObjective
from kpioed_drake.design.options import DesignOptions
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import estimate
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import measure
from kpioed_drake.tracker.orientation import (
    orientation_jacobian,
    probe_orientation,
    rotation_log,
    tcp_angular_jacobian,
)

SIGMA_DEG = 0.005


def _pose_problem(name, **kw):
    return make_problem(name, sigma_mm=0.02, measure="pose", sigma_deg=SIGMA_DEG, **kw)


def _poses(problem, n, seed):
    return np.random.default_rng(seed).uniform(
        problem.robot.lower, problem.robot.upper, (n, problem.robot.n_joints)
    )


@pytest.mark.parametrize("name", ["kr16", "ur10"])
def test_pose_rows_and_their_joint_derivatives(name):
    """6 rows per pose: the position rows / sigma (the point problem's where the free sets agree),
    then the orientation residual's Jacobian at zero residual / sigma_rot; d F1 / d q against central
    differences."""
    pose, point = _pose_problem(name), make_problem(name, sigma_mm=0.02)
    q = _poses(pose, 5, 1)
    F, dF = pose.F1(q, with_dq=True)
    k = pose.n_params
    assert F.shape == (30, k) and dF.shape == (5, pose.robot.n_joints, 6, k) and pose.min_poses() == 5
    rows = F.reshape(5, 6, k)
    names = pose.param_names
    shared = [names.index(n) for n in point.param_names]
    assert_allclose(rows[:, :3, shared], point.F1(q).reshape(5, 3, -1), rtol=0, atol=1e-12)
    _, Hr = orientation_jacobian(pose.model, q, probe_orientation(pose.model, q))
    assert_allclose(rows[:, 3:], Hr[:, :, pose.free] / np.deg2rad(SIGMA_DEG), rtol=1e-12, atol=1e-6)
    h = 1e-6
    for j in range(pose.robot.n_joints):
        dq = np.zeros(pose.robot.n_joints)
        dq[j] = h
        fd = (pose.F1(q + dq) - pose.F1(q - dq)).reshape(5, 6, k) / (2 * h)
        assert_allclose(dF[:, j], fd, rtol=1e-6, atol=1e-6 * np.abs(dF).max())
    assert np.abs(dF[:, :, 3:]).max() > 1.0  # the orientation rows move with the joints


@pytest.mark.parametrize("name", ["kr16", "ur10"])
def test_tcp_angular_jacobian_matches_finite_differences(name):
    """The TCP frame (flange times the probe's rotation) turns in W by ``Js_rot dp``."""
    pb = _pose_problem(name)
    model = pb.model
    rng = np.random.default_rng(2)
    model = model.with_params(
        model.p + np.where(model.layout.is_angle, 0.01, 0.5) * rng.normal(size=model.p.size)
    )
    qw = pb.q_works[0]

    def R_tool(m):
        return m.R_WT @ probe_orientation(m, qw[None])[0]

    J = tcp_angular_jacobian(model, qw)
    h = 1e-6
    fd = np.empty_like(J)
    for c in range(model.p.size):
        dp = np.zeros(model.p.size)
        dp[c] = h
        Rp, Rm = R_tool(model.with_params(model.p + dp)), R_tool(model.with_params(model.p - dp))
        fd[:, c] = rotation_log((Rp @ Rm.T)[None])[0] / (2 * h)
    lay = model.layout
    fd[:, lay.tracker_rotation] = 0.0  # the tracker turns the measured frame, not the tool
    assert_allclose(J, fd, atol=1e-8)
    assert np.abs(J[:, lay.probe_rotation]).max() > 0.5 and not np.any(J[:, lay.tracker_position])


def test_orientation_kpi_is_the_weighted_sum_and_its_gradient_matches_finite_differences():
    L = 200.0
    pb = _pose_problem("kr16", kpi_orientation_mm=L)
    q = heuristic_design(pb, n=12, seed=4)
    pos, rot = pb.tcp_variances(q)
    value = pb.criteria(q)["kpi_avg_var_mm2"]
    assert_allclose(value, pos[0] + L**2 * rot[0] * np.deg2rad(1.0) ** 2, rtol=1e-10)
    assert pb.Js().shape == (6, pb.n_params)
    obj = DesignObjective(pb, "kpi")
    v, g = obj.value_and_grad(q)
    assert_allclose(v, value, rtol=1e-10)
    h = 1e-6
    fd = np.zeros_like(g)
    for i in (0, 5):
        for j in range(6):
            dq = np.zeros_like(q)
            dq[i, j] = h
            fd[i, j] = (obj.value(q + dq) - obj.value(q - dq)) / (2 * h)
    assert_allclose(g[[0, 5]], fd[[0, 5]], rtol=1e-5, atol=1e-6 * np.abs(g).max())


def test_point_problem_is_unchanged_and_pose_inputs_are_checked():
    a, b = make_problem("kr16"), make_problem("kr16", measure="point", kpi_orientation_mm=0.0)
    q = _poses(a, 10, 3)
    assert np.array_equal(a.F1(q), b.F1(q)) and np.array_equal(a.Js(), b.Js()) and a.min_poses() == 9
    for kw, field in (
        (dict(measure="probe"), "measure"),
        (dict(measure="pose", sigma_deg=0.0), "sigma_deg"),
        (dict(sigma_deg=0.01), "sigma_deg"),
        (dict(kpi_orientation_mm=-1.0), "kpi_orientation_mm"),
        (dict(measure="pose", extend=["joint_elasticity:2"]), "extensions"),
    ):
        with pytest.raises(InputError, match=field):
            make_problem("kr16", **kw)
    for kw, field in (
        (dict(measure="probe"), "measure"),
        (dict(measure="pose", sigma_deg=-0.01), "sigma_deg"),
        (dict(sigma_deg=0.01), "sigma_deg"),
        (dict(kpi_orientation_mm=float("nan")), "kpi_orientation_mm"),
    ):
        with pytest.raises(InputError, match=field):
            DesignOptions(**kw)


def test_pose_design_certificate_bounds_its_value(monkeypatch):
    """With 6 rows per pose (and the orientation in the KPI): the pool certificate's dual and
    equivalence bounds meet the pool optimum, and the certificate of 20-pose designs is below their
    tr(Cs)/3 (efficiency <= 1), on a small search."""
    pb = _pose_problem("kr16", kpi_orientation_mm=100.0)
    pool = heuristic_design(pb, n=200, seed=3, margin_mm=0.0)
    pc = pool_certificate(pb, pool)
    assert pc.dual <= pc.phi and pc.dual_gap < 1e-6 and abs(pc.equivalence_gap) < 1e-5
    approx = approximate_design(pb, seed=0, max_rounds=2, pool=200, starts=8, random_starts=4)
    assert approx.F.shape[1:] == (6, pb.n_params) and approx.Y.shape == (pb.n_params, 6)
    for seed in range(2):
        q = heuristic_design(pb, n=20, seed=seed)
        c = certify(pb, q, approx=approx, refinements=0)
        assert 0 < c["efficiency"] <= 1 and c["bound_mm2"] <= c["value_mm2"]
        assert c["value_mm2"] == pytest.approx(pb.criteria(q)["kpi_avg_var_mm2"], rel=1e-12)
    # the unit-noise search scaled back: the orientation rows scale with sigma_mm too
    unit = certcache.unit_noise(pb)
    assert_allclose(unit.F1(q) / pb.sigma, pb.F1(q), rtol=1e-12)


def test_predicted_tcp_orientation_variance_matches_simulated_fits():
    """Fits of simulated pose measurements (seeded): the TCP frame's orientation error at the
    working pose has the variance tr(C_rot)/3 the problem predicts (200 fits: within 20 %), and so
    does its position."""
    pb = _pose_problem("kr16")
    q = heuristic_design(pb, n=20, seed=5)
    pos_pred, rot_pred = pb.tcp_variances(q)
    truth = pb.model
    qw = pb.q_works[0]
    R_true = truth.R_WT @ probe_orientation(truth, qw[None])[0]
    eta0, R0 = measure(truth, q), probe_orientation(truth, q)
    rng = np.random.default_rng(7)
    s_rot = np.deg2rad(SIGMA_DEG)
    err_rot, err_pos = [], []
    point = make_problem("kr16", sigma_mm=0.02).model  # the estimator adds the probe itself
    for _ in range(200):
        eta = eta0 + rng.normal(0, 0.02, eta0.shape)
        R_TP = Rotation.from_rotvec(rng.normal(0, s_rot, (len(q), 3))).as_matrix() @ R0
        data = Measurements.from_arrays(q, eta, R_TP=R_TP, sigma_rot_rad=np.full((len(q), 3), s_rot))
        fit = estimate(point, data.q, data.eta, sigma=0.02, R_TP=data.R_TP, sigma_rot=data.sigma_rot_rad)
        m = fit.model
        R_est = m.R_WT @ probe_orientation(m, qw[None])[0]
        err_rot.append(rotation_log((R_est @ R_true.T)[None])[0])
        err_pos.append(
            measure(m, qw[None])[0] @ m.R_WT.T
            + m.p_WT
            - (measure(truth, qw[None])[0] @ truth.R_WT.T + truth.p_WT)
        )
    var_rot = np.mean(np.sum(np.square(err_rot), axis=1)) / 3 * np.rad2deg(1.0) ** 2
    var_pos = np.mean(np.sum(np.square(err_pos), axis=1)) / 3
    assert_allclose(var_rot, rot_pred[0], rtol=0.2)
    assert_allclose(var_pos, pos_pred[0], rtol=0.2)


def test_design_command_with_pose_measurements(capsys, tmp_path, quick_certificate, quick_start, monkeypatch):
    monkeypatch.setenv("KPIOED_CACHE", "off")
    res = api.design(
        "kr16", n=12, measure="pose", sigma_mm=0.02, kpi_orientation_mm=50.0, out=tmp_path / "d.csv"
    )
    tcp = res.tcp
    assert tcp["measure"] == "pose" and tcp["sigma_deg"] == pytest.approx(0.005)
    L2 = 50.0**2 * np.deg2rad(1.0) ** 2
    assert_allclose(
        res.kpi_avg_var_mm2, tcp["position_var_mm2"] + L2 * tcp["orientation_var_deg2"], rtol=1e-9
    )
    assert res.certificate["efficiency"] <= 1
    assert "orientation tr(C)/3" in format_summary(res) and "efficiency" in format_summary(res)
    with pytest.raises(InputError, match="discriminate"):
        api.design(
            "kr16", measure="pose", discriminate="joint_scale:2|gear_cyclic:2:1", out=tmp_path / "e.csv"
        )


def test_cli_passes_the_measurement_options(monkeypatch):
    """``kpioed design --measure pose --sigma-deg S --kpi-orientation-mm L`` reaches api.design with
    those settings (and without them, the point defaults are not passed as orientation settings)."""
    seen = []
    monkeypatch.setattr(api, "design", lambda robot, **kw: seen.append(kw) or _Stop())
    base = ["design", "--robot", "kr16", "--criterion", "kpi", "--out", "d.csv"]
    extra = ["--measure", "pose", "--sigma-deg", "0.01", "--kpi-orientation-mm", "50"]
    for argv in (base + extra, base):
        args = build_parser().parse_args(argv)
        with pytest.raises(_Stopped):
            args.func(args)
    assert (
        seen[0]["measure"] == "pose" and seen[0]["sigma_deg"] == 0.01 and seen[0]["kpi_orientation_mm"] == 50
    )
    assert (
        seen[1]["measure"] == "point" and seen[1]["sigma_deg"] is None and "kpi_orientation_mm" not in seen[1]
    )


class _Stopped(Exception):
    pass


class _Stop:
    """A stand-in result that stops the command once the API was called."""

    def __getattr__(self, name):
        raise _Stopped(name)
