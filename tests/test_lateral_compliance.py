"""Lateral joint compliance (``lateral_compliance:j``): a joint's bearing yields about the axes across
its axis under the gravity moment of what it carries. Its rotation is perpendicular to the joint
axis and droops the arm; the rotation's and the measurement columns' derivatives against central
finite differences; the text syntax; simulated kr16 data fitted to the noise with c recovered
within 3 sigma; the calibrated model file predicts fresh poses with it."""

import numpy as np
import pytest

from kpioed_drake import effects as fx
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml
from kpioed_drake.calibration.validate import validate
from kpioed_drake.effects import compliance as cp
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation import SimulationOptions, simulate
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model


@pytest.fixture(scope="module")
def q(kr16):
    return np.random.default_rng(11).uniform(kr16.lower, kr16.upper, size=(5, 6))


@pytest.mark.parametrize("joint", [1, 2, 3, 5])
def test_rotation_is_across_the_axis_and_droops_the_arm(kr16, nominal, joint):
    q = np.array([[0.0, -np.pi / 2, np.pi / 2, 0.0, 0.3, 0.0], [0.5, -1.2, 1.0, 0.4, -0.6, 0.2]])
    rot = cp.rotation(kr16, cp.LATERAL, joint, q, p_FP=nominal.p_FQ)
    fr = forward_kinematics(kr16, q)
    a = fr.joint_axes[:, joint - 1]
    np.testing.assert_allclose(np.einsum("na,na->n", rot.m, a), 0.0, atol=1e-12 * np.abs(rot.m).max())
    np.testing.assert_allclose(rot.pivot, fr.joint_points[:, joint - 1], atol=1e-12)
    # a positive c lowers the centre of mass of what the joint carries (it yields to gravity)
    links = np.arange(joint, 7)
    p_l = fr.o[:, links] + np.einsum("nlab,lb->nla", fr.R[:, links], kr16.coms[links])
    drop = np.einsum(
        "l,nl->n", kr16.masses[links], np.cross(rot.m[:, None, :], p_l - rot.pivot[:, None])[..., 2]
    )
    assert np.all(drop < 0)


@pytest.mark.parametrize("joint", [2, 3, 5])
@pytest.mark.parametrize("payload", [None, 8.0])
def test_rotation_derivatives_match_finite_differences(kr16, q, joint, payload):
    p_FP = np.array([12.0, -30.0, 150.0])
    rot = cp.rotation(kr16, cp.LATERAL, joint, q, p_FP=p_FP, payload_kg=payload, with_dq=True)

    def fd(attr):
        out = np.zeros((len(q), 6, 3))
        for j in range(6):
            dq = np.eye(6)[j] * 1e-6
            plus = getattr(cp.rotation(kr16, cp.LATERAL, joint, q + dq, p_FP=p_FP, payload_kg=payload), attr)
            minus = getattr(cp.rotation(kr16, cp.LATERAL, joint, q - dq, p_FP=p_FP, payload_kg=payload), attr)
            out[:, j] = (plus - minus) / 2e-6
        return out

    np.testing.assert_allclose(rot.dm, fd("m"), atol=1e-6 * np.abs(rot.dm).max())
    np.testing.assert_allclose(rot.dpivot, fd("pivot"), atol=1e-5)


def test_measurement_columns_and_their_joint_derivative(nominal, q):
    effs = [
        fx.parse_effect("lateral_compliance:2=2e-6", model=nominal),
        fx.parse_effect("joint_elasticity:3=1e-6"),
    ]
    h, _, E = fx.augmented_jacobian(nominal, q, effs, payload_kg=5.0)
    np.testing.assert_allclose(h, fx.augmented_response(nominal, q, effs, payload_kg=5.0), atol=1e-9)
    up = [effs[0].with_values([3e-6]), effs[1]]
    dn = [effs[0].with_values([1e-6]), effs[1]]
    fd = (
        fx.augmented_response(nominal, q, up, payload_kg=5.0)
        - fx.augmented_response(nominal, q, dn, payload_kg=5.0)
    ) / 2e-6
    np.testing.assert_allclose(E[:, :, 0], fd, rtol=1e-6, atol=1e-9 * np.abs(E[:, :, 0]).max())
    ext = ["lateral_compliance:2", "lateral_compliance:5"]
    E0, dE = fx.extension_columns(nominal, q, ext, payload_kg=5.0, with_dq=True)
    assert np.all(np.abs(E0).max(axis=(0, 1)) > 0)
    scale = np.abs(E0).max(axis=(0, 1))
    for j in range(6):
        dq = np.eye(6)[j] * 1e-6
        fdq = (
            fx.extension_columns(nominal, q + dq, ext, payload_kg=5.0)
            - fx.extension_columns(nominal, q - dq, ext, payload_kg=5.0)
        ) / 2e-6
        np.testing.assert_allclose(dE[:, j] / scale, fdq / scale, atol=1e-6, err_msg=str(j))


@pytest.mark.parametrize(
    "text, fragment",
    [("lateral_compliance", "lateral_compliance:JOINT"), ("lateral_compliance:9", "joint must be"),
     ("lateral_compliance:2=1,2", "2")],
)  # fmt: skip
def test_parse_errors_name_the_text(nominal, text, fragment):
    with pytest.raises(InputError, match=fragment):
        fx.parse_effect(text, model=nominal)


def test_a_prismatic_joint_has_no_lateral_compliance():
    lift7 = load_robot("lift7")
    with pytest.raises(InputError, match="prismatic"):
        fx.parse_effect("lateral_compliance:1", model=nominal_model(lift7, load_cell(robot=lift7)))


def _data(kr16, n, seed, effects):
    """Fitted and fresh poses of one simulated robot (the same truth): n and 40."""
    q = np.random.default_rng(seed).uniform(kr16.lower, kr16.upper, size=(n + 40, 6))
    table, truth = simulate(kr16, q, SimulationOptions(sigma_mm=0.02, seed=seed, effects=effects))
    fit, fresh = table.iloc[:n].reset_index(drop=True), table.iloc[n:].reset_index(drop=True)
    return (
        Measurements.from_table(fit, kr16, source="fitted"),
        Measurements.from_table(fresh, kr16, source="fresh"),
        truth,
    )


def test_calibrate_extend_recovers_it_and_the_model_file_predicts_fresh_poses(kr16, tmp_path):
    effects = ("lateral_compliance:2=4e-5",)
    data, fresh, truth = _data(kr16, 80, 3, effects)
    true_c = truth["effects"][0].values[0]
    p_FQ = nominal_model(kr16, load_cell(robot=kr16)).p_FQ
    rot = cp.rotation(kr16, cp.LATERAL, 2, data.q, p_FP=p_FQ)
    size = true_c * np.max(
        np.linalg.norm(rot.displacement(flange_point(forward_kinematics(kr16, data.q), p_FQ)), axis=1)
    )
    assert 0.2 < size < 2.0  # the tool moves by a realistic amount [mm]
    geo = calibrate(kr16, data, CalibrationOptions(sigma_mm=0.02))
    ext = calibrate(kr16, data, CalibrationOptions(sigma_mm=0.02, effects=("lateral_compliance:2",)))
    assert geo.chi2_per_dof > 3.0 and ext.chi2_per_dof < 1.5
    rec = ext.to_dict()["effects"][0]
    assert rec["unit"] == "rad/(N m)"
    assert abs(rec["value"] - true_c) < 3 * rec["std"][0]
    path = tmp_path / "kr16_lateral.yaml"
    path.write_text(calibrated_robot_yaml(ext))
    fitted = load_robot(str(path))
    v_ext = validate(fitted, fresh).to_dict()["mean_error_mm"]
    v_geo = validate(load_robot(str(_geometric(geo, tmp_path))), fresh).to_dict()["mean_error_mm"]
    assert v_ext < 0.5 * v_geo


def _geometric(report, tmp_path):
    path = tmp_path / "kr16_geometric.yaml"
    path.write_text(calibrated_robot_yaml(report))
    return path
