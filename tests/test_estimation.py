"""Registration and Levenberg-Marquardt estimation (kpioed_drake.estimation.estimator)."""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from kpioed_drake.errors import InputError
from kpioed_drake.estimation import estimator, problem, residuals
from kpioed_drake.robot import models
from kpioed_drake.tracker import measurement


@pytest.fixture(scope="module")
def kr16():
    robot = models.load_robot("kr16")
    cell = models.load_cell(robot=robot)
    return robot, cell, measurement.nominal_model(robot, cell)


def random_poses(robot, n, rng):
    return rng.uniform(robot.lower, robot.upper, size=(n, 6))


def perturbed_truth(model, rng):
    """SPEC sizes on the 27 free parameters, an arbitrary tracker frame."""
    p = model.p.copy()
    free = model.layout.free
    size = np.where(model.layout.is_angle, np.deg2rad(0.05), 0.5)
    p[free] += size[free] * rng.standard_normal(free.size)
    p[model.layout.tracker_position] = model.p_WT + rng.uniform(-500, 500, 3)
    p[model.layout.tracker_rotation] = 0.0
    R = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    return dataclasses.replace(model, p=p, R_WT_ref=R)


# ----------------------------------------------------------------------------------------------
def test_registration_recovers_random_rigid_transform():
    rng = np.random.default_rng(11)
    for _ in range(20):
        R = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
        t = rng.uniform(-5000, 5000, 3)
        p_T = rng.uniform(-2000, 2000, (30, 3))
        p_W = p_T @ R.T + t
        R_est, t_est = estimator.register_tracker(p_W, p_T)
        assert_allclose(R_est, R, atol=1e-12)
        assert_allclose(t_est, t, atol=1e-8)


def test_registration_proper_rotation_for_planar_points_and_mirrored_data():
    rng = np.random.default_rng(12)
    # planar points: the SVD is free to return a reflection; the result must still be exact
    p_T = np.column_stack([rng.uniform(-1000, 1000, (10, 2)), np.zeros(10)])
    R = Rotation.random(random_state=5).as_matrix()
    t = np.array([100.0, -200.0, 300.0])
    R_est, t_est = estimator.register_tracker(p_T @ R.T + t, p_T)
    assert_allclose(R_est, R, atol=1e-12)
    assert_allclose(t_est, t, atol=1e-9)
    # mirrored (left-handed) data: the best proper rotation, never a reflection
    p_T = rng.uniform(-1000, 1000, (20, 3))
    p_W = (p_T * np.array([1.0, 1.0, -1.0])) @ R.T
    R_est, _ = estimator.register_tracker(p_W, p_T)
    assert_allclose(R_est.T @ R_est, np.eye(3), atol=1e-12)
    assert_allclose(np.linalg.det(R_est), 1.0, atol=1e-12)


def test_registration_rejects_bad_input():
    with pytest.raises(InputError, match="at least 3"):
        estimator.register_tracker(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="collinear"):
        estimator.register_tracker(line, line)


def test_noise_free_data_recovers_truth_exactly(kr16):
    robot, _, model = kr16
    rng = np.random.default_rng(3)
    q = random_poses(robot, 40, rng)
    truth = perturbed_truth(model, rng)
    res = estimator.estimate(model, q, measurement.measure(truth, q), sigma=0.02)
    assert res.converged
    joint_ref = np.r_[model.layout.free[:18], 30, 31, 32]  # joint and reflector parameters
    assert_allclose(res.model.p[joint_ref], truth.p[joint_ref], atol=1e-7)
    assert_allclose(res.model.R_WT, truth.R_WT, atol=1e-10)
    assert_allclose(res.model.p_WT, truth.p_WT, atol=1e-6)
    assert_allclose(res.residuals, 0.0, atol=1e-7)


def test_recovers_perturbed_parameters_within_reported_std(kr16):
    """SPEC sizes (0.5 mm, 0.05 deg), arbitrary tracker frame, sigma 0.02 mm."""
    robot, _, model = kr16
    rng = np.random.default_rng(4)
    q = random_poses(robot, 60, rng)
    sigma = 0.02
    for _ in range(3):
        truth = perturbed_truth(model, rng)
        eta = measurement.measure(truth, q) + rng.normal(0.0, sigma, (60, 3))
        res = estimator.estimate(model, q, eta, sigma=sigma)
        assert res.converged
        free = model.layout.free
        z = (res.model.p[free] - truth.p[free]) / res.std
        # the tracker's small rotations refer to the estimated frame: compare the rotation instead
        rot = Rotation.from_matrix(res.model.R_WT.T @ truth.R_WT).as_rotvec()
        r = res.model.layout.free_tracker_rotation
        z[r] = rot / res.std[r]
        # 27 standard normal deviates: all within 4 (probability ~0.998)
        assert np.max(np.abs(z)) < 4.0, z
        assert 0.5 < res.chi2_per_dof < 1.6
        # the KPI too
        s_est, Js = measurement.kpi_jacobian(res.model, robot.q_work)
        s_true = measurement.kpi_jacobian(truth, robot.q_work)[0]
        Cs = Js[:, free] @ res.Cp @ Js[:, free].T
        d = s_est - s_true
        assert d @ np.linalg.solve(Cs, d) < chi2.ppf(0.999, 3)


def test_too_few_poses(kr16):
    robot, _, model = kr16
    q = random_poses(robot, 8, np.random.default_rng(0))
    with pytest.raises(InputError, match="at least 9 poses"):
        estimator.estimate(model, q, measurement.measure(model, q))


def test_mask_excludes_poses(kr16):
    robot, _, model = kr16
    rng = np.random.default_rng(5)
    q = random_poses(robot, 30, rng)
    eta = measurement.measure(model, q) + rng.normal(0, 0.02, (30, 3))
    eta_bad = eta.copy()
    eta_bad[7] += 5.0
    mask = np.ones(30, bool)
    mask[7] = False
    a = estimator.estimate(model, q[mask], eta[mask])
    b = estimator.estimate(model, q, eta_bad, mask=mask)
    assert_allclose(b.model.p, a.model.p, atol=1e-8)
    assert_allclose(b.cost, a.cost, rtol=1e-8)
    nr = residuals.normalized_residuals(b)
    assert nr[7] > 1e4  # 5 mm against 0.02 mm noise
    assert np.all(nr[mask] < chi2.ppf(1 - 1e-4, 3))


def test_monte_carlo_kpi_covariance_matches_Cs(kr16):
    """Sample covariance of the estimated KPI over 300 noise draws against Cs = Js Cp Js^T.

    With N draws, (N-1) S ~ Wishart(Cs, N-1): E tr S = tr Cs, Var tr S = 2 tr(Cs^2)/(N-1).
    The trace must lie within 4 of those standard deviations; the mean error within 3 standard
    errors per coordinate (and its Mahalanobis norm below the chi^2(3) 99.9 % quantile).
    """
    robot, _, _ = kr16
    sigma, N = 1.0, 300
    prob = problem.make_problem(robot, sigma_mm=sigma)
    model = prob.model
    rng = np.random.default_rng(2024)
    q = random_poses(robot, 60, rng)
    _, Cs = prob.covariances(q)
    s_true = measurement.kpi_jacobian(model, robot.q_work)[0]
    h = measurement.measure(model, q)
    S = np.empty((N, 3))
    for k in range(N):
        eta = h + rng.normal(0.0, sigma, h.shape)
        res = estimator.estimate(model, q, eta, sigma=sigma)
        assert res.converged, res.message
        S[k] = measurement.kpi_jacobian(res.model, robot.q_work)[0]
    C_sample = np.cov(S.T)
    sd_trace = np.sqrt(2.0 * np.trace(Cs @ Cs) / (N - 1))
    ratio = np.trace(C_sample) / np.trace(Cs)
    print(f"trace ratio {ratio:.4f} (1 sd = {sd_trace / np.trace(Cs):.4f})")
    assert abs(np.trace(C_sample) - np.trace(Cs)) < 4.0 * sd_trace
    d = S.mean(axis=0) - s_true
    assert np.all(np.abs(d) < 3.0 * np.sqrt(np.diag(Cs) / N))
    assert N * d @ np.linalg.solve(Cs, d) < chi2.ppf(0.999, 3)
    # whitened: mean squared Mahalanobis distance is 3 with standard deviation sqrt(6/N)
    L = np.linalg.cholesky(Cs)
    z = np.linalg.solve(L, (S - s_true).T)
    assert abs(np.mean(np.sum(z**2, axis=0)) - 3.0) < 4.0 * np.sqrt(6.0 / N)
