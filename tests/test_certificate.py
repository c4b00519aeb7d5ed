"""The optimality certificate and the approximate design (issue 14, items 1 and 2)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kpioed_drake.design import check_design, heuristic_design, settings
from kpioed_drake.design.approximate import certcache, certificate, search
from kpioed_drake.design.approximate import design as column_generation
from kpioed_drake.design.approximate.certificate import (
    certified_design,
    certify,
    pool_certificate,
    verify_search,
)
from kpioed_drake.design.approximate.design import (
    approximate_design,
    approximate_start,
    efficient_rounding,
    exchange_counts,
    kpi_factor,
    rank3_changes,
    replicate_poses,
)
from kpioed_drake.design.approximate.pool import l_criterion
from kpioed_drake.design.approximate.search import (
    DualObjective,
    corner_poses,
    dual_values,
    maximize_dual,
    pose_rows,
    search_batch,
)
from kpioed_drake.estimation.problem import make_problem


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16")


def _search_settings(monkeypatch, *, pool: int, starts: int, certify_rounds: int, verify_rounds: int) -> None:
    """A smaller certificate search for one test: its pool, starts and rounds."""
    monkeypatch.setattr(certificate, "VERIFY_POOL", pool)
    monkeypatch.setattr(certificate, "VERIFY_STARTS", starts)
    monkeypatch.setattr(certificate, "CERTIFY_ROUNDS", certify_rounds)
    monkeypatch.setattr(certificate, "VERIFY_ROUNDS", verify_rounds)


@pytest.fixture(scope="module")
def pool(kr16):
    return heuristic_design(kr16, n=300, seed=3, margin_mm=0.0)


@pytest.fixture(scope="module")
def small_approx(kr16):
    return approximate_design(kr16, seed=0, max_rounds=2, pool=200, starts=8, random_starts=4)


def _kpi(problem, q) -> float:
    return problem.criteria(q)["kpi_avg_var_mm2"]


def test_pool_certificate_dual_and_equivalence_theorem_hold_to_1e6(kr16, pool):
    cert = pool_certificate(kr16, pool)
    F = pose_rows(kr16, pool)
    assert dual_values(F, cert.Y).max() == pytest.approx(1.0, abs=1e-12)  # Y is dual feasible
    assert cert.dual <= cert.phi
    assert 0.0 <= cert.dual_gap < 1e-9  # measured 2e-12 to 5e-11
    assert abs(cert.equivalence_gap) < 1e-6  # max_x d(x, w*) = Phi(w*) at the pool optimum
    assert cert.equivalence <= cert.phi
    assert cert.w.sum() == pytest.approx(1.0) and np.all(cert.w >= 0)
    assert cert.phi == pytest.approx(l_criterion(F, cert.w, kpi_factor(kr16))[0], rel=1e-12)


def test_pool_bound_is_below_every_design_from_the_pool(kr16, pool):
    cert = pool_certificate(kr16, pool)
    rng = np.random.default_rng(0)
    for n in (10, 20, 60, 150):
        for _ in range(5):
            q = pool[rng.choice(len(pool), size=n, replace=True)]
            assert cert.dual / n <= _kpi(kr16, q)
    # and below every approximate design on the pool
    F, K = pose_rows(kr16, pool), kpi_factor(kr16)
    for _ in range(20):
        w = rng.dirichlet(np.full(len(pool), 0.3))
        assert cert.dual <= l_criterion(F, w, K)[0]


def test_bound_with_any_dual_matrix_is_below_the_design_value(kr16):
    # tr(Cs)/3 >= tr(K^T Y)^2 / (n max_i ||F_i Y||^2) for every Y and every design (module proof)
    rng = np.random.default_rng(1)
    K = kpi_factor(kr16)
    for n in (9, 30, 60):
        q = rng.uniform(kr16.robot.lower, kr16.robot.upper, size=(n, 6))
        value = _kpi(kr16, q)
        F = pose_rows(kr16, q)
        for _ in range(10):
            Y = rng.normal(size=K.shape)
            assert np.sum(K * Y) ** 2 / (n * dual_values(F, Y).max()) <= value * (1 + 1e-12)
        # the equivalence-theorem choice Y = M^-1 K of the design itself: Phi^2 / (n max d) <= Phi / n
        phi, X = l_criterion(F, np.full(n, 1.0 / n), K)
        assert phi / n == pytest.approx(value, rel=1e-10)
        assert np.sum(K * X) ** 2 / (n * dual_values(F, X).max()) <= value * (1 + 1e-12)


def test_dual_objective_gradient_matches_central_differences(kr16):
    rng = np.random.default_rng(2)
    q = rng.uniform(kr16.robot.lower, kr16.robot.upper, size=(4, 6))
    obj = DualObjective(kr16, rng.normal(size=kpi_factor(kr16).shape))
    value, grad = obj.value_and_grad(q)
    assert value == pytest.approx(obj.value(q), rel=1e-12)
    h = 1e-6
    fd = np.zeros_like(q)
    for i in range(q.shape[0]):
        for j in range(6):
            e = np.zeros_like(q)
            e[i, j] = h
            fd[i, j] = (obj.value(q + e) - obj.value(q - e)) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


def test_local_maximisation_raises_g_and_stays_feasible(kr16, pool):
    cert = pool_certificate(kr16, pool)
    starts = pool[np.argsort(-dual_values(pose_rows(kr16, pool), cert.Y))[:8]]
    q, g, ok = maximize_dual(kr16, starts, cert.Y)
    g0 = dual_values(pose_rows(kr16, starts), cert.Y)
    assert ok.sum() >= 6
    assert np.all(g[ok] >= g0[ok] - 1e-9)
    assert g[ok].max() > 1.0  # the pool optimum is not optimal over the continuous feasible set
    _, n_bad, _ = check_design(kr16, q[ok])
    assert n_bad == 0


def test_efficient_rounding_sums_to_n_and_is_an_efficient_apportionment():
    rng = np.random.default_rng(4)
    for n in (7, 30, 60, 61):
        w = rng.dirichlet(np.ones(25))
        w[rng.choice(25, 5, replace=False)] = 0.0
        w /= w.sum()
        c = efficient_rounding(w, n)
        assert c.sum() == n and np.all(c >= 0) and np.all(c[w == 0] == 0)
        sup = (w > 0) & (c > 0)
        # multiplier property of efficient apportionment: max (c_i - 1)/w_i <= min c_j/w_j
        assert np.max((c[sup] - 1) / w[sup]) <= np.min(c[w > 0] / w[w > 0]) + 1e-12
    np.testing.assert_array_equal(efficient_rounding(np.array([0.5, 0.3, 0.2]), 10), [5, 3, 2])


def test_replicated_poses_are_the_same_configuration(kr16, pool):
    q = replicate_poses(kr16, pool[:3], np.array([3, 0, 2]))
    assert q.shape == (5, 6)
    assert np.all(q >= kr16.robot.lower) and np.all(q <= kr16.robot.upper)
    F = pose_rows(kr16, q)
    np.testing.assert_allclose(F[:3], np.repeat(pose_rows(kr16, pool[:1]), 3, axis=0), atol=1e-9)
    np.testing.assert_allclose(F[3:], np.repeat(pose_rows(kr16, pool[2:3]), 2, axis=0), atol=1e-9)


def test_certificate_of_designs_is_below_their_values(kr16, small_approx):
    a = small_approx
    assert a.dual / a.g_max <= a.phi and a.g_max >= 1.0
    for seed in range(3):
        for n in (20, 60):
            q = heuristic_design(kr16, n=n, seed=seed)
            c = certify(kr16, q, approx=a, refinements=0)
            assert c["bound_mm2"] <= c["value_mm2"] and 0 < c["efficiency"] <= 1
            assert c["value_mm2"] == pytest.approx(_kpi(kr16, q), rel=1e-12)
            assert c["bound_mm2"] * n <= a.phi and c["n_candidates"] == len(a.q) + n + 8
            assert c["bound_mm2"] <= c["search_bound_mm2"] * (1 + 1e-12)
            assert c["bound_mm2"] == pytest.approx(
                c["search_bound_mm2"] / max(1.0, c["design_beyond_search"])
            )
    # the approximate design's own rounding: a design of candidates, so bound <= its value
    q0 = approximate_start(kr16, n=60, approx=a)
    assert q0.shape == (60, 6)
    c = certify(kr16, q0, approx=a, refinements=0)
    assert c["bound_mm2"] <= c["value_mm2"]
    assert c["value_mm2"] < _kpi(kr16, heuristic_design(kr16, n=60, seed=0))
    _, n_bad, _ = check_design(kr16, q0)
    assert n_bad == 0
    with pytest.raises(ValueError, match="collision"):
        certify(kr16, q0, approx=a, collision=False)


def test_verify_search_and_certified_design_continue_the_column_generation(kr16, small_approx, monkeypatch):
    a = small_approx
    checked, found = verify_search(kr16, a, seed=7)
    assert checked.g_max >= a.g_max and checked.n_checked >= certificate.VERIFY_POOL
    assert checked.bound <= a.bound and np.all(checked.Y == a.Y)
    if len(found):
        assert np.all(dual_values(pose_rows(kr16, found), a.Y) > 1.0) and not checked.converged
    _search_settings(monkeypatch, pool=300, starts=8, certify_rounds=1, verify_rounds=2)
    cert = certified_design(kr16, seed=5, warm=a)
    assert cert is certified_design(kr16, seed=5)  # cached per problem object and seed
    assert cert.rounds > a.rounds and cert.n_checked >= 300
    assert cert.bound <= cert.phi <= a.phi * (1 + 1e-9)  # more candidates: no worse
    c = certify(kr16, heuristic_design(kr16, n=60, seed=0), seed=5, refinements=0)
    assert c["n_candidates"] == len(cert.q) + cert.n_checked + 68 and c["efficiency"] <= 1


def test_corner_poses_put_joints_at_limits_and_are_feasible(kr16, pool):
    q = corner_poses(kr16, pool, seed=1)
    lo, up = kr16.robot.lower, kr16.robot.upper
    at_limit = np.isclose(q, lo) | np.isclose(q, up)
    assert len(q) > 30 and np.all(at_limit.any(axis=1))
    assert 0.2 < at_limit.mean() < 0.45  # each joint with probability 1/3
    _, n_bad, _ = check_design(kr16, q)
    assert n_bad == 0


def test_certify_continues_the_search_with_poses_found_near_the_design(kr16, small_approx, monkeypatch):
    for name, value in (("VERIFY_POOL", 300), ("VERIFY_STARTS", 8), ("CERTIFY_ROUNDS", 2)):
        monkeypatch.setattr(certificate, name, value)
    q0 = approximate_start(kr16, n=40, approx=small_approx)
    # the rounded design's poses are candidates: nothing beyond the search, nothing to refine
    plain = certify(kr16, q0, approx=small_approx, refinements=0)
    assert plain["design_beyond_search"] <= 1.0 + certificate.ROUND_TOL
    assert certify(kr16, q0, approx=small_approx)["bound_mm2"] == plain["bound_mm2"]
    # a "search" of the candidates alone (g_max = 1): local maxima from the design's poses go beyond
    weak = dataclasses.replace(small_approx, g_max=1.0)
    plain = certify(kr16, q0, approx=weak, refinements=0)
    refined = certify(kr16, q0, approx=weak, refinements=2)
    assert plain["refinements"] == 0 and plain["design_beyond_search"] > 2.0  # measured 2.72
    assert 1 <= refined["refinements"] <= 2
    assert refined["rounds"] > plain["rounds"] and refined["n_candidates"] > plain["n_candidates"]
    assert refined["design_beyond_search"] < plain["design_beyond_search"]
    assert plain["bound_mm2"] < refined["bound_mm2"] <= refined["value_mm2"] == plain["value_mm2"]
    assert 0 < refined["efficiency"] <= 1
    assert weak.g_max == 1.0 and len(weak.q) == len(small_approx.q)  # the caller's design is unchanged


def test_a_large_design_is_refined_only_below_the_efficiency_gate(kr16, small_approx, monkeypatch):
    for name, value in (("VERIFY_POOL", 300), ("VERIFY_STARTS", 8), ("CERTIFY_ROUNDS", 2)):
        monkeypatch.setattr(certificate, name, value)
    q0 = approximate_start(kr16, n=40, approx=small_approx)
    weak = dataclasses.replace(small_approx, g_max=1.0)  # the design's poses reach beyond it
    plain = certify(kr16, q0, approx=weak, refinements=0)
    monkeypatch.setattr(certificate, "REFINE_BELOW_EFFICIENCY", 0.5 * plain["efficiency"])
    # a six-joint 40-pose design (240 joint variables) is small: refined whatever its efficiency
    assert certify(kr16, q0, approx=weak)["refinements"] >= 1
    # counted as large (as the 18-joint twin's 720 variables are), its bound is kept
    monkeypatch.setattr(settings, "LARGE_SOLVE_VARIABLES", 100)
    large = certify(kr16, q0, approx=weak)
    assert large["refinements"] == 0 and large["bound_mm2"] == plain["bound_mm2"]
    monkeypatch.setattr(certificate, "REFINE_BELOW_EFFICIENCY", 2.0 * plain["efficiency"])
    assert certify(kr16, q0, approx=weak)["refinements"] >= 1


@pytest.mark.parametrize("robot", ["kr16", "notional-850-800"])
def test_bound_with_given_poses_is_below_the_combined_design_value(robot):
    # tr(K^T (M0 + M)^-1 K) >= tr(K^T Y)^2 / (n max_i ||F_i Y||^2 + ||F0 Y||^2) for every Y
    problem = make_problem(robot)
    rng = np.random.default_rng(11)
    K = kpi_factor(problem)
    for seed in range(3):
        given = rng.uniform(problem.robot.lower, problem.robot.upper, size=(10 + 10 * seed, 6))
        for n in (3, 12, 40):
            q = rng.uniform(problem.robot.lower, problem.robot.upper, size=(n, 6))
            value = _kpi(problem, np.concatenate([given, q]))
            F, GY = pose_rows(problem, q), None
            for _ in range(8):
                Y = rng.normal(size=K.shape)
                GY = pose_rows(problem, given) @ Y
                bound = np.sum(K * Y) ** 2 / (n * dual_values(F, Y).max() + np.sum(GY * GY))
                assert bound <= value * (1 + 1e-12)
                if n < problem.min_poses():
                    continue
                # without given poses the plain bound holds for the new poses alone
                assert np.sum(K * Y) ** 2 / (n * dual_values(F, Y).max()) <= _kpi(problem, q) * (1 + 1e-12)


def test_certify_with_given_poses_bounds_the_combined_design(kr16, small_approx):
    given = heuristic_design(kr16, n=25, seed=4)
    q = heuristic_design(kr16, n=10, seed=5)
    c = certify(kr16, q, approx=small_approx, refinements=0, given=given)
    both = _kpi(kr16, np.concatenate([given, q]))
    assert c["value_mm2"] == pytest.approx(both, rel=1e-12) and c["n_given"] == 25
    assert 0 < c["bound_mm2"] <= both and c["efficiency"] == pytest.approx(c["bound_mm2"] / both)
    # the given information only adds to the denominator: below the bound of the new poses alone
    alone = certify(kr16, q, approx=small_approx, refinements=0)
    assert c["bound_mm2"] < alone["bound_mm2"] and alone["n_given"] == 0


def test_exchange_never_raises_the_criterion_and_its_updates_are_exact(kr16, small_approx):
    a = small_approx
    F, K = a.F, kpi_factor(kr16)
    G = F.transpose(0, 2, 1) @ F
    for n in (20, 60):
        c0 = efficient_rounding(a.w, n)
        M = np.einsum("i,ikl->kl", c0, G)
        phi0 = np.sum(K * np.linalg.solve(M, K))
        # the rank-3 updates equal the criterion recomputed after adding / removing one copy
        add = rank3_changes(F, M, K, 1.0)
        rem = rank3_changes(F, M, K, -1.0)
        for i in np.flatnonzero(c0)[:5]:
            assert phi0 - np.sum(K * np.linalg.solve(M + G[i], K)) == pytest.approx(add[i], rel=1e-7)
            assert np.sum(K * np.linalg.solve(M - G[i], K)) - phi0 == pytest.approx(rem[i], rel=1e-6)
        c1 = exchange_counts(F, K, c0)
        assert c1.sum() == n and np.all(c1 >= 0)
        phi1 = np.sum(K * np.linalg.solve(np.einsum("i,ikl->kl", c1, G), K))
        assert phi1 <= phi0 and n * phi1 >= a.bound * (1 - 1e-9)  # never below the dual bound
    # the approximate start uses it: its value is the exchanged counts'
    q0 = approximate_start(kr16, n=60, approx=a)
    c1 = exchange_counts(F, K, efficient_rounding(a.w, 60))
    assert _kpi(kr16, q0) == pytest.approx(np.sum(K * np.linalg.solve(np.einsum("i,ikl->kl", c1, G), K)))


def test_local_searches_per_solve_and_the_settings_in_the_cache_key(monkeypatch):
    """About 48 joint variables per SNOPT solve: 8 starts of a six-joint robot, 2 of the twin."""
    assert [search_batch(nj) for nj in (6, 7, 11, 18, 60)] == [8, 6, 4, 2, 1]
    # per column-generation round: 24 starts of six joints (8 random), 12 of the twin (4 random)
    assert [search.round_starts(nj) for nj in (6, 7, 18)] == [(24, 8), (20, 6), (12, 4)]
    base = certificate.search_settings()
    for module, name, value in (
        (search, "SEARCH_VARIABLES", 24),
        (search, "SEARCH_OPTIONS", {**search.SEARCH_OPTIONS, "Major optimality tolerance": 1e-4}),
        (search, "ROUND_VARIABLES", 72),
        (column_generation, "WORKING_POSES", 100),
        (certificate, "VERIFY_POOL", 100),
    ):
        with monkeypatch.context() as m:
            m.setattr(module, name, value)
            assert certificate.search_settings() != base, name
    assert certificate.search_settings() == base


def test_disk_cache_of_the_certificate_search(kr16, small_approx, tmp_path, monkeypatch):
    monkeypatch.setenv("KPIOED_CACHE", str(tmp_path))
    key = certcache.problem_key(kr16, collision=True, seed=0, settings={"a": 1})
    assert certcache.load(key) is None
    path = certcache.store(key, small_approx)
    assert path.parent == tmp_path and path.is_file()
    back = certcache.load(key)
    for f in dataclasses.fields(small_approx):
        x, y = getattr(back, f.name), getattr(small_approx, f.name)
        assert type(x) is type(y) or isinstance(x, np.ndarray)
        np.testing.assert_array_equal(x, y)
    # every input of the search changes the key
    other = [
        certcache.problem_key(kr16, collision=False, seed=0, settings={"a": 1}),
        certcache.problem_key(kr16, collision=True, seed=1, settings={"a": 1}),
        certcache.problem_key(kr16, collision=True, seed=0, settings={"a": 2}),
        certcache.problem_key(make_problem("kr16", sigma_mm=0.5), collision=True, seed=0, settings={"a": 1}),
        certcache.problem_key(make_problem("kr300"), collision=True, seed=0, settings={"a": 1}),
    ]
    assert len({key, *other}) == 6
    assert key == certcache.problem_key(make_problem("kr16"), collision=True, seed=0, settings={"a": 1})
    # a damaged file is not read (the search runs again); "off" disables the cache
    path.write_bytes(b"not an npz")
    assert certcache.load(key) is None
    monkeypatch.setenv("KPIOED_CACHE", "off")
    assert certcache.cache_dir() is None and certcache.store(key, small_approx) is None
    assert certcache.load(key) is None


@pytest.fixture
def small_search_cached_in(tmp_path, monkeypatch):
    """A short certificate search whose disk cache is ``tmp_path``."""
    monkeypatch.setenv("KPIOED_CACHE", str(tmp_path))
    _search_settings(monkeypatch, pool=200, starts=4, certify_rounds=1, verify_rounds=1)
    return tmp_path


def test_certified_design_is_read_back_from_the_disk_cache(kr16, small_search_cached_in):
    tmp_path = small_search_cached_in
    first = certified_design(kr16, seed=9)
    assert len(list(tmp_path.glob("certificate-*.npz"))) == 1
    fresh = make_problem("kr16")  # another problem object: not in the memory cache
    again = certified_design(fresh, seed=9)
    assert again is not first and again.bound == first.bound and np.array_equal(again.Y, first.Y)
    # the same memory layout as a loaded design: later sums (a refinement) give the same bits
    for f in dataclasses.fields(first):
        x, y = getattr(first, f.name), getattr(again, f.name)
        if isinstance(x, np.ndarray):
            assert x.flags["C_CONTIGUOUS"] and y.flags["C_CONTIGUOUS"], f.name
            np.testing.assert_array_equal(x, y)


def test_the_search_of_another_noise_is_the_unit_noise_search_scaled(small_search_cached_in):
    tmp_path = small_search_cached_in
    unit, noisy = make_problem("kr16", sigma_mm=1.0), make_problem("kr16", sigma_mm=0.3)
    a, b = certified_design(unit, seed=2), certified_design(noisy, seed=2)
    assert len(list(tmp_path.glob("certificate-*.npz"))) == 1  # one search for both
    np.testing.assert_allclose(b.F, pose_rows(noisy, b.q), rtol=1e-12)
    np.testing.assert_allclose(dual_values(b.F, b.Y), dual_values(a.F, a.Y), rtol=1e-10)
    assert b.bound == pytest.approx(0.09 * a.bound, rel=1e-12) and b.g_max == a.g_max
    q = heuristic_design(noisy, n=20, seed=1)
    c_noisy, c_unit = certify(noisy, q, seed=2, refinements=0), certify(unit, q, seed=2, refinements=0)
    assert c_noisy["efficiency"] == pytest.approx(c_unit["efficiency"], rel=1e-9)
    assert c_noisy["bound_mm2"] <= c_noisy["value_mm2"]
