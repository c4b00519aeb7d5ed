"""Core: models, kinematics vs Drake, derivatives vs finite differences, eq. 19 identities."""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake.errors import InputError
from kpioed_drake.estimation import covariance, criteria
from kpioed_drake.estimation.identifiability import check_identifiability
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.geometry import ClearanceModel, segment_distance
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.models import list_robots, load_cell, load_robot
from kpioed_drake.robot.plant import MM, build_scene
from kpioed_drake.study.authoring import work_target
from kpioed_drake.tracker.feasibility import FeasibilityChecker
from kpioed_drake.tracker.measurement import (
    incidence_cosine,
    kpi_jacobian,
    measure,
    measurement_jacobian,
    nominal_model,
)

ROBOTS = ["kr16", "kr300", "kr500", "notional-650-600", "notional-1100-1000", "notional-850-800"]


def _perturbed(model, rng):
    p = model.p.copy()
    p[:24] += rng.normal(0, 0.01, 24)
    p[24:27] += rng.normal(0, 5, 3)
    p[27:30] = rng.normal(0, 0.2, 3)
    p[30:] += rng.normal(0, 1, 3)
    return model.with_params(p)


@pytest.mark.parametrize("name", ROBOTS)
def test_plant_forward_kinematics_matches_numpy(name):
    robot = load_robot(name)
    scene = build_scene(robot, load_cell(robot=robot))
    rng = np.random.default_rng(1)
    for q in rng.uniform(robot.lower, robot.upper, size=(10, 6)):
        scene.set_q(q)
        fr = forward_kinematics(robot, q)
        for i in range(7):
            X = scene.X_WB(i)
            assert_allclose(X.translation() / MM, fr.o[0, i], rtol=0, atol=1e-9)
            assert_allclose(X.rotation().matrix(), fr.R[0, i], rtol=0, atol=1e-12)


@pytest.mark.slow
def test_every_shipped_robot_has_all_its_parameters_identifiable():
    """27 for every robot of the paper (93); the UR5 and UR10 hold theta5 and alpha5 too (their target
    lies on joint 6's axis), and without that extra gauge they are not identifiable."""
    names = list_robots()
    assert len(names) == 103 and {
        "ur5",
        "ur10",
        "lift7",
        "humanoid11",
        "humanoid18",
        "column8",
        "column_tree",
        "fanuc6",
    } <= set(
        names
    )  # URDF: lift7, column8, humanoid11 and its two-arm twin humanoid18 (each with a truth file)
    for name in names:
        robot = load_robot(name)
        rep = check_identifiability(robot, load_cell(robot=robot), seed=3)
        if robot.urdf is None:
            assert rep.n_candidates == 27 - len(robot.extra_gauge)
        elif name == "lift7":
            assert rep.n_candidates == 29
        assert rep.rank == rep.n_candidates, (name, rep.unidentifiable)
        assert rep.singular_values[-1] > 1e-3, name
    assert load_robot("ur5").extra_gauge == ("theta5", "alpha5")
    ur5 = dataclasses.replace(load_robot("ur5"), extra_gauge=())
    rep = check_identifiability(ur5, load_cell(robot=ur5), seed=3)
    assert rep.n_candidates == 27 and rep.rank == 25 and len(rep.unidentifiable) == 2  # two dependencies


def test_all_33_candidates_have_exactly_six_dependencies():
    robot = load_robot("kr16")
    rep = check_identifiability(robot, load_cell(robot=robot), all_params=True)
    assert rep.n_candidates == 33
    assert rep.rank == 27
    assert rep.singular_values[26] > 1e-3 and rep.singular_values[27] < 1e-10


@pytest.mark.parametrize("name", ["kr16", "notional-850-800"])
def test_measurement_jacobian_matches_finite_differences(name):
    robot = load_robot(name)
    rng = np.random.default_rng(7)
    model = _perturbed(nominal_model(robot, load_cell(robot=robot)), rng)
    q = rng.uniform(robot.lower, robot.upper, size=(6, 6))
    h, H, dH = measurement_jacobian(model, q, with_dq=True)
    assert_allclose(h, measure(model, q), atol=1e-9)
    eps = 1e-6
    Hfd = np.empty_like(H)
    for k in range(33):
        pp, pm = model.p.copy(), model.p.copy()
        pp[k] += eps
        pm[k] -= eps
        Hfd[..., k] = (measure(model.with_params(pp), q) - measure(model.with_params(pm), q)) / (2 * eps)
    assert_allclose(H, Hfd, rtol=0, atol=1e-5 * np.abs(H).max())
    dHfd = np.empty_like(dH)
    for j in range(6):
        qp, qm = q.copy(), q.copy()
        qp[:, j] += eps
        qm[:, j] -= eps
        dHfd[:, j] = (measurement_jacobian(model, qp)[1] - measurement_jacobian(model, qm)[1]) / (2 * eps)
    assert_allclose(dH, dHfd, rtol=0, atol=1e-5 * np.abs(dH).max())


def test_kpi_jacobian_matches_finite_differences():
    robot = load_robot("kr300")
    rng = np.random.default_rng(2)
    model = _perturbed(nominal_model(robot, load_cell(robot=robot)), rng)
    tool = np.array([10.0, -20.0, 50.0])
    s, Js = kpi_jacobian(model, robot.q_work, tool)
    eps = 1e-6
    for k in range(33):
        pp, pm = model.p.copy(), model.p.copy()
        pp[k] += eps
        pm[k] -= eps
        fd = (
            kpi_jacobian(model.with_params(pp), robot.q_work, tool)[0]
            - kpi_jacobian(model.with_params(pm), robot.q_work, tool)[0]
        ) / (2 * eps)
        assert_allclose(Js[:, k], fd, rtol=0, atol=1e-6 * max(1.0, np.abs(Js).max()))
    assert_allclose(Js[:, 24:30], 0.0)  # the tracker does not move the TCP


@pytest.mark.parametrize("name", ["kr16", "kr500"])
def test_clearance_gradient_matches_finite_differences(name):
    robot = load_robot(name)
    cm = ClearanceModel(robot, load_cell(robot=robot))
    rng = np.random.default_rng(5)
    q = rng.uniform(robot.lower, robot.upper, size=(8, 6))
    v, J = cm.evaluate(q)
    assert v.shape == (8, cm.n_rows) and J.shape == (8, cm.n_rows, 6)
    eps = 1e-6
    for j in range(6):
        qp, qm = q.copy(), q.copy()
        qp[:, j] += eps
        qm[:, j] -= eps
        fd = (cm.evaluate(qp)[0] - cm.evaluate(qm)[0]) / (2 * eps)
        assert_allclose(J[:, :, j], fd, rtol=0, atol=1e-4)


def _grid_min(P, s0, s1, t0, t1, m):
    """Min distance over an m x m grid of (s, t) in [s0, s1] x [t0, t1] per pair; and its argmin."""
    u = np.linspace(0, 1, m)
    s = s0[:, None] + u[None, :] * (s1 - s0)[:, None]
    t = t0[:, None] + u[None, :] * (t1 - t0)[:, None]
    A = P[:, None, 0] + s[..., None] * (P[:, None, 1] - P[:, None, 0])
    B = P[:, None, 2] + t[..., None] * (P[:, None, 3] - P[:, None, 2])
    D = np.linalg.norm(A[:, :, None] - B[:, None, :], axis=-1).reshape(len(P), -1)
    k = D.argmin(axis=1)
    return D.min(axis=1), s[np.arange(len(P)), k // m], t[np.arange(len(P)), k % m]


def _brute_segment_distance(P):
    """Grid search over both segment parameters, then a finer grid around the best cell."""
    n, m = len(P), 201
    zero, one = np.zeros(n), np.ones(n)
    _, s, t = _grid_min(P, zero, one, zero, one, m)
    h = 1.0 / (m - 1)
    d, _, _ = _grid_min(
        P, np.clip(s - h, 0, 1), np.clip(s + h, 0, 1), np.clip(t - h, 0, 1), np.clip(t + h, 0, 1), m
    )
    return d


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(11)
    P = rng.normal(0, 100, size=(200, 4, 3))
    P[:20, 3] = P[:20, 2] + 0.5 * (P[:20, 1] - P[:20, 0])  # some parallel pairs
    d, s, t = segment_distance(P[:, 0], P[:, 1], P[:, 2], P[:, 3])
    brute = _brute_segment_distance(P)
    assert np.all(d <= brute + 1e-9)
    assert_allclose(d, brute, rtol=0, atol=1e-3)  # two-level grid: step about 1e-4 of the length
    assert np.all((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1))


@pytest.mark.parametrize("name", ["kr16", "kr500", "notional-700-900"])
def test_numpy_clearances_agree_with_drake_signed_distance(name):
    robot = load_robot(name)
    cell = load_cell(robot=robot)
    cm, fc = ClearanceModel(robot, cell), FeasibilityChecker(robot, cell)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.lower, robot.upper, size=(150, 6))
    v, _ = cm.evaluate(q)
    names = cm.rows.names
    n_compared = 0
    for i in range(len(q)):
        drake = fc.clearances(q[i])
        for key, dv in drake.items():
            if key.startswith("beam"):
                continue
            a, b = key.split(" vs ")
            if b in ("floor", "wall"):
                ours = min(v[i, k] for k, n in enumerate(names) if n in (f"{a}.a vs {b}", f"{a}.b vs {b}"))
            else:
                ours = v[i, names.index(key)]
            # Ours equals brute force (test above); Drake's GJK differs by up to ~0.02 mm near
            # contact (seen: capsule-capsule 0.021 mm at 50 mm). A deep penetration of a box is
            # measured to its nearest face, so compare near contact only.
            if -100.0 < dv < 100.0:
                assert abs(ours - dv) < 0.05, (key, ours, dv)
                n_compared += 1
            if dv < 0:
                assert ours < 0.01, key
    assert n_compared > 100


def test_drake_checks_exactly_the_declared_pairs():
    robot = load_robot("kr16")
    fc = FeasibilityChecker(robot, load_cell(robot=robot))
    keys = {k for k in fc.clearances(robot.q_work) if not k.startswith("beam")}
    caps = {c.name: c.frame for c in robot.capsules}
    expected = set()
    for a, fa in caps.items():
        for b, fb in caps.items():
            if fa < fb and (fa, fb) in robot.self_pairs:
                expected.add(f"{a} vs {b}")
        if fa >= 1:
            for ob in ("floor", "wall", "mount", "car_body", "car_cabin"):
                expected.add(f"{a} vs {ob}")
    assert keys == expected


def test_covariance_forms_agree():
    prob = make_problem("kr16")
    rng = np.random.default_rng(3)
    q = rng.uniform(prob.robot.lower, prob.robot.upper, size=(40, 6))
    F1p, Js = prob.F1(q), prob.Js()
    Cp, Cs = covariance.kpi_covariance(F1p, Js)
    F1, F2 = covariance.kpi_kkt_matrices(F1p, Js)
    Cv_kkt = covariance.kkt_covariance(F1, F2)
    Cv_null = covariance.nullspace_covariance(F1, F2)
    k = F1p.shape[1]
    for Cv in (Cv_kkt, Cv_null):
        assert_allclose(Cv[:k, :k], Cp, rtol=1e-9, atol=1e-9 * np.abs(Cp).max())
        assert_allclose(Cv[k:, k:], Cs, rtol=1e-9, atol=1e-9 * np.abs(Cs).max())
        assert_allclose(Cv[k:, :k], Js @ Cp, rtol=1e-9, atol=1e-9 * np.abs(Js @ Cp).max())


@pytest.mark.parametrize("name", criteria.CRITERIA)
def test_criteria_match_independent_formulas_and_their_adjoint(name):
    prob = make_problem("kr16")
    rng = np.random.default_rng(4)
    q = rng.uniform(prob.robot.lower, prob.robot.upper, size=(30, 6))
    F1, Js, scale = prob.F1(q), prob.Js(), prob.scale
    crit = criteria.resolve(name)
    value, dF1 = crit.evaluate(F1, Js, scale)
    Cp, Cs = covariance.kpi_covariance(F1, Js)
    mu = np.linalg.svd(F1, compute_uv=False)
    expected = {
        "kpi": np.trace(Cs) / 3.0,
        "param": np.trace(np.diag(scale) @ Cp @ np.diag(scale)),
        "d": -np.linalg.slogdet(F1.T @ F1)[1],
        "o1": -np.exp(np.mean(np.log(mu))) / np.sqrt(len(mu)),
    }[name]
    assert_allclose(value, expected, rtol=1e-9)
    assert crit.evaluate(F1, Js, scale, with_grad=False) == value
    # d value / d F1 against central differences, on random entries
    for i, j in zip(rng.integers(0, F1.shape[0], 12), rng.integers(0, F1.shape[1], 12), strict=True):
        h = 1e-7 * np.abs(F1[:, j]).max()  # columns differ in size by 1e4
        Fp, Fm = F1.copy(), F1.copy()
        Fp[i, j] += h
        Fm[i, j] -= h
        fd = (
            crit.evaluate(Fp, Js, scale, with_grad=False) - crit.evaluate(Fm, Js, scale, with_grad=False)
        ) / (2 * h)
        assert_allclose(dF1[i, j], fd, rtol=1e-5, atol=1e-7 * np.abs(dF1).max())
    # information held fixed (M0) is the same as its rows appended to F1
    v_fixed, g_fixed = crit.evaluate(F1[:45], Js, scale, M0=F1[45:].T @ F1[45:])
    assert_allclose(v_fixed, value, rtol=1e-10)
    assert_allclose(g_fixed, dF1[:45], rtol=1e-8, atol=1e-12 * np.abs(dF1).max())


@pytest.mark.parametrize("name", criteria.CRITERIA)
def test_normalised_changes_of_a_criterion_do_not_depend_on_the_noise_level(name):
    """The optimiser's cost scale and the sweeps' stopping test see the same change whatever sigma:
    F1 scales as 1/sigma, which multiplies kpi, param and o1 and shifts d (a log)."""
    prob = make_problem("kr16")
    rng = np.random.default_rng(5)
    Fa, Fb = (prob.F1(rng.uniform(prob.robot.lower, prob.robot.upper, size=(20, 6))) for _ in range(2))
    crit, Js, scale, k = criteria.resolve(name), prob.Js(), prob.scale, prob.n_params
    changes = []
    for c in (1.0, 7.0):  # sigma divided by c
        va, vb = (crit.evaluate(c * F, Js, scale, with_grad=False) for F in (Fa, Fb))
        changes.append((va - vb) / crit.normalisation(va, k))
    assert abs(changes[0]) > 1e-3
    assert_allclose(changes[1], changes[0], rtol=1e-9)


def test_unknown_criterion_is_an_input_error():
    with pytest.raises(InputError, match="unknown criterion 'e-optimal'; expected one of kpi, param, d, o1"):
        criteria.resolve("e-optimal")


def test_working_pose_reaches_the_work_point():
    for name in ["kr16", "kr300", "kr500", "notional-650-600", "notional-1100-1000"]:
        robot = load_robot(name)
        cell = load_cell(robot=robot)
        p = flange_point(forward_kinematics(robot, robot.q_work), cell.p_FQ)[0]
        assert np.linalg.norm(p - work_target(cell)) < 0.2, name
        assert incidence_cosine(nominal_model(robot, cell), robot.q_work)[0] > np.cos(np.deg2rad(30))


def test_unknown_robot_and_bad_model_file(tmp_path):
    with pytest.raises(InputError, match="unknown robot 'kr17'"):
        load_robot("kr17")
    with pytest.raises(InputError, match="unknown robot 'notional-855-800'"):
        load_robot("notional-855-800")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\njoints:\n  - {name: A1, convention: dh, theta_dg: 0}\n")
    with pytest.raises(InputError, match="bad.yaml.*theta_dg"):
        load_robot(str(bad))
    short = tmp_path / "short.yaml"
    short.write_text("name: x\njoints:\n  - {name: A1, convention: dh}\n")
    with pytest.raises(InputError, match="short.yaml.*6 rows"):
        load_robot(str(short))
