"""Column and base compliance (``column_compliance:k``, ``base_compliance``): the cantilever model and
its sign, the closed-form columns and joint-value derivatives against central finite differences,
the text syntax, the model test on simulated lift7 data and the diagnosis candidates."""

import dataclasses

import numpy as np
import pytest

from kpioed_drake import effects as fx
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.cli import main
from kpioed_drake.design.discriminate.explanations import parse_pair
from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.diagnosis.options import DiagnosisOptions
from kpioed_drake.diagnosis.selection import candidate_effects
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.effects import compliance as cp
from kpioed_drake.effects.gravity_basis import link_moments, link_regressor
from kpioed_drake.effects.physical import plausibility
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.models import MODELS_DIR, load_cell, load_robot
from kpioed_drake.study.synthetic import detectability, perturbed_masses, synthetic_case
from kpioed_drake.tracker.data import as_measurements
from kpioed_drake.tracker.measurement import nominal_model

ROBOTS = MODELS_DIR / "robots"


@pytest.fixture(scope="module")
def lift7():
    return load_robot("lift7")


@pytest.fixture(scope="module")
def lmodel(lift7):
    return nominal_model(lift7, load_cell(robot=lift7))


@pytest.fixture(scope="module")
def lposes(lift7):
    q = np.random.default_rng(5).uniform(lift7.lower, lift7.upper, size=(4, 7))
    return q


# ---------------------------------------------------------------------------------------------- mechanics
def test_moment_uses_the_masses_drake_uses(lift7, lposes):
    """The gravity torque of a revolute joint is the axis component of the moment of the links it
    carries about a point on its axis: the base moment projected on joint 3's axis through the base
    origin differs from Drake's tau_3 only by the moment of links 1, 2 (checked by a column at the
    carriage instead: joint 2 is vertical, so its torque and the moment's axis part are both 0)."""
    q = lposes
    fr = forward_kinematics(lift7, q)
    rot = cp.rotation(lift7, cp.COLUMN, 1, q, p_FP=np.zeros(3))
    a = fr.joint_axes[:, 0]
    np.testing.assert_allclose(np.einsum("na,na->n", rot.m, a), 0.0, atol=1e-12)  # perpendicular
    # the column moment equals sum over links >= 1 of m (p - C) x g; its component along joint 3's
    # axis through C plus the moment of the force about the offset equals Drake's tau_3 for links >= 3
    tau = fx.gravity_torques(lift7, q)
    w3, a3 = fr.joint_axes[:, 2], fr.joint_points[:, 2]
    links = np.arange(3, 8)
    p_l = fr.o[:, links] + np.einsum("nlab,lb->nla", fr.R[:, links], lift7.coms[links])
    g = fx.gravity_model(lift7).g
    mom = 1e-3 * np.einsum("l,nla->na", lift7.masses[links], np.cross(p_l - a3[:, None], g))
    np.testing.assert_allclose(np.einsum("na,na->n", w3, mom), tau[:, 2], rtol=1e-9)


def test_column_is_a_cantilever_leaning_towards_the_load(lift7, lmodel):
    """Arm stretched along +x (q = 0), no payload: the carriage moves by M h^2 / (2 EI) towards +x
    and everything above turns by M h / EI about +y (down at the front)."""
    q = np.zeros((1, 7))
    q[0, 0] = 300.0  # carriage 350 mm above the foot
    c = 1e-6
    rot = cp.rotation(lift7, cp.COLUMN, 1, q, p_FP=lmodel.p_FQ)
    fr = forward_kinematics(lift7, q)
    C = fr.o[0, 1]
    h = 0.35  # m
    links = np.arange(1, 8)
    p_l = fr.o[0, links] + np.einsum("lab,lb->la", fr.R[0, links], lift7.coms[links])
    g = fx.gravity_model(lift7).g
    M = 1e-3 * np.sum(lift7.masses[links, None] * np.cross(p_l - C, g), axis=0)  # N m
    assert M[1] > 0 and abs(M[0]) < 0.01 * M[1] and M[2] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(c * rot.m[0], c * M * h, rtol=1e-9)  # theta = M h / EI
    carriage = c * rot.displacement(C[None])[0]  # M h^2 / (2 EI) towards the load [mm]
    np.testing.assert_allclose(carriage, 1e3 * c * np.cross(M, [0, 0, 1]) * h**2 / 2, rtol=1e-9, atol=1e-15)
    assert carriage[0] > 0
    tool = c * rot.displacement(flange_point(fr, lmodel.p_FQ))[0]
    assert tool[0] > 0 and tool[2] < 0  # the top leans forward and the arm tips down


@pytest.mark.parametrize("family, joint", [(cp.COLUMN, 1), (cp.BASE, None)])
@pytest.mark.parametrize("payload", [None, 8.0])
def test_rotation_derivatives_match_finite_differences(lift7, lposes, family, joint, payload):
    q = lposes
    p_FP = np.array([-90.0, -3.0, 327.0])
    rot = cp.rotation(lift7, family, joint, q, p_FP=p_FP, payload_kg=payload, with_dq=True)
    q_steps = np.where(lift7.prismatic, 1e-3, 1e-6)

    def fd(attr):
        out = np.zeros((len(q), 7, 3))
        for j in range(7):
            dq = np.zeros(7)
            dq[j] = q_steps[j]
            plus = getattr(cp.rotation(lift7, family, joint, q + dq, p_FP=p_FP, payload_kg=payload), attr)
            minus = getattr(cp.rotation(lift7, family, joint, q - dq, p_FP=p_FP, payload_kg=payload), attr)
            out[:, j] = (plus - minus) / (2 * q_steps[j])
        return out

    np.testing.assert_allclose(rot.dm, fd("m"), atol=1e-6 * np.abs(rot.dm).max())
    np.testing.assert_allclose(rot.dpivot, fd("pivot"), atol=1e-6)
    if payload is None:
        assert rot.dm_dp is None
        return
    dp = np.zeros((len(q), 3, 3))
    for d in range(3):
        e = np.eye(3)[d] * 1e-3
        plus = cp.rotation(lift7, family, joint, q, p_FP=p_FP + e, payload_kg=payload).m
        minus = cp.rotation(lift7, family, joint, q, p_FP=p_FP - e, payload_kg=payload).m
        dp[:, :, d] = (plus - minus) / 2e-3
    np.testing.assert_allclose(rot.dm_dp, dp, atol=1e-7 * np.abs(rot.dm_dp).max())


# ---------------------------------------------------------------------------------------------- columns
def _effects(lmodel):
    return [
        fx.parse_effect("column_compliance:1=8e-7", model=lmodel),
        fx.parse_effect("base_compliance=3e-7", model=lmodel),
        fx.parse_effect("joint_elasticity:4=2e-6", model=lmodel),
    ]


@pytest.mark.parametrize("payload", [None, 6.0])
def test_augmented_jacobian_matches_finite_differences(lmodel, lposes, payload):
    q = lposes
    effs = _effects(lmodel)
    h, H, E = fx.augmented_jacobian(lmodel, q, effs, payload_kg=payload)
    h_r = fx.augmented_response(lmodel, q, effs, payload_kg=payload)
    np.testing.assert_allclose(h, h_r, atol=1e-9)
    # geometric columns (exact with the compliances' rotation, payload moment included)
    for k in np.flatnonzero(np.abs(H).max(axis=(0, 1)) > 0):
        step = 1e-6 if lmodel.layout.names[k].startswith(("r", "off")) else 1e-4
        dp = np.zeros(lmodel.p.size)
        dp[k] = step
        fd = (
            fx.augmented_response(lmodel.with_params(lmodel.p + dp), q, effs, payload_kg=payload)
            - fx.augmented_response(lmodel.with_params(lmodel.p - dp), q, effs, payload_kg=payload)
        ) / (2 * step)
        np.testing.assert_allclose(
            H[:, :, k], fd, atol=2e-6 * max(1.0, np.abs(H[:, :, k]).max()), err_msg=str(k)
        )
    # the compliance columns (the response is linear in c)
    for i in range(2):
        v = effs[i].value_array()[0]
        up = [e.with_values([v * 1.5]) if k == i else e for k, e in enumerate(effs)]
        dn = [e.with_values([v * 0.5]) if k == i else e for k, e in enumerate(effs)]
        fd = (
            fx.augmented_response(lmodel, q, up, payload_kg=payload)
            - fx.augmented_response(lmodel, q, dn, payload_kg=payload)
        ) / v
        np.testing.assert_allclose(E[:, :, i], fd, rtol=1e-6, atol=1e-9 * np.abs(E[:, :, i]).max())


def test_extension_columns_and_their_joint_derivative(lmodel, lposes):
    """The design's columns (values unknown: c = 0) and d/dq against finite differences, with a payload."""
    q = lposes
    ext = ["column_compliance:1", "base_compliance", "gear_cyclic:3:1"]
    E, dE = fx.extension_columns(lmodel, q, ext, payload_kg=5.0, with_dq=True)
    assert E.shape == (4, 3, 4) and np.all(np.abs(E[:, :, :2]).max(axis=(0, 1)) > 0)
    steps = np.where(lmodel.robot.prismatic, 1e-3, 1e-6)
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = steps[j]
        fd = (
            fx.extension_columns(lmodel, q + dq, ext, payload_kg=5.0)
            - fx.extension_columns(lmodel, q - dq, ext, payload_kg=5.0)
        ) / (2 * steps[j])
        scale = np.abs(E).max(axis=(0, 1))  # per column
        np.testing.assert_allclose(dE[:, j] / scale, fd / scale, atol=1e-6, err_msg=str(j))


def test_compliance_column_derivative_at_a_value(lmodel, lposes):
    """dE of a compliance column is exact at any c (its column does not depend on c)."""
    q = lposes[:2]
    effs = [fx.parse_effect("column_compliance:1=8e-7", model=lmodel)]
    _, _, _, dE = fx.augmented_jacobian(lmodel, q, effs, with_dq=True)

    def col(qq):
        return fx.augmented_jacobian(lmodel, qq, effs)[2][:, :, 0]

    steps = np.where(lmodel.robot.prismatic, 1e-3, 1e-6)
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = steps[j]
        fd = (col(q + dq) - col(q - dq)) / (2 * steps[j])
        np.testing.assert_allclose(dE[:, j, :, 0], fd, atol=1e-6 * np.abs(dE).max())


def test_kpi_column_is_the_tcp_shift(lmodel):
    qw = lmodel.robot.q_work
    effs = _effects(lmodel)[:2]
    cols = fx.effect_kpi_columns(lmodel, qw, effs)
    shift = fx.effect_tcp_shift(lmodel, qw, effs)
    np.testing.assert_allclose(cols @ np.concatenate([e.value_array() for e in effs]), shift, rtol=1e-9)
    assert 0.01 < np.linalg.norm(shift) < 5.0  # mm at c of realistic size


def test_no_compliance_leaves_the_response_alone(lmodel, lposes):
    effs = [fx.parse_effect("joint_elasticity:3=1e-6", model=lmodel)]
    a = fx.augmented_jacobian(lmodel, lposes, effs)
    b = fx.augmented_jacobian(lmodel, lposes, effs, compliance_payload_kg=7.0)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


# ---------------------------------------------------------------------------------------------- syntax
def test_parse_values_units_and_sizes(lmodel):
    e = fx.parse_effect("column_compliance:1=5e-7")
    assert (
        e.key == ("column_compliance", 1, None)
        and e.values == (5e-7,)
        and e.param_names == ["column_compliance:1.c"]
    )
    assert e.to_dict()["unit"] == "1/(N m^2)" and fx.parse_effect(e.text()).values == pytest.approx(e.values)
    b = fx.parse_effect("base_compliance=2e-7")
    assert b.name == "base_compliance" and b.to_dict()["unit"] == "rad/(N m)"
    assert fx.parse_effect("base_compliance").values is None  # an extension to estimate
    rng = np.random.default_rng(3)
    robot = lmodel.robot
    q = fx.reference_poses(robot)
    p = flange_point(forward_kinematics(robot, q), lmodel.p_FQ)
    for text in ("column_compliance:1", "base_compliance"):
        for _ in range(3):
            d = fx.parse_effect(text, rng, model=lmodel)
            rot = cp.rotation(robot, d.family, d.joint, q, p_FP=lmodel.p_FQ)
            largest = np.max(np.linalg.norm(d.values[0] * rot.displacement(p), axis=1))
            assert 0.1 <= largest <= 1.0 and largest == pytest.approx(d.tool_mm)


@pytest.mark.parametrize(
    "text, fragment, on",
    [
        ("column_compliance", "column_compliance:JOINT", None),
        ("column_compliance:2", "joint 2 of lift7 is revolute", "lift7"),
        ("column_compliance:1", "needs the prismatic joint", "kr16"),
        ("column_compliance:8", "joint must be 1..7", "lift7"),
        ("column_compliance:1=x", "1 comma-separated", None),
        ("base_compliance:1", "takes no joint", None),
        ("base_compliance=1,2", "1 comma-separated", None),
    ],
)
def test_parse_errors_name_the_text(text, fragment, on, lmodel, model):
    m = {"lift7": lmodel, "kr16": model, None: None}[on]
    with pytest.raises(InputError, match=fragment) as err:
        fx.parse_effect(text, np.random.default_rng(0), model=m)
    assert repr(text) in str(err.value)


# ---------------------------------------------------------------------------------------------- CLI
def test_cli_simulate_refuses_a_revolute_column(lift7, tmp_path, capsys):
    design = tmp_path / "d.csv"
    write_design(design, np.random.default_rng(0).uniform(lift7.lower, lift7.upper, (20, 7)), robot=lift7)
    out = tmp_path / "data.csv"
    argv = ["simulate", "--robot", "lift7", "--design", str(design), "--effect", "column_compliance:2"]
    assert main([*argv, "--out", str(out)]) == 2
    assert "joint 2 of lift7 is revolute" in capsys.readouterr().err and not out.exists()
    assert main(["simulate", "--robot", "kr16", "--design", str(design), "--effect", "base_compliance=x",
                 "--out", str(out)]) == 2  # fmt: skip
    assert not out.exists()


def test_design_extends_by_a_column_compliance(lift7):
    prob = make_problem(lift7, extend=["column_compliance:1", "base_compliance"])
    q = np.random.default_rng(2).uniform(lift7.lower, lift7.upper, (40, 7))
    F1 = prob.F1(q)
    assert F1.shape[1] == lift7_free(prob) + 2 and np.all(np.linalg.norm(F1[:, -2:], axis=0) > 0)
    with pytest.raises(InputError, match="compliances"):
        make_problem(lift7, extend=["thermal_expansion"])


def lift7_free(prob):
    return prob.model.layout.n_free


# ---------------------------------------------------------------------------------------------- model test
@pytest.fixture(scope="module")
def column_case(lift7):
    """lift7, 100 poses, sigma 0.02 mm, link masses +-30 % off the file's, a hidden column compliance."""
    return synthetic_case(
        lift7, np.random.default_rng(1), ["column_compliance:1"], n_poses=100, mass_spread=0.3
    )


def test_extended_model_fits_to_the_noise(lift7, column_case):
    geo = calibrate(
        lift7, as_measurements(column_case.data, lift7), CalibrationOptions(effects=[], sigma_mm=0.02)
    ).to_dict()
    ext = calibrate(
        lift7,
        as_measurements(column_case.data, lift7),
        CalibrationOptions(effects=["column_compliance:1"], sigma_mm=0.02),
    ).to_dict()
    assert geo["chi2_per_dof"] > 3.0
    assert ext["chi2_per_dof"] < 1.3
    (c,) = ext["effects"]
    true = column_case.effects[0].values[0]
    assert c["unit"] == "1/(N m^2)" and abs(c["value"] - true) < 0.3 * true  # masses +-30 %


def test_extended_model_with_a_varying_payload(lift7):
    """The payload's moment is part of the compliance in simulation and in the fit (the fit's
    conditions carry the data's payload)."""
    case = synthetic_case(
        lift7, np.random.default_rng(2), ["column_compliance:1=8e-7"], n_poses=80, payload_kg=(0.0, 40.0)
    )
    ext = calibrate(
        lift7,
        as_measurements(case.data, lift7),
        CalibrationOptions(effects=["column_compliance:1"], sigma_mm=0.02),
    ).to_dict()
    assert ext["chi2_per_dof"] < 1.25 and ext["effects"][0]["value"] == pytest.approx(8e-7, rel=0.05)


# ---------------------------------------------------------------------------------------------- diagnosis
def test_candidates_on_a_lift_and_unchanged_elsewhere(lift7, kr16, column_case, tmp_path):
    data = column_case.data
    names = [e.name for e in candidate_effects(data, robot=lift7)[0]]
    assert names[-2:] == ["column_compliance:1", "base_compliance"]
    q = data.q.copy()
    q[:, 0] = 100.0  # the carriage stays put
    still = dataclasses.replace(data, q=q)
    cands, notes = candidate_effects(still, robot=lift7)
    assert "base_compliance" in [e.name for e in cands] and "column_compliance:1" not in [
        e.name for e in cands
    ]
    assert any("spans 0 mm" in n for n in notes)
    # a six-joint robot file: the same list with and without the robot
    k = synthetic_case(kr16, np.random.default_rng(0), [], n_poses=20).data
    tau = fx.gravity_torques(kr16, k.q)
    assert [e.name for e in candidate_effects(k, tau, robot=kr16)[0]] == [
        e.name for e in candidate_effects(k, tau)[0]
    ]
    assert candidate_effects(k, tau, robot=kr16)[1] == candidate_effects(k, tau)[1]
    # a robot file that says its base is compliant
    (tmp_path / "ur5c.urdf").write_text((ROBOTS / "ur5.urdf").read_text())
    side = (ROBOTS / "ur5.kpioed.yaml").read_text()
    (tmp_path / "ur5c.kpioed.yaml").write_text(side + "\ncompliant_base: true\n")
    soft = load_robot(str(tmp_path / "ur5c.urdf"))
    assert soft.compliant_base and not load_robot("ur5").compliant_base
    q6 = np.zeros((5, 6))
    assert [e.name for e in candidate_effects(dataclasses.replace(k, q=q6), robot=soft)[0]][
        -1
    ] == "base_compliance"


def test_compliant_base_must_be_true_or_false(tmp_path):
    (tmp_path / "ur5c.urdf").write_text((ROBOTS / "ur5.urdf").read_text())
    side = (ROBOTS / "ur5.kpioed.yaml").read_text()
    (tmp_path / "ur5c.kpioed.yaml").write_text(side + "\ncompliant_base: maybe\n")
    with pytest.raises(InputError, match="ur5c.kpioed.yaml"):
        load_robot(str(tmp_path / "ur5c.urdf"))


def test_diagnose_names_the_column(lift7, column_case):
    """Not gear_cyclic stand-ins: the column compliance itself, and the held-out RMS at the noise."""
    rep = diagnose(lift7, column_case.data, DiagnosisOptions(sigma_mm=0.02))
    assert [c.get("name", c["effect"]) for c in rep.causes] == ["column_compliance:1"]
    assert rep.causes[0]["plausible"]
    assert rep.extended["holdout_rms_mm"] < 1.3 * 0.02 < rep.baseline["holdout_rms_mm"]


def test_negative_compliance_is_implausible():
    tau = np.ones((3, 7))
    bad = fx.parse_effect("column_compliance:1=-5e-7")
    ok, why = plausibility(bad, np.array([1e-7]), tau=tau, time_s=None)
    assert not ok and "negative compliance" in why and "1/(N m^2)" in why
    assert plausibility(bad, np.array([1e-6]), tau=tau, time_s=None)[0]  # not pinned down: not flagged
    assert plausibility(fx.parse_effect("base_compliance=2e-7"), np.array([1e-8]), tau=tau, time_s=None)[0]


def test_harness_masses_reach_the_urdf_plant(lift7):
    """The synthetic harness's +-30 % masses act on a URDF robot's Drake gravity torques too."""
    other = perturbed_masses(lift7, np.random.default_rng(3))
    q = np.random.default_rng(1).uniform(lift7.lower, lift7.upper, (5, 7))
    tau, tau0 = fx.gravity_torques(other, q), fx.gravity_torques(lift7, q)
    for j in range(3, 8):
        np.testing.assert_allclose(
            tau[:, j - 1], link_regressor(other, q, j) @ link_moments(other, j), atol=1e-9
        )
    assert np.abs(tau[:, 2] - tau0[:, 2]).max() > 1.0  # [N m]


def test_discrimination_pair_takes_a_compliance_without_value(lmodel):
    a, b = parse_pair("column_compliance:1|joint_elasticity:3", lmodel)
    assert a.source == "default" and a.effect.tool_mm == 0.1
    size = cp.lever(lmodel.robot, cp.COLUMN, 1, lmodel.p_FQ)
    assert a.theta[0] * size == pytest.approx(0.1)


def test_base_compliance_and_shoulder_elasticity_look_alike_on_kr16(kr16):
    """A floor-mounted six-joint robot: a small base compliance (lambda 60) is reported with
    ``joint_elasticity:2`` among its alternatives (not a default candidate of the YAML robots)."""
    first = synthetic_case(kr16, np.random.default_rng(3), ["base_compliance"], mass_spread=0.3)
    (lam,) = detectability(first)
    eff = first.effects[0].with_values(first.effects[0].value_array() * np.sqrt(60.0 / lam))
    case = synthetic_case(kr16, np.random.default_rng(3), [eff], mass_spread=0.3)
    prob = FitProblem(kr16, case.data, 0.02)
    cands = candidate_effects(case.data, prob.tau, robot=kr16)[0] + [fx.Effect("base_compliance")]
    rep = diagnose(kr16, case.data, DiagnosisOptions(sigma_mm=0.02, candidates=tuple(c.name for c in cands)))
    (cause,) = rep.causes
    assert cause["effect"] == "base_compliance"
    assert ("joint_elasticity", 2) in [(a["effect"], a.get("joint")) for a in cause["alternatives"]]
