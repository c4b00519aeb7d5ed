"""The mass-free gravity basis (``joint_elasticity_basis:j``): the regressor against Drake's torques,
its closed-form joint-angle derivative and the effect's Jacobian columns against finite differences,
the payload column, the joint-1 torque-range check, and a model test: elasticity simulated on a
robot whose masses and centres of mass are +-30 % off the file is fitted to the noise level by the
basis and not by the model-mass elasticity."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from fd import central_fd

from kpioed_drake import effects as fx
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.cli import main as cli_main
from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.study.synthetic import perturbed_masses, run_synthetic_case, synthetic_case
from kpioed_drake.tracker.data import as_measurements


@pytest.fixture(scope="module")
def q(kr16):
    return np.random.default_rng(5).uniform(kr16.lower, kr16.upper, size=(4, 6))


DESIGN = Path(__file__).resolve().parents[1] / "studies" / "results" / "designs" / "kr16_kpi_ca.csv"


@pytest.mark.parametrize("joint", [2, 3, 5, 6])
def test_regressor_reproduces_drake_and_masses_do_not_enter(kr16, q, joint):
    jb = gb.joint_basis(kr16, joint)
    tau = fx.gravity_torques(kr16, q)[:, joint - 1]
    np.testing.assert_allclose(jb.regressor(kr16, q) @ jb.beta_file, tau, atol=1e-9 * np.abs(tau).max())
    # other masses: the same basis (geometry only), other moments; Drake agrees
    other = perturbed_masses(kr16, np.random.default_rng(joint))
    jo = gb.joint_basis(other, joint)
    np.testing.assert_allclose(jo.V, jb.V, atol=1e-12)
    tau_o = fx.gravity_torques(other, q)[:, joint - 1]
    np.testing.assert_allclose(jb.regressor(kr16, q) @ jo.beta_file, tau_o, atol=1e-9 * np.abs(tau_o).max())


def test_ranks_and_joint1_torque_range(kr16, model):
    assert [gb.joint_basis(kr16, j).rank for j in range(1, 7)] == [0, 10, 8, 6, 4, 2]
    with pytest.raises(InputError, match="no torque on joint 1"):
        fx.parse_effect("joint_elasticity_basis:1", model=model)
    # a tilted gravity (e.g. a robot on a slope) makes joint 1 carry a torque: the range check, not the number
    assert gb.joint_basis(kr16, 1, g=np.array([2.0, 0.0, -9.6])).rank > 0
    e = fx.parse_effect("joint_elasticity_basis:3", model=model)
    assert e.n_params == 8 and e.param_names[0] == "joint_elasticity_basis:3.t0"
    with pytest.raises(InputError, match="resolve it first"):
        _ = fx.parse_effect("joint_elasticity_basis:3").n_params
    with pytest.raises(InputError, match="basis moments"):
        fx.parse_effect("joint_elasticity_basis:3=1,2", model=model)
    assert gb.resolve_basis(fx.parse_effect("joint_elasticity_basis:3"), model, [0, 5.0]).n_params == 9


@pytest.mark.parametrize("joint", [2, 4, 6])
def test_regressor_dq_matches_fd(kr16, q, joint):
    _, dY = gb.link_regressor(kr16, q, joint, with_dq=True)
    fd = central_fd(lambda x: gb.link_regressor(kr16, x, joint), q, 1e-6)  # (n, p, n, 6)
    fd = np.einsum("npnj->njp", fd)
    np.testing.assert_allclose(dY, fd, atol=1e-6 * max(1.0, np.abs(fd).max()))


@pytest.mark.parametrize("payload", [None, "varying"])
def test_effect_columns_and_dq_match_fd(model, q, payload):
    pay = None if payload is None else np.array([0.0, 4.0, 8.0, 2.0])
    e = gb.resolve_basis(fx.Effect("joint_elasticity_basis", 3), model, pay)
    rng = np.random.default_rng(3)
    e = e.with_values(1e-4 * rng.standard_normal(e.n_params))
    h, _, E, dE = fx.augmented_jacobian(model, q, [e], payload_kg=pay, with_dq=True)
    # columns: d h / d values
    v0 = e.value_array()
    fdv = np.zeros_like(E)
    for k in range(v0.size):
        vp, vm = v0.copy(), v0.copy()
        vp[k] += 1e-7
        vm[k] -= 1e-7
        hp = fx.augmented_response(model, q, [e.with_values(vp)], payload_kg=pay)
        hm = fx.augmented_response(model, q, [e.with_values(vm)], payload_kg=pay)
        fdv[:, :, k] = (hp - hm) / 2e-7
    np.testing.assert_allclose(E, fdv, atol=1e-6 * np.abs(fdv).max())
    # d E / d q
    fdq = central_fd(lambda x: fx.extension_columns(model, x, [e], payload_kg=pay), q, 1e-6)
    n = q.shape[0]
    fdq = fdq[np.arange(n), :, :, np.arange(n), :].transpose(0, 3, 1, 2)  # own pose: (n, 6, 3, k)
    np.testing.assert_allclose(dE, fdq, atol=1e-5 * np.abs(fdq).max())


def test_payload_column_is_the_payload_torque(kr16, model, q):
    pay = np.array([0.0, 4.0, 8.0, 2.0])
    e = gb.resolve_basis(fx.Effect("joint_elasticity_basis", 2), model, pay)
    f = gb.basis_factors(model, q, e, payload_kg=pay)
    tau = fx.gravity_torques(kr16, q, payload_kg=pay, p_FP=model.p_FQ)
    np.testing.assert_allclose(f[:, -1], tau[:, 1] - fx.gravity_torques(kr16, q)[:, 1], atol=1e-9)
    np.testing.assert_allclose(gb.basis_factors(model, q, e, tau=tau), f, atol=1e-9)


def _fit_chi2(robot, case, family, joint):
    """chi2/dof and fit of the geometry + one elasticity, with the model file's robot."""
    prob = FitProblem(robot, case.data, case.sigma)
    eff = fx.Effect(family, joint)
    if family == gb.FAMILY:
        eff = gb.resolve_basis(eff, prob.nominal, case.data.payload_kg)
    f = prob.fit([eff])
    return f.chi2_per_dof, f


@pytest.mark.parametrize("payload", [False, True])
def test_basis_fits_mass_mismatch_to_noise(kr16, payload):
    """KR 16, joint-5 elasticity (1 mm tool size), true masses/COMs +-30 % off the file, 120 poses
    (measured over seeds 0-3, payload 0/15 kg: chi2/dof model masses 2.4-8.4, basis 1.00-1.11;
    joints 2, 3: 1.09-1.52 against 0.99-1.11)."""
    rng = np.random.default_rng(1)
    eff = dataclasses.replace(fx.parse_effect("joint_elasticity:5"), tool_mm=1.0)
    case = synthetic_case(
        kr16,
        rng,
        [eff],
        n_poses=120,
        sigma=0.02,
        mass_spread=0.3,
        payload_kg=(0.0, 15.0) if payload else None,
    )
    chi_model, _ = _fit_chi2(kr16, case, "joint_elasticity", 5)
    chi_basis, fit = _fit_chi2(kr16, case, gb.FAMILY, 5)
    sd = np.sqrt(2.0 / fit.dof)
    assert chi_basis < 1.0 + 4.0 * sd  # chi2/dof ~ 1 within 4 standard deviations
    assert chi_model > 1.0 + 10.0 * sd  # the model-mass version does not fit
    c_true = case.effects[0].values[0]
    rep = gb.basis_compliance(fit.effects[0], fit.model)
    # against the file's torques: the true compliance up to the mass mismatch
    assert 0.6 * c_true < rep["compliance"] < 1.4 * c_true
    if payload:  # a varying payload identifies the compliance itself
        assert rep["payload_compliance"] == pytest.approx(c_true, rel=0.05)


def test_diagnose_upgrades_elasticity_when_masses_are_off(kr16):
    """diagnose names joint 5's elasticity with the gravity basis (no stand-ins), fits to the
    noise level and reports the compliance against the file's torques."""
    rng = np.random.default_rng(1)
    eff = dataclasses.replace(fx.parse_effect("joint_elasticity:5"), tool_mm=1.0)
    case = synthetic_case(kr16, rng, [eff], n_poses=60, sigma=0.02, mass_spread=0.3)
    rep = diagnose(kr16, case.data, DiagnosisOptions(sigma_mm=0.02))
    assert [c["name"] for c in rep.causes] == ["joint_elasticity_basis:5"]
    up = rep.causes[0]["evidence"]["basis_upgrade"]
    assert up["replaces"] == "joint_elasticity:5" and up["p_value"] < 1e-6
    assert 0.6 < up["basis_compliance"] / case.effects[0].values[0] < 1.4
    assert rep.extended["chi2_per_dof"] < 1.0 + 4.0 * np.sqrt(2.0 / rep.extended["dof"])
    assert any("gravity basis" in n for n in rep.notes)
    # with the file's masses the same elasticity stays the one-parameter family
    case = synthetic_case(kr16, np.random.default_rng(1), [eff], n_poses=60, sigma=0.02)
    assert [c["name"] for c in diagnose(kr16, case.data, DiagnosisOptions(sigma_mm=0.02)).causes] == [
        "joint_elasticity:5"
    ]


def test_calibrate_extend_with_the_basis(kr16):
    """``calibrate --extend joint_elasticity_basis:5`` (API): sized per robot and payload; a varying
    payload adds the compliance parameter; a text with the wrong number of values is refused."""
    rng = np.random.default_rng(4)
    eff = dataclasses.replace(fx.parse_effect("joint_elasticity:5"), tool_mm=0.5)
    case = synthetic_case(kr16, rng, [eff], n_poses=60, sigma=0.02, mass_spread=0.3, payload_kg=(0.0, 10.0))
    rep = calibrate(
        kr16,
        as_measurements(case.data, kr16),
        CalibrationOptions(effects=["joint_elasticity_basis:5"], sigma_mm=0.02),
    ).to_dict()
    assert rep["chi2_per_dof"] < 1.0 + 4.0 * np.sqrt(2.0 / (3 * 60 - 33 - 5))
    (ext,) = rep["effects"]
    assert ext["effect"] == "joint_elasticity_basis" and len(ext["value"]) == 5  # r_5 = 4, + payload
    assert ext["value"][-1] == pytest.approx(case.effects[0].values[0], rel=0.1)
    with pytest.raises(InputError, match="basis moments"):
        calibrate(
            kr16,
            as_measurements(case.data, kr16),
            CalibrationOptions(effects=["joint_elasticity_basis:5=1,2"], sigma_mm=0.02),
        ).to_dict()


def test_backlash_side_from_the_data_when_masses_are_off():
    """backlash:6 on a robot whose link-6 centre of mass is off the file's: the file's torque puts
    poses on the wrong side, the selection names joint_elasticity:6; the side fitted from the data
    names the backlash (harness case single/backlash seed 22: named joint_elasticity:6 before)."""
    rec = run_synthetic_case(
        "single", 22, "kr16", families=("backlash",), mass_spread=0.3, near_threshold=True
    )
    assert rec["truth_names"] == ["backlash:6"] and rec["lambda"][0] > 25
    assert rec["named"] == ["backlash:6"] and rec["holdout_ext_over_sigma"] < 1.3


@pytest.mark.parametrize("joint", [2, 4, 6])
def test_torque_std_matches_monte_carlo_of_the_mass_prior(kr16, q, joint):
    """torque_std (first-order propagation) against the spread of the torque over robots whose
    masses and centres of mass are drawn as the harness draws them (``perturbed_masses``)."""
    Y = gb.link_regressor(kr16, q, joint)
    rng = np.random.default_rng(joint)
    taus = np.array(
        [Y @ gb.link_moments(perturbed_masses(kr16, rng, gb.MASS_PRIOR_SPREAD), joint) for _ in range(4000)]
    )
    np.testing.assert_allclose(gb.torque_std(kr16, q, joint), taus.std(axis=0), rtol=0.08)
    assert np.all(gb.torque_std(kr16, q, joint, spread=0.0) == 0.0)


def test_expected_side():
    tau = np.array([-2.0, 0.0, 1.0, 1.0, 3.0])
    std = np.array([1.0, 1.0, 1.0, 0.0, 1e-6])
    np.testing.assert_allclose(gb.expected_side(tau, std), [-0.9545, 0.0, 0.6827, 1.0, 1.0], atol=1e-4)
    assert gb.expected_side(np.array([0.0]), np.array([0.0]))[0] == 0.0


def test_backlash_column_takes_the_given_side(model, q):
    """A backlash's column is ``G sign(tau)`` by default and ``G side`` with a given side (the
    diagnosis's expected side); the response agrees with the Jacobian's column."""
    bl = fx.Effect("backlash", 4, values=(0.0,))
    tau = fx.gravity_torques(model.robot, q)
    side = np.tile(np.array([0.9, -0.2, 0.0, 1.0])[:, None], (1, 6))
    _, _, E_sign = fx.augmented_jacobian(model, q, [bl], tau=tau)
    _, _, E_side = fx.augmented_jacobian(model, q, [bl], tau=tau, side=side)
    G = E_sign[:, :, 0] * np.sign(tau[:, 3])[:, None]
    np.testing.assert_allclose(E_side[:, :, 0], G * side[:, 3:4], atol=1e-12)
    h0 = fx.augmented_response(model, q, [bl], tau=tau, side=side)
    h1 = fx.augmented_response(model, q, [bl.with_values((1e-6,))], tau=tau, side=side)
    np.testing.assert_allclose(h1 - h0, 1e-6 * E_side[:, :, 0], atol=1e-8)


def test_backlash_with_the_expected_side_when_masses_are_off():
    """backlash:6 near the threshold (harness case single/backlash seed 87, lambda 37): the file's
    torque puts 10 of 80 poses on the wrong side and the file-sign column keeps lambda 17.5, nothing
    was named; the expected side (uncertain poses weigh little) names it."""
    rec = run_synthetic_case(
        "single", 87, "kr16", families=("backlash",), mass_spread=0.3, payload="changes", near_threshold=True
    )
    assert rec["truth_names"] == ["backlash:6"] and 25 < rec["lambda"][0] < 50
    assert rec["named"] == ["backlash:6"] and rec["holdout_ext_over_sigma"] < 1.3


def test_design_extend_with_the_basis(kr16):
    """``design --extend joint_elasticity_basis:3`` (API): sized per robot, its columns in F1."""
    prob = make_problem(kr16, extend=["joint_elasticity_basis:3"])
    assert prob.n_params == prob.model.layout.n_free + 8
    q = np.random.default_rng(0).uniform(kr16.lower, kr16.upper, size=(40, 6))
    F1 = prob.F1(q)
    assert F1.shape == (120, prob.n_params) and np.linalg.matrix_rank(F1) == prob.n_params


@pytest.mark.parametrize(
    ("argv", "pattern"),
    [
        (
            "simulate --robot kr16 --design {design} --effect joint_elasticity_basis:3 --out {out}",
            "no size to draw",
        ),
        (
            "design --robot kr16 --criterion kpi --extend joint_elasticity_basis:1 --out {out}",
            "no torque on joint 1",
        ),
        ("evaluate --robot kr16 --design {design} --extend joint_elasticity_basis:3=1,2", "basis moments"),
    ],
)
def test_cli_bad_input(tmp_path, capsys, argv, pattern):
    """Bad basis extensions on the command line: exit 2, one line naming the effect, nothing written."""
    out = tmp_path / "out.csv"
    code = cli_main(argv.format(design=DESIGN, out=out).split())
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert re.search(pattern, [ln for ln in err.splitlines() if ln.startswith("kpioed:")][-1])
    assert not out.exists()
