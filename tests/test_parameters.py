"""The parameter layout, the one measurement type, the covariance routine and the shared sampler."""

import dataclasses

import numpy as np
import pytest
import scipy.stats
from numpy.testing import assert_allclose
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RotationMatrix
from scipy.spatial.transform import Rotation

from kpioed_drake import simulation
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import estimator
from kpioed_drake.robot.models import load_cell
from kpioed_drake.robot.parameters import FIXED_NAMES, n_parameters, parameter_layout
from kpioed_drake.tracker.data import Measurements, per_pose
from kpioed_drake.tracker.measurement import measurement_jacobian


def test_six_joint_layout_keeps_the_33_vector_order(kr16):
    lay = parameter_layout(kr16)
    assert lay.size == n_parameters() == 33 and lay.n_free == 27
    names = lay.names
    assert list(names[lay.joints]) == kr16.param_names()
    assert names[lay.tracker_position] == ("tracker_x", "tracker_y", "tracker_z")
    assert names[lay.tracker_rotation] == ("tracker_rx", "tracker_ry", "tracker_rz")
    assert names[lay.target(0)] == ("reflector_x", "reflector_y", "reflector_z")
    assert [names[i] for i in range(lay.size)[lay.joint_angles]] == [f"theta{j}" for j in range(1, 7)]
    assert all(names[lay.joint_angle(j)] == f"theta{j}" for j in range(1, 7))
    assert names[lay.joint_row(3)][0] == "theta3" and len(names[lay.joint_row(3)]) == 4
    assert set(FIXED_NAMES).isdisjoint(lay.free_names)
    free = lay.free_names
    assert [free[i] for i in lay.free_tracker_position] == ["tracker_x", "tracker_y", "tracker_z"]
    assert [free[i] for i in lay.free_tracker_rotation] == ["tracker_rx", "tracker_ry", "tracker_rz"]
    assert [free[i] for i in lay.free_target(0)] == ["reflector_x", "reflector_y", "reflector_z"]
    assert not any(names[i].startswith("tracker") for i in lay.free_robot_side)
    assert lay.free_robot_side.size == 21
    # angles are scaled by the reach, lengths not
    sc = lay.scale(1000.0)
    assert all((sc[k] == 1000.0) == lay.is_angle[i] for k, i in enumerate(lay.free))
    ext = lay.with_effects(3)
    assert ext.n_unknowns == 30 and range(30)[ext.effects] == range(27, 30)


def test_layout_follows_joint_and_target_counts(kr16):
    seven = dataclasses.replace(kr16, conventions=tuple(kr16.conventions) + ("dh",))
    lay = parameter_layout(seven, n_targets=2)
    assert lay.n_joints == 7 and lay.size == n_parameters(7, n_targets=2) == 7 * 4 + 6 + 6
    assert lay.names[lay.joint_angle(7)] == "theta7"
    assert lay.names[lay.target(1)] == ("reflector_x2", "reflector_y2", "reflector_z2")
    assert lay.targets.stop == lay.size
    with pytest.raises(ValueError, match="not in the model"):
        parameter_layout(kr16, fixed=("theta9",))


def test_tracker_model_reads_its_parts_through_the_layout(kr16, nominal):
    cell = load_cell(robot=kr16)
    lay = nominal.layout
    assert_allclose(nominal.geometry, kr16.geometry)
    assert_allclose(nominal.p_WT, cell.p_WT)
    assert_allclose(nominal.p_FQ, cell.p_FQ)
    p = nominal.p.copy()
    p[lay.tracker_rotation] = [0.01, -0.02, 0.03]
    m = nominal.with_params(p)
    rebased = m.rebased()
    assert np.all(rebased.p[lay.tracker_rotation] == 0.0)
    assert_allclose(rebased.R_WT, m.R_WT, atol=1e-15)
    q = np.deg2rad([[10.0, -80.0, 90.0, 20.0, 30.0, 40.0]])
    h, H = measurement_jacobian(m, q)
    assert_allclose(H[0][:, lay.tracker_position], -m.R_WT.T, atol=1e-15)
    assert H.shape == (1, 3, lay.size)


def test_measurements_from_arrays_validates():
    q, eta = np.zeros((4, 6)), np.zeros((4, 3))
    d = Measurements.from_arrays(q, eta, time_s=np.arange(4.0), source="x")
    assert d.n == 4 and list(d.rows) == [2, 3, 4, 5]
    sub = d.subset(np.array([1, 3]))
    assert list(sub.rows) == [3, 5] and list(sub.time_s) == [1.0, 3.0]
    with pytest.raises(InputError, match="x: expected q"):  # any joint count (the robot checks it)
        Measurements.from_arrays(q[:, :0], eta, source="x")
    with pytest.raises(InputError, match="column time_s must have one value per pose"):
        Measurements.from_arrays(q, eta, time_s=np.arange(3.0), source="x")
    with pytest.raises(InputError, match="column eta has a non-finite value"):
        Measurements.from_arrays(q, np.full((4, 3), np.nan))
    with pytest.raises(InputError, match="missing column 'q3_deg'"):
        Measurements.from_table(d.to_frame().drop(columns=["q3_deg"]))
    assert_allclose(per_pose(2.0, 3, "t"), [2.0, 2.0, 2.0])
    with pytest.raises(InputError, match="t: expected one finite number or 3"):
        per_pose([1.0, np.inf, 2.0], 3, "t")


def test_covariance_is_the_inverse_information_or_raises():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((40, 5)) * np.array([1e-3, 1.0, 1e3, 1.0, 10.0])
    assert_allclose(estimator.covariance(J), np.linalg.inv(J.T @ J), rtol=1e-10)
    J[:, 4] = 0.0  # a parameter the data says nothing about
    with pytest.raises(np.linalg.LinAlgError):
        estimator.covariance(J)
    C = estimator.covariance(J, singular_ok=True)
    assert_allclose(C, np.linalg.pinv(J.T @ J), rtol=1e-8, atol=1e-12)


class Normals:
    """A stand-in generator whose ``standard_normal`` returns the given numbers."""

    def __init__(self, values):
        self.values = np.asarray(values, dtype=float)

    def standard_normal(self, size):
        assert size == self.values.size
        return self.values.copy()


def test_one_rotation_sampler_for_simulation_and_harness(nominal):
    """Drake's rotation of the same unit quaternion; a known rotation from both component orders;
    the harness order is scipy's ``Rotation.random`` draw for draw; uniform on SO(3)."""
    g = np.random.default_rng(5).standard_normal(4)  # read as (w, x, y, z)
    drake = RotationMatrix(Quaternion(g / np.linalg.norm(g))).matrix()
    assert_allclose(simulation.random_rotation(np.random.default_rng(5)), drake, atol=1e-15)
    # 2.5 (cos 20 deg, sin 20 deg u): 40 degrees about u = (2, -1, 2) / 3, unnormalised on purpose
    u, c, s = np.array([2.0, -1.0, 2.0]) / 3.0, np.cos(np.radians(40.0)), np.sin(np.radians(40.0))
    K = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    rodrigues = np.eye(3) + s * K + (1 - c) * K @ K
    half = 2.5 * np.array([np.cos(np.radians(20.0)), *(np.sin(np.radians(20.0)) * u)])
    assert_allclose(simulation.random_rotation(Normals(half)), rodrigues, atol=1e-15)
    last = simulation.random_rotation(Normals(np.roll(half, -1)), scalar_first=False)  # (x, y, z, w)
    assert_allclose(last, rodrigues, atol=1e-15)
    R = simulation.random_rotation(np.random.default_rng(6), scalar_first=False)
    assert_allclose(R, Rotation.random(random_state=np.random.default_rng(6)).as_matrix(), atol=1e-15)
    # uniform on SO(3): each entry is U(-1, 1) (mean 0, mean square 1/3), the trace 1 + 2 cos(angle)
    # has mean 0; rotations: orthonormal, determinant +1
    rng = np.random.default_rng(7)
    Rs = np.array([simulation.random_rotation(rng) for _ in range(4000)])
    assert_allclose(np.einsum("nji,njk->nik", Rs, Rs), np.broadcast_to(np.eye(3), Rs.shape), atol=1e-14)
    assert_allclose(np.linalg.det(Rs), 1.0, atol=1e-14)
    se = np.sqrt(1.0 / 3.0 / 4000)  # of an entry's mean
    assert np.all(np.abs(Rs.mean(axis=0)) < 4 * se)
    assert np.all(np.abs((Rs**2).mean(axis=0) - 1.0 / 3.0) < 4 * np.sqrt(4.0 / 45.0 / 4000))
    assert abs(np.trace(Rs, axis1=1, axis2=2).mean()) < 4 * np.sqrt(1.0 / 4000)  # Var(trace) = 1
    assert scipy.stats.kstest(Rs[:, 2, 0], scipy.stats.uniform(-1.0, 2.0).cdf).pvalue > 1e-3
    # the truth keeps the gauge parameters nominal and moves the tracker within the spread
    truth = simulation.true_model(nominal, np.random.default_rng(7), tracker_spread_mm=200.0)
    lay = nominal.layout
    fixed = [lay.names.index(n) for n in FIXED_NAMES]
    assert_allclose(truth.p[fixed], nominal.p[fixed], rtol=0, atol=0)
    assert np.all(np.abs(truth.p_WT - nominal.p_WT) <= 200.0)
    assert np.any(truth.p[lay.free_robot_side] != nominal.p[lay.free_robot_side])
