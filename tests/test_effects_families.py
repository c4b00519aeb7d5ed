"""The further effect families (joint_scale, joint_coupling, tracker_scale, backlash): text syntax,
models against their definitions, closed-form Jacobian columns against central finite differences,
and recovery by ``calibrate(..., effects=...)`` from simulated KR 16 data."""

import numpy as np
import pytest

from kpioed_drake import effects as fx
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.errors import InputError
from kpioed_drake.files.designs import read_design
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import as_measurements
from kpioed_drake.tracker.measurement import measure

DESIGN = "studies/results/designs/kr16_kpi_ca.csv"


@pytest.fixture(scope="module")
def poses(kr16):
    rng = np.random.default_rng(11)
    q = rng.uniform(kr16.lower, kr16.upper, size=(6, 6))
    return q, rng.uniform(10, 30, 6), rng.uniform(0, 1800, 6)


# ---------------------------------------------------------------------------------------------- syntax
def test_parse_values_units_and_round_trip():
    s = fx.parse_effect("joint_scale:2=300")
    assert s.key == ("joint_scale", 2, None) and s.values == pytest.approx((300e-6,))
    c = fx.parse_effect("joint_coupling:5:4=-200")
    assert c.name == "joint_coupling:5:4" and c.joint == 5 and c.coupled == 4
    assert c.to_dict()["coupled_joint"] == 4 and c.to_dict()["unit"] == "ppm"
    t = fx.parse_effect("tracker_scale=-0.93")
    assert t.values == pytest.approx((-0.93e-6,)) and t.param_names == ["tracker_scale.k"]
    b = fx.parse_effect("backlash:3=0.01")
    assert b.values == pytest.approx((np.deg2rad(0.01),)) and fx.UNITS["backlash"] == "deg"
    for e in (s, c, t, b):
        back = fx.parse_effect(e.text())
        assert back.key == e.key
        np.testing.assert_allclose(back.values, e.values, rtol=1e-5)
        assert fx.parse_effect(e.name).values is None  # an extension to estimate
    assert fx.parse_effect("tracker_scale", np.random.default_rng(0)).values == (fx.AIR_PPM_PER_K * 1e-6,)
    rng = np.random.default_rng(4)
    for _ in range(20):
        assert 100 <= abs(fx.parse_effect("joint_scale:3", rng).display_values()[0]) <= 1000
        assert 0.003 <= fx.parse_effect("backlash:2", rng).display_values()[0] <= 0.02
    # not diagnosis candidates
    assert not set(fx.EXTRA_FAMILIES) & set(fx.FAMILIES)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("joint_scale", "joint_scale:JOINT"),
        ("joint_scale:7", "joint must be 1..6"),
        ("joint_scale:2=1,2", "1 comma-separated"),
        ("joint_coupling:4", "joint_coupling:JOINT:JOINT"),
        ("joint_coupling:4:4", "coupled to itself"),
        ("tracker_scale:1", "tracker_scale\\[=k ppm/K\\]"),
        ("backlash:1", "vertical axis"),
        ("backlash:2=x", "1 comma-separated"),
        ("backlash:2=", "nothing after"),
    ],
)
def test_parse_errors_name_the_text(text, fragment):
    with pytest.raises(InputError, match=fragment) as err:
        fx.parse_effect(text, np.random.default_rng(0))
    assert repr(text) in str(err.value)


# ---------------------------------------------------------------------------------------------- models
def test_models_match_their_definitions(model, poses):
    q, T, _ = poses
    tau = fx.gravity_torques(model.robot, q)
    for text, i, dq_i in [
        ("joint_scale:2=500", 1, 500e-6 * q[:, 1]),
        ("joint_coupling:5:4=-300", 4, -300e-6 * q[:, 3]),
        ("backlash:3=0.02", 2, np.deg2rad(0.02) * np.sign(tau[:, 2])),
    ]:
        dq = np.zeros_like(q)
        dq[:, i] = dq_i
        np.testing.assert_allclose(fx.true_measurements(model, q, [text]), measure(model, q + dq), atol=1e-9)
    # tracker scale: every measured vector from the tracker scales by 1 + k (T - 20)
    h = fx.true_measurements(model, q, ["tracker_scale=3"], temperature_C=T)
    np.testing.assert_allclose(h, measure(model, q) * (1 + 3e-6 * (T - 20.0))[:, None], atol=1e-9)


ALL = ["joint_scale:2=400", "joint_coupling:5:4=-300", "tracker_scale=5", "backlash:3=0.02"]


@pytest.mark.parametrize("others", [[], ["thermal_expansion=2e-5", "tracker_drift=0.03,0.01,-0.02"]])
def test_columns_match_finite_differences(model, poses, others):
    q, T, t = poses
    effs = [fx.parse_effect(x) for x in ALL + others + ["joint_elasticity:2=2e-7"]]
    kw = dict(temperature_C=T, time_s=t)
    h, H, E, dE = fx.augmented_jacobian(model, q, effs, with_dq=True, **kw)
    np.testing.assert_allclose(h, fx.augmented_response(model, q, effs, **kw), atol=1e-9)
    vals = np.concatenate([e.value_array() for e in effs])

    def at(v):
        out, c = [], 0
        for e in effs:
            out.append(e.with_values(v[c : c + e.n_params]))
            c += e.n_params
        return out

    for k in range(vals.size):  # effect columns (all, as the tracker scale multiplies every column)
        dv = np.zeros(vals.size)
        dv[k] = 1e-4 * abs(vals[k])
        fd = (
            fx.augmented_response(model, q, at(vals + dv), **kw)
            - fx.augmented_response(model, q, at(vals - dv), **kw)
        ) / (2 * dv[k])
        np.testing.assert_allclose(
            E[:, :, k], fd, rtol=1e-6, atol=1e-6 * np.abs(E[:, :, k]).max(), err_msg=str(k)
        )
    for k in (0, 4, 8, 30):  # a few geometric columns, scaled by the tracker scale
        dp = np.zeros(model.p.size)
        dp[k] = 1e-6
        fd = (
            fx.augmented_response(model.with_params(model.p + dp), q, effs, **kw)
            - fx.augmented_response(model.with_params(model.p - dp), q, effs, **kw)
        ) / 2e-6
        np.testing.assert_allclose(
            H[:, :, k], fd, atol=2e-6 * max(1.0, np.abs(H[:, :, k]).max()), err_msg=str(k)
        )
    for j in range(6):  # joint-angle derivative of the effect columns (backlash: zero a.e.)
        dq = np.zeros_like(q)
        dq[:, j] = 1e-6
        fd = (
            fx.augmented_jacobian(model, q + dq, effs, **kw)[2]
            - fx.augmented_jacobian(model, q - dq, effs, **kw)[2]
        ) / 2e-6
        np.testing.assert_allclose(dE[:, j], fd, atol=1e-6 * max(1e-9, np.abs(dE).max()), err_msg=f"q{j + 1}")


def test_kpi_columns(model):
    qw = model.robot.q_work
    effs = [fx.parse_effect(x) for x in ALL]
    C = fx.effect_kpi_columns(model, qw, effs)
    lin = C @ np.concatenate([e.value_array() for e in effs])
    np.testing.assert_allclose(fx.effect_tcp_shift(model, qw, effs), lin, atol=1e-3 * np.abs(lin).max())
    assert np.all(C[:, 2] == 0) and np.all(C[:, [0, 1, 3]] != 0)  # the tracker does not move the TCP


# ---------------------------------------------------------------------------------------------- recovery
@pytest.mark.parametrize(
    "text", ["joint_scale:2=500", "joint_coupling:5:4=-400", "tracker_scale=10", "backlash:3=0.02"]
)
def test_calibrate_extended_recovers_the_value(kr16, tmp_path, text):
    q = read_design(DESIGN, kr16)
    table, _ = simulate(kr16, q, SimulationOptions(sigma_mm=0.02, seed=7, effects=[text]))
    path = tmp_path / "data.csv"
    table.to_csv(path, index=False)
    eff = fx.parse_effect(text)
    rep = calibrate(
        kr16, as_measurements(path, kr16), CalibrationOptions(effects=[eff.name], sigma_mm=0.02)
    ).to_dict()
    (ext,) = rep["effects"]
    true = eff.display_values()[0]
    print(text, "estimate", ext["value"], "+-", ext["std"], "chi2/dof", rep["chi2_per_dof"])
    assert abs(ext["value"] - true) < 3 * ext["std"][0]
    assert abs(true) > 5 * ext["std"][0]  # visible
    assert 0.7 < rep["chi2_per_dof"] < 1.3


def test_calibrate_extended_refuses_what_the_data_does_not_vary(kr16, tmp_path):
    q = read_design(DESIGN, kr16)
    table, _ = simulate(
        kr16, q, SimulationOptions(sigma_mm=0.02, seed=7), temperature_C=np.full(len(q), 20.0)
    )
    path = tmp_path / "data.csv"
    table.to_csv(path, index=False)
    with pytest.raises(InputError, match="temperature_C"):
        calibrate(kr16, as_measurements(path, kr16), CalibrationOptions(effects=["tracker_scale"])).to_dict()
    # backlash: joint 3's gravity torque of one sign only (the poses where it is positive)
    tau = fx.gravity_torques(kr16, q)
    table, _ = simulate(kr16, q[tau[:, 2] > 0], SimulationOptions(sigma_mm=0.02, seed=7))
    table.to_csv(path, index=False)
    with pytest.raises(InputError, match="both signs"):
        calibrate(kr16, as_measurements(path, kr16), CalibrationOptions(effects=["backlash:3"])).to_dict()
    assert calibrate(
        kr16, as_measurements(path, kr16), CalibrationOptions(effects=["joint_scale:3"])
    ).to_dict()["effects"]  # the data itself is usable
