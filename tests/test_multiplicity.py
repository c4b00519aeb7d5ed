"""Family-wise p-values of a selection step (min-p over correlated candidates) and the backlash's
side patterns from the mass prior: the min-p law against the closed forms of independent and of
identical candidates, against Bonferroni, the harness cases whose backlash side the file's masses
get wrong (named now, missed with the expected side alone), and a nested alternative."""

import numpy as np
import pytest
import scipy.stats

from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.diagnosis.sides import prior_moments, side_patterns, side_weights, with_expected_sides
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.estimation import multiplicity as mp
from kpioed_drake.study.synthetic import RATE_FAMILIES as FAMILIES
from kpioed_drake.study.synthetic import perturbed_masses, run_synthetic_case, synthetic_case


def _orthonormal(m, k, seed):
    Q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((m, k)))
    return Q


@pytest.mark.parametrize("dofs", [(1,) * 10, (1, 2, 2, 3, 1)])
def test_independent_candidates_give_sidak(dofs):
    """Orthogonal bases: the minimum p of independent uniforms, P(min p <= p) = 1 - (1 - p)^M."""
    Q = _orthonormal(60, sum(dofs), 1)
    cut = np.cumsum((0,) + dofs)
    bases = [Q[:, a:b] for a, b in zip(cut[:-1], cut[1:], strict=True)]
    null = mp.min_p_null(bases, n_draws=40000)
    m = len(dofs)
    for p in (1e-3, 2e-3, 1e-2):
        exact = 1 - (1 - p) ** m
        np.testing.assert_allclose(mp.adjusted_p(p, null, 10**6), exact, rtol=0.1)
    crit = mp.critical_p(0.05, null, m)
    np.testing.assert_allclose(crit, 1 - 0.95 ** (1 / m), rtol=0.05)


def test_identical_candidates_cost_nothing_and_never_more_than_bonferroni():
    """Ten copies of one column are one test: the family-wise p-value is the marginal one, while
    Bonferroni would multiply it by 10; and the adjusted p-value is capped by p * m."""
    u = _orthonormal(40, 1, 2)
    null = mp.min_p_null([u] * 10, n_draws=100000)  # 1000 draws below 0.01: 3 % standard error
    np.testing.assert_allclose(mp.adjusted_p(0.01, null, 10), 0.01, rtol=0.1)
    np.testing.assert_allclose(mp.critical_p(0.01, null, 10), 0.01, rtol=0.1)
    indep = mp.min_p_null([_orthonormal(40, 10, 5)[:, [i]] for i in range(10)])
    assert mp.adjusted_p(0.01, indep, 2) == pytest.approx(0.02)  # capped by Bonferroni's p * m
    assert mp.critical_p(0.01, null, 10) >= 0.01 / 10


def test_min_p_null_is_deterministic_and_monte_carlo_matches_the_level():
    """Same bases, same draws; and a direct simulation of the score statistics of correlated
    candidates (residuals of pure noise) rejects at the adjusted level alpha about alpha of the time."""
    rng = np.random.default_rng(3)
    base = rng.standard_normal((50, 1))
    bases = [np.linalg.qr(base + 0.5 * rng.standard_normal((50, 1)))[0] for _ in range(8)]
    a, b = mp.min_p_null(bases), mp.min_p_null(bases)
    assert np.array_equal(a, b)
    crit = mp.critical_p(0.05, a, len(bases))
    eps = np.random.default_rng(4).standard_normal((20000, 50))
    stats = np.stack([(eps @ u[:, 0]) ** 2 for u in bases], axis=1)
    p_min = scipy.stats.chi2.sf(stats, 1).min(axis=1)
    assert 0.045 < np.mean(p_min <= crit) < 0.055
    assert crit > 0.05 / len(bases) * 1.5  # correlated candidates: clearly less strict than Bonferroni


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_chi2_sf_closed_forms_match_scipy(k):
    """The null draws' chi-square survival function equals scipy's, also far in the tail."""
    x = np.concatenate([np.random.default_rng(k).chisquare(k, 2000) * 3, [0.0, 1e-9, 50.0, 300.0]])
    np.testing.assert_allclose(mp.chi2_sf(x, k), scipy.stats.chi2.sf(x, k), rtol=1e-11, atol=0)


def test_weighted_min_p_holds_its_level_and_matches_weighted_sidak():
    """Weighted min-p (weights 3, 1, 1, 1, 1, 1 over independent candidates): a candidate of weight
    w is rejected at p <= t w with P(any) = 1 - prod(1 - t w_c), and a direct simulation of
    correlated candidates with weights rejects at the adjusted level about alpha of the time."""
    Q = _orthonormal(60, 6, 7)
    bases = [Q[:, [i]] for i in range(6)]
    raw = [3.0, 1, 1, 1, 1, 1]
    w = mp.normalized(raw, 6)
    np.testing.assert_allclose(w.mean(), 1.0)
    null = mp.min_p_null(bases, weights=raw, n_draws=40000)
    for i in (0, 3):
        p = 2e-3
        t = p / w[i]
        exact = 1 - np.prod(1 - np.minimum(t * w, 1))
        np.testing.assert_allclose(mp.adjusted_p(p, null, 10**6, weight=w[i]), exact, rtol=0.1)
    # the heavier candidate needs a p-value three times larger than the others for the same level
    crit = [mp.critical_p(0.05, null, 6, weight=w[i]) for i in (0, 1)]
    np.testing.assert_allclose(crit[0] / crit[1], 3.0, rtol=1e-12)
    rng = np.random.default_rng(8)
    base = rng.standard_normal((50, 1))
    corr = [np.linalg.qr(base + 0.5 * rng.standard_normal((50, 1)))[0] for _ in range(8)]
    raw = [4.0, 1, 1, 1, 0.25, 0.25, 0.25, 0.25]
    w = mp.normalized(raw, 8)
    null = mp.min_p_null(corr, weights=raw)
    eps = np.random.default_rng(9).standard_normal((20000, 50))
    stats = np.stack([(eps @ u[:, 0]) ** 2 for u in corr], axis=1)
    p = scipy.stats.chi2.sf(stats, 1)
    t = mp.critical_p(0.05, null, 8, weight=1.0)  # p_c <= t w_c for some c
    assert 0.045 < np.mean(np.any(p <= t * w, axis=1)) < 0.055
    with pytest.raises(ValueError, match="positive"):
        mp.normalized([1.0, 0.0], 2)


def test_side_weights_give_the_expected_side_one_test_and_the_other_sides_one():
    """Sides of one backlash: the expected side weight 1 like any candidate; identical other sides
    are one test together (weight 1 each), independent ones share weight 1 by their number."""
    u = _orthonormal(40, 6, 3)
    assert np.array_equal(side_weights([u[:, [0]]]), [1.0])
    same = side_weights([u[:, [0]]] + [u[:, [1]]] * 5)
    np.testing.assert_allclose(same, [1.0] * 6, rtol=0.1)
    indep = side_weights([u[:, [i]] for i in range(6)])
    # Sidak's 5 independent tests at 1 %: 4.98; the 1 % quantile of 10 000 draws (100 below it)
    # has a relative standard error of about 10 %: 2.5 of them
    np.testing.assert_allclose(indep[0], 1.0)
    np.testing.assert_allclose(indep[1:], 1.0 / (0.01 / (1 - 0.99 ** (1 / 5))), rtol=0.25)


def uniform_prior_moments(masses, coms, spread):
    """Closed-form mean and std (L, 4) of ``m, m c_x, m c_y, m c_z`` when ``m = m0 (1 + a)`` and
    ``c = c0 + d r`` (``r`` the centre-of-mass scale), ``a, d ~ U(-spread, spread)`` independent:
    ``E[m c] = m0 c0``, ``E[(m c)^2] = m0^2 (1 + spread^2 / 3) (c0^2 + r^2 spread^2 / 3)``."""
    v = spread**2 / 3.0  # variance of U(-spread, spread)
    r = gb.com_scales(coms)[:, None]
    m0 = masses[:, None]
    mean = np.concatenate([m0, m0 * coms], axis=1)
    second = np.concatenate([m0**2 * (1 + v), m0**2 * (1 + v) * (coms**2 + r**2 * v)], axis=1)
    return mean, np.sqrt(second - mean**2)


@pytest.mark.parametrize("joint", [4, 2])
def test_prior_moments_have_the_closed_form_moments_of_the_uniform_prior(kr16, joint):
    """The prior draws of the link moments and the harness's perturbed masses (``mass_spread`` 0.3)
    both have the mean and spread of independent +-MASS_PRIOR_SPREAD uniform errors (closed form; 4
    standard errors on the means, 5 % on the stds), and the masses stay within the +-30 %."""
    assert gb.MASS_PRIOR_SPREAD == 0.3
    ks = np.arange(joint, kr16.n_joints + 1)
    mean, std = uniform_prior_moments(kr16.masses[ks], kr16.coms[ks], 0.3)
    mean, std = mean.reshape(-1), std.reshape(-1)
    n = 20000
    draws = prior_moments(kr16, joint, np.random.default_rng(0), n)
    rng = np.random.default_rng(1)
    harness = np.array([gb.link_moments(perturbed_masses(kr16, rng, 0.3), joint) for _ in range(n // 5)])
    for sample in (draws, harness):
        se = std / np.sqrt(len(sample))
        assert np.all(np.abs(sample.mean(axis=0) - mean) < 4 * se + 1e-12 * np.abs(mean))
        np.testing.assert_allclose(sample.std(axis=0), std, rtol=0.05)
        m = sample[:, ::4]
        assert np.all(m >= 0.7 * kr16.masses[ks] - 1e-12) and np.all(m <= 1.3 * kr16.masses[ks] + 1e-12)
        assert np.all(m.max(axis=0) > 1.29 * kr16.masses[ks])  # the whole range, not a narrower one


def test_side_patterns_hold_the_expected_side_and_the_true_one(kr16):
    """Row 0 is the expected side; on a robot whose masses are off, some prior pattern is closer to
    the true side than the file's sign (single/backlash seed 40: the file's torque puts poses on the
    wrong side of joint 6)."""
    rng = np.random.default_rng(11)
    case = synthetic_case(kr16, rng, [], n_poses=60, mass_spread=0.3)
    prob = with_expected_sides(FitProblem(kr16, case.data, 0.02))
    pats = side_patterns(prob, [4, 6])
    true_tau = FitProblem(case.model_true.robot, case.data, 0.02).tau
    for j, P in pats.items():
        np.testing.assert_array_equal(P[0], prob.conditions.side[:, j - 1])
        assert np.all(np.abs(P[1:]) == 1.0) and P.shape[1] == case.data.n
        truth = np.sign(true_tau[:, j - 1])
        wrong = [min(np.sum(p != truth), np.sum(p != -truth)) for p in P[1:]]
        file_wrong = min(np.sum(np.sign(prob.tau[:, j - 1]) != t) for t in (truth, -truth))
        assert min(wrong) <= file_wrong


@pytest.mark.parametrize("seed, joint", [(12, 6), (40, 6)])
def test_backlash_named_when_the_file_masses_get_the_side_wrong(seed, joint):
    """Harness cases (single/backlash, masses +-30 % off, near the threshold) that the expected side
    alone missed (its column kept lambda 8 of 27 and 44): named with a side from the mass prior."""
    rec = run_synthetic_case(
        "single",
        seed,
        "kr16",
        families=("backlash",),
        mass_spread=0.3,
        payload="changes" if seed % 2 else None,
        near_threshold=True,
    )
    assert rec["truth_names"] == [f"backlash:{joint}"] and rec["lambda"][0] > 25
    assert rec["named"] == [f"backlash:{joint}"] and rec["holdout_ext_over_sigma"] < 1.3


def test_nested_alternative_when_one_cause_holds_another():
    """Harness case pair/73: hidden joint_scale:2 (lambda 84) and gear_cyclic:2:1 (lambda 34). The
    first harmonic of joint 2 holds 99.5 % of the scale error's signature (joint 2 turns over part of
    a circle), so gear_cyclic:2:1 alone fits to the noise level; joint_scale:2 is significant alone
    and listed as a nested alternative: the data cannot tell whether it is present as well."""
    rec = run_synthetic_case(
        "pair", 73, "kr16", families=FAMILIES, mass_spread=0.3, payload="changes", near_threshold=True
    )
    assert rec["truth_names"] == ["gear_cyclic:2:1", "joint_scale:2"]
    assert rec["named"] == ["gear_cyclic:2:1"]
    assert "joint_scale:2" in rec["alternatives"][0] and rec["explained"]
    assert rec["chi2_per_dof_ext"] < 1.2
