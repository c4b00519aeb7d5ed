"""Effect models (kpioed_drake.effects): parsing, Drake gravity torques, the effect models themselves,
and the closed-form augmented Jacobian against finite differences."""

import dataclasses

import numpy as np
import pytest

from kpioed_drake import effects as fx
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import forward_kinematics, point_velocity_jacobian
from kpioed_drake.tracker.measurement import measure, measurement_jacobian


@pytest.fixture(scope="module")
def poses(kr16):
    rng = np.random.default_rng(11)
    n = 6
    q = rng.uniform(kr16.lower, kr16.upper, size=(n, 6))
    return q, rng.uniform(10, 30, n), rng.uniform(0, 1800, n)


ALL = [
    "joint_elasticity:2",
    "joint_elasticity:5",
    "gear_cyclic:4:2",
    "gear_cyclic:1:1",
    "thermal_expansion",
    "tracker_drift",
]


def _drawn(model, seed=0):
    return fx.parse_effects(ALL, np.random.default_rng(seed), model=model)


# ---------------------------------------------------------------------------------------------- parsing
def test_parse_given_values_and_units():
    e = fx.parse_effect("joint_elasticity:2=2e-6")
    assert (e.family, e.joint, e.harmonic, e.values) == ("joint_elasticity", 2, None, (2e-6,))
    g = fx.parse_effect(" gear_cyclic:4:2=0.01,-0.005 ")
    assert g.key == ("gear_cyclic", 4, 2)
    np.testing.assert_allclose(g.values, np.deg2rad([0.01, -0.005]))
    np.testing.assert_allclose(g.display_values(), [0.01, -0.005])
    assert fx.parse_effect("thermal_expansion", np.random.default_rng(0)).values == (fx.STEEL_K,)
    assert fx.parse_effect("thermal_expansion").values is None
    assert fx.parse_effect("thermal_expansion=2e-5").values == (2e-5,)
    d = fx.parse_effect("tracker_drift=0.06,0,-0.03")
    np.testing.assert_allclose(d.values, [0.001, 0.0, -0.0005])  # mm/s inside
    np.testing.assert_allclose(d.display_values(), [0.06, 0.0, -0.03])
    # text round trip
    for e in (e, g, d):
        assert fx.parse_effect(e.text()).key == e.key
        np.testing.assert_allclose(fx.parse_effect(e.text()).values, e.values, rtol=1e-5)
    # without rng and value: unknown (an extension to estimate)
    assert fx.parse_effect("gear_cyclic:3:1").values is None
    assert fx.parse_effect("tracker_drift").values is None


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("elasticity:2", "unknown effect"),
        ("joint_elasticity", "JOINT"),
        ("joint_elasticity:7", "joint must be 1..6"),
        ("joint_elasticity:0", "joint must be 1..6"),
        ("joint_elasticity:1", "vertical axis"),
        ("gear_cyclic:4", "gear_cyclic:JOINT:N"),
        ("gear_cyclic:4:0", "harmonic"),
        ("gear_cyclic:4:x", "harmonic"),
        ("gear_cyclic:4:1=0.01", "2 comma-separated"),
        ("joint_elasticity:2=abc", "1 comma-separated"),
        ("joint_elasticity:2=", "nothing after"),
        ("thermal_expansion:2", "takes no joint"),
        ("tracker_drift=1,2", "3 comma-separated"),
        ("tracker_drift=1,nan,2", "3 comma-separated"),
    ],
)
def test_parse_errors(text, fragment):
    with pytest.raises(InputError, match=fragment):
        fx.parse_effect(text, np.random.default_rng(0))


def test_duplicate_effects_refused():
    with pytest.raises(InputError, match="more than once"):
        fx.parse_effects(["gear_cyclic:2:1", "gear_cyclic:2:1=0.01,0.01"])


def test_drawn_sizes_in_spec_ranges(model):
    rng = np.random.default_rng(5)
    for _ in range(50):
        g = fx.parse_effect("gear_cyclic:3:2", rng)
        a = np.abs(g.display_values())
        assert np.all((a >= 0.003) & (a <= 0.02))
        d = fx.parse_effect("tracker_drift", rng)
        assert 0.005 <= np.linalg.norm(d.display_values()) <= 0.05
        e = fx.parse_effect("joint_elasticity:3", rng)
        assert 0.1 <= e.tool_mm <= 1.0 and e.values is None
    # resolving turns the tool displacement into c: the largest displacement over the joint box
    e = fx.resolve(fx.Effect("joint_elasticity", 3, tool_mm=0.5), model)
    q = fx.reference_poses(model.robot)
    shift = fx.true_measurements(model, q, [e]) - measure(model, q)
    assert np.max(np.linalg.norm(shift, axis=1)) == pytest.approx(0.5, rel=2e-3)


# ---------------------------------------------------------------------------------------------- gravity
def test_gravity_torque_sign_and_joint1(kr16):
    """Drake's gravity generalized forces equal J^T (m g) with g = (0, 0, -9.81) m/s^2."""
    q = np.random.default_rng(2).uniform(kr16.lower, kr16.upper, size=(5, 6))
    tau = fx.gravity_torques(kr16, q)
    fr = forward_kinematics(kr16, q)
    ref = np.zeros_like(tau)
    for i in range(1, 7):
        p = fr.o[:, i] + np.einsum("nij,j->ni", fr.R[:, i], kr16.coms[i])
        J = point_velocity_jacobian(fr, p[:, None, :], np.array([i]))[:, 0]  # (n,6,3) mm/rad
        ref += 1e-3 * J @ np.array([0.0, 0.0, -9.81 * kr16.masses[i]])
    np.testing.assert_allclose(tau, ref, atol=1e-8 * np.abs(ref).max())
    np.testing.assert_allclose(tau[:, 0], 0.0, atol=1e-9)  # vertical axis: no torque on joint 1
    # arm stretched forward (q2 = -90 deg puts the upper arm horizontal): gravity pulls the arm down,
    # which for our joint-2 axis (y of W, turned by alpha1 = -90) is a positive torque
    tau_h = fx.gravity_torques(kr16, np.deg2rad([[0, -90, 90, 0, 0, 0]]))
    assert tau_h[0, 1] > 100.0


def test_gravity_torque_derivatives(kr16, model):
    q = np.random.default_rng(4).uniform(kr16.lower, kr16.upper, size=(4, 6))
    pay = np.array([0.0, 5.0, 10.0, 2.5])
    tau, dtau = fx.gravity_torques(kr16, q, payload_kg=pay, p_FP=model.p_FQ, with_dq=True)
    fd = np.zeros_like(dtau)
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = 1e-6
        fd[:, :, j] = (
            fx.gravity_torques(kr16, q + dq, payload_kg=pay, p_FP=model.p_FQ)
            - fx.gravity_torques(kr16, q - dq, payload_kg=pay, p_FP=model.p_FQ)
        ) / 2e-6
    np.testing.assert_allclose(dtau, fd, atol=1e-6 * np.abs(dtau).max())
    # payload torque: point mass at the reflector, J^T m g
    gm = fx.gravity_model(kr16)
    tp = gm.payload_torques(q, pay, model.p_FQ)
    fr = forward_kinematics(kr16, q)
    p = fr.o[:, 6] + fr.R[:, 6] @ model.p_FQ
    J = point_velocity_jacobian(fr, p[:, None, :], np.array([6]))[:, 0]
    np.testing.assert_allclose(tp, 1e-3 * np.einsum("njc,c,n->nj", J, [0, 0, -9.81], pay), atol=1e-9)
    dp = gm.payload_torques_dp(q, pay)
    for d in range(3):
        e = np.zeros(3)
        e[d] = 1e-3
        fdp = (gm.payload_torques(q, pay, model.p_FQ + e) - gm.payload_torques(q, pay, model.p_FQ - e)) / 2e-3
        np.testing.assert_allclose(dp[:, :, d], fdp, atol=1e-9)


# ---------------------------------------------------------------------------------------------- models
def test_effect_models_match_their_definitions(model, poses):
    q, T, t = poses
    rng = np.random.default_rng(1)
    # gear: measure at q + a sin(n q) + b cos(n q)
    g = fx.parse_effect("gear_cyclic:4:2", rng)
    a, b = g.values
    dq = np.zeros_like(q)
    dq[:, 3] = a * np.sin(2 * q[:, 3]) + b * np.cos(2 * q[:, 3])
    np.testing.assert_allclose(fx.true_measurements(model, q, [g]), measure(model, q + dq), atol=1e-9)
    # elasticity: measure at q + c tau (payload at the reflector)
    c = 3e-7
    tau = fx.gravity_torques(model.robot, q, payload_kg=8.0, p_FP=model.p_FQ)
    dq = np.zeros_like(q)
    dq[:, 1] = c * tau[:, 1]
    h = fx.true_measurements(model, q, [f"joint_elasticity:2={c}"], payload_kg=8.0)
    np.testing.assert_allclose(h, measure(model, q + dq), atol=1e-9)
    # thermal: every robot length (a, d, reflector offset) scaled by 1 + k (T - 20)
    k = 2e-5
    h = fx.true_measurements(model, q, [f"thermal_expansion={k}"], temperature_C=T)
    robot = model.robot
    is_len = ~np.array([nm.startswith(("theta", "alpha", "beta")) for nm in robot.param_names()])
    for i in range(len(q)):
        p = model.p.copy()
        s = 1 + k * (T[i] - fx.T_REF_C)
        p[model.layout.joints][is_len] *= s
        p[model.layout.target(0)] *= s
        np.testing.assert_allclose(h[i], measure(model.with_params(p), q[i : i + 1])[0], atol=1e-9)
    # drift: the tracker origin moves by v t in W
    v = np.array([0.03, -0.01, 0.02])  # mm/min
    h = fx.true_measurements(model, q, ["tracker_drift=" + ",".join(map(str, v))], time_s=t)
    np.testing.assert_allclose(
        h - measure(model, q), -(v[None, :] * t[:, None] / 60.0) @ model.R_WT, atol=1e-9
    )


def test_true_measurements_needs_values_and_columns(model, poses):
    q, _, _ = poses
    with pytest.raises(InputError, match="has no value"):
        fx.true_measurements(model, q, ["gear_cyclic:2:1"])
    with pytest.raises(InputError, match="temperature_C"):
        fx.true_measurements(model, q, ["thermal_expansion=1e-5"])
    with pytest.raises(InputError, match="time_s"):
        fx.true_measurements(model, q, ["tracker_drift=0.01,0,0"])


# ---------------------------------------------------------------------------------------------- Jacobian
def test_augmented_jacobian_without_effects_is_the_measurement_jacobian(model, poses):
    q, _, _ = poses
    h, H, E = fx.augmented_jacobian(model, q, [])
    h0, H0 = measurement_jacobian(model, q)
    np.testing.assert_allclose(h, h0, atol=1e-9)
    np.testing.assert_allclose(H, H0, atol=1e-9)
    assert E.shape == (len(q), 3, 0)


@pytest.mark.parametrize("payload", [None, 6.0])
def test_augmented_jacobian_matches_finite_differences(model, poses, payload):
    q, T, t = poses
    effs = _drawn(model)
    kw = dict(temperature_C=T, time_s=t, payload_kg=payload)
    h, H, E, dE = fx.augmented_jacobian(model, q, effs, with_dq=True, **kw)
    # geometric columns
    for k in range(33):
        step = 1e-6 if k in (0, 3, 4, 6, 7, 8, 11, 12, 15, 16, 19, 20, 23, 27, 28, 29) else 1e-4
        dp = np.zeros(33)
        dp[k] = step
        fd = (
            fx.augmented_jacobian(model.with_params(model.p + dp), q, effs, **kw)[0]
            - fx.augmented_jacobian(model.with_params(model.p - dp), q, effs, **kw)[0]
        ) / (2 * step)
        np.testing.assert_allclose(
            H[:, :, k], fd, atol=2e-6 * max(1.0, np.abs(H[:, :, k]).max()), err_msg=str(k)
        )
    # effect columns
    vals = np.concatenate([e.value_array() for e in effs])

    def with_vals(v):
        out, c = [], 0
        for e in effs:
            out.append(e.with_values(v[c : c + e.n_params]))
            c += e.n_params
        return out

    for k in range(vals.size):
        step = 1e-4 * max(abs(vals[k]), 1e-9)
        dv = np.zeros(vals.size)
        dv[k] = step
        fd = (
            fx.augmented_jacobian(model, q, with_vals(vals + dv), **kw)[0]
            - fx.augmented_jacobian(model, q, with_vals(vals - dv), **kw)[0]
        ) / (2 * step)
        np.testing.assert_allclose(E[:, :, k], fd, rtol=1e-6, atol=1e-6 * np.abs(E[:, :, k]).max())
    # joint-angle derivative of the effect columns
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = 1e-6
        fd = (
            fx.augmented_jacobian(model, q + dq, effs, **kw)[2]
            - fx.augmented_jacobian(model, q - dq, effs, **kw)[2]
        ) / 2e-6
        np.testing.assert_allclose(dE[:, j], fd, atol=1e-6 * max(1e-9, np.abs(dE).max()), err_msg=f"q{j + 1}")


def test_extension_columns_at_zero(model, poses):
    """What calibration/design append: columns at unknown (= zero) effect values, in column order."""
    q, T, t = poses
    ext = ["joint_elasticity:3", "gear_cyclic:2:1", "thermal_expansion", "tracker_drift"]
    names = fx.extension_param_names(ext)
    assert names == [
        "joint_elasticity:3.c",
        "gear_cyclic:2:1.a",
        "gear_cyclic:2:1.b",
        "thermal_expansion.k",
        "tracker_drift.vx",
        "tracker_drift.vy",
        "tracker_drift.vz",
    ]
    E, dE = fx.extension_columns(model, q, ext, temperature_C=T, time_s=t, with_dq=True)
    assert E.shape == (len(q), 3, 7) and dE.shape == (len(q), 6, 3, 7)
    _, H = measurement_jacobian(model, q)
    tau = fx.gravity_torques(model.robot, q)
    # a joint-angle effect column is the theta column times its factor
    np.testing.assert_allclose(E[:, :, 0], H[:, :, 8] * tau[:, 2:3], atol=1e-9)
    np.testing.assert_allclose(E[:, :, 1], H[:, :, 4] * np.sin(q[:, 1:2]), atol=1e-9)
    np.testing.assert_allclose(E[:, :, 4:7], -model.R_WT.T[None] * t[:, None, None], atol=1e-9)
    with pytest.raises(InputError, match="temperature_C"):
        fx.extension_columns(model, q, ["thermal_expansion"])


def test_kpi_columns_match_tcp_shift(model):
    qw = model.robot.q_work
    effs = [
        fx.parse_effect("joint_elasticity:2=1e-7"),
        fx.parse_effect("gear_cyclic:5:2=0.01,-0.02"),
        fx.parse_effect("thermal_expansion=1e-5"),
        fx.parse_effect("tracker_drift=0.01,0.02,0"),
    ]
    C = fx.effect_kpi_columns(model, qw, effs)
    lin = C @ np.concatenate([e.value_array() for e in effs])
    np.testing.assert_allclose(
        fx.effect_tcp_shift(model, qw, effs), lin, atol=1e-3 * np.abs(lin).max()
    )  # 2nd order
    assert np.all(C[:, 4:] == 0)  # thermal at T_ref and drift do not move the TCP


def test_effect_is_frozen_value_object():
    e = fx.parse_effect("gear_cyclic:1:2=0.01,0.01")
    with pytest.raises(dataclasses.FrozenInstanceError):
        e.joint = 2
    assert e.to_dict() == {
        "effect": "gear_cyclic",
        "joint": 1,
        "harmonic": 2,
        "value": [0.01, 0.01],
        "unit": "deg",
    }
