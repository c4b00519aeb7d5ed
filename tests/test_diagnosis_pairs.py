"""Pairs of candidates that cancel (diagnosis/pairs.py): canonical correlations against a closed
form, the pair bases, the family-wise level of the pair test under "no effect" (Monte Carlo), and the
harness case whose two effects cancel (KR 16 pair seed 124: thermal expansion and tracker drift)."""

import json

import numpy as np
import scipy.stats

from kpioed_drake.diagnosis import pairs as pr
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.estimation import multiplicity as mp
from kpioed_drake.study import synthetic
from kpioed_drake.study.synthetic import RATE_FAMILIES as FAMILIES
from kpioed_drake.study.synthetic import run_synthetic_case


def _unit(v):
    return (v / np.linalg.norm(v))[:, None]


def test_canonical_correlation_of_two_lines_is_the_cosine():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal(50), rng.standard_normal(50)
    cos = abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    np.testing.assert_allclose(pr.canonical_correlation(_unit(a), _unit(b)), cos, rtol=1e-12)
    # a plane holding b: correlation 1 (one line within the plane)
    Q, _ = np.linalg.qr(np.stack([b, a], axis=1))
    np.testing.assert_allclose(pr.canonical_correlation(Q, _unit(b)), 1.0, atol=1e-12)


def test_correlated_pairs_and_their_bases():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(40)
    near = x + 0.3 * rng.standard_normal(40)  # strongly correlated with x
    far = rng.standard_normal(40)
    bases = [_unit(x), _unit(near), _unit(far), _unit(x)]  # the last one: the same span as x
    pairs = pr.correlated_pairs(bases, min_corr=0.5)
    assert [(i, j) for i, j, _ in pairs] == [(0, 1), (1, 3)]  # (0, 3) identical: one test, not a pair
    for B in pr.pair_bases(bases, pairs):
        np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-12)
    r = rng.standard_normal(40)
    B = pr.pair_bases(bases, pairs)[0]
    P = np.concatenate([bases[0], bases[1]], axis=1)
    proj = P @ np.linalg.lstsq(P, r, rcond=None)[0]  # projection on the span of both
    np.testing.assert_allclose(pr.scores([B], r)[0], proj @ proj, rtol=1e-10)


def test_pair_test_holds_its_level_under_no_effect():
    """Monte Carlo: with noise only, the smallest family-wise p-value over correlated pairs falls
    below the level at most at the level's rate (binomial 3 sigma)."""
    rng = np.random.default_rng(2)
    m = 60
    cols = rng.standard_normal((m, 8))
    cols[:, 1] += 1.2 * cols[:, 0]
    cols[:, 3] -= 1.5 * cols[:, 2]
    cols[:, 5] += cols[:, 4] + cols[:, 6]
    bases = [_unit(c) for c in cols.T]
    pairs = pr.correlated_pairs(bases, min_corr=0.5)
    assert len(pairs) >= 3
    joint = pr.pair_bases(bases, pairs)
    null = mp.min_p_null(joint, n_draws=20000, seed=5)
    dof = np.array([B.shape[1] for B in joint])
    level, n = 0.05, 4000
    hits = 0
    for _ in range(n):
        p = scipy.stats.chi2.sf(pr.scores(joint, rng.standard_normal(m)), dof)
        hits += mp.adjusted_p(float(p.min()), null, len(joint)) < level
    assert abs(hits / n - level) < 3 * np.sqrt(level * (1 - level) / n), hits / n


def test_cancelling_pair_is_named(monkeypatch):
    """KR 16 harness pair 124: thermal expansion and tracker drift cancel (LR 6.1 and 9.8 alone on
    the geometric fit, 31.8 together); the forward steps name nothing, the pair step names both,
    and the JSON report says so (the step's pairs, each cause ``added_with`` the other)."""
    reports = []

    def keep(*args, **kwargs):
        reports.append(diagnose(*args, **kwargs))
        return reports[-1]

    monkeypatch.setattr(synthetic, "diagnose", keep)
    r = run_synthetic_case(
        "pair",
        124,
        n_poses=80,
        families=FAMILIES,
        mass_spread=0.3,
        payload=None,
        near_threshold=True,
    )
    assert r["truth_names"] == ["thermal_expansion", "tracker_drift"]
    assert min(r["lambda_given_others"]) >= 25  # each is detectable beside the other
    assert r["named"] == r["truth_names"] and r["explained"]
    assert r["holdout_ext_over_sigma"] < 1.3
    js = json.loads(json.dumps(reports[0].to_json()))
    (step,) = [st for st in js["steps"] if st.get("pair")]
    assert (
        step["added"] == "thermal_expansion + tracker_drift" and step["pairs"][0]["p_value_corrected"] < 1e-3
    )
    with_ = {c["name"]: c["evidence"]["added_with"] for c in js["causes"]}
    assert with_ == {"thermal_expansion": "tracker_drift", "tracker_drift": "thermal_expansion"}
