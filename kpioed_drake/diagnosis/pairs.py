"""Pairs of candidates that cancel: the joint score test of correlated candidates.

Forward selection tests one candidate at a time. Two effects whose columns are correlated once the
model's span is projected out can cancel each other: each alone leaves a small score, together they
explain much (a *suppressor pair*). Measured on the KR 16 harness, pair seed 124:
``thermal_expansion`` and ``tracker_drift`` (temperature and time both grow over the campaign)
reach LR 6.1 and 9.8 alone and 31.8 together; the forward selection named nothing.

When no single candidate qualifies, :func:`correlated_pairs` lists the pairs of candidates whose
projected bases have a largest canonical correlation of at least
:data:`~kpioed_drake.diagnosis.common.PAIR_CORRELATION` (fixed by the poses, not by the residuals),
and :func:`pair_bases` gives each pair's orthonormal basis ``B`` (the span of both). The score
statistic ``|B^T r|^2`` is chi2(k_a + k_b) under "neither effect"; the selection
(:func:`~kpioed_drake.diagnosis.selection.select_effects`) takes the family-wise p-value over the
pairs by the min-p method (:mod:`~kpioed_drake.estimation.multiplicity`), refits the best pair and
adds both if they pass the same tests as a single candidate.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake.diagnosis.common import PAIR_CORRELATION
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.sides import set_side
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.multiplicity import adjusted_p, min_p_null

MAX_ROWS = 10
"""Pairs listed in a pair step's record (the strongest by score)."""


def canonical_correlation(U_a: np.ndarray, U_b: np.ndarray) -> float:
    """Largest canonical correlation between the spans of two orthonormal bases (m, k_a), (m, k_b)."""
    if not (U_a.shape[1] and U_b.shape[1]):
        return 0.0
    return float(min(1.0, np.linalg.svd(U_a.T @ U_b, compute_uv=False)[0]))


def correlated_pairs(bases: list[np.ndarray], *, min_corr: float) -> list[tuple[int, int, float]]:
    """``(i, j, rho)`` for every pair ``i < j`` of the orthonormal ``bases`` whose largest canonical
    correlation ``rho`` is at least ``min_corr`` and below 1 - 1e-9 (identical spans are one test)."""
    out = []
    for i in range(len(bases)):
        for j in range(i + 1, len(bases)):
            rho = canonical_correlation(bases[i], bases[j])
            if min_corr <= rho < 1.0 - 1e-9:
                out.append((i, j, rho))
    return out


def pair_bases(bases: list[np.ndarray], pairs) -> list[np.ndarray]:
    """Orthonormal basis (m, <= k_a + k_b) of the span of each pair's two bases."""
    out = []
    for i, j, _ in pairs:
        Q, sv, _ = np.linalg.svd(np.concatenate([bases[i], bases[j]], axis=1), full_matrices=False)
        out.append(Q[:, sv > 1e-9 * sv.max()])
    return out


def scores(joint: list[np.ndarray], r: np.ndarray) -> np.ndarray:
    """(n_pairs,) score statistics ``|B^T r|^2`` of the weighted residuals ``r`` (m,)."""
    return np.array([float(np.sum((B.T @ r) ** 2)) for B in joint])


def pair_step(
    prob: FitProblem, current: Fit, tested, r: np.ndarray, *, alpha: float, ln_n: float, k_folds: int
):
    """The joint test of correlated pairs, after a selection step that added nothing.

    Args:
        prob, current: the fit problem and the current model's fit.
        tested: ``(effect, basis, side)`` per identifiable candidate of the step: its orthonormal
            projected basis (m, k) and, for a backlash, the side it was scored with (else None).
        r: (m,) the current weighted residuals.
        alpha: family-wise level over the pairs; ln_n: ``ln(3 n)`` of BIC; k_folds: held-out folds.

    Returns:
        (rows, best): up to :data:`MAX_ROWS` pair records (strongest score first) and the accepted
        pair ``((a, b), row)`` with the refitted ``row["_fit"]`` and held-out ``row["_hold"]``, or
        None: significant (family-wise p < alpha), BIC gain with both members' parameters, each
        member significant given the other (uncorrected p < alpha) and a lower held-out RMS.
    """
    pairs = correlated_pairs([u for _, u, _ in tested], min_corr=PAIR_CORRELATION)
    if not pairs:
        return [], None
    joint = pair_bases([u for _, u, _ in tested], pairs)
    stat = scores(joint, r)
    dof = np.array([B.shape[1] for B in joint])
    p = scipy.stats.chi2.sf(stat, dof)
    m = len(joint)
    null = min_p_null(joint) if p.min() < 2 * alpha else None
    order = np.argsort(-(stat - dof * ln_n))
    rows = []
    for k in order[:MAX_ROWS]:
        i, j, rho = pairs[k]
        rows.append(
            {
                "pair": [tested[i][0].name, tested[j][0].name],
                "canonical_correlation": rho,
                "score": float(stat[k]),
                "dof": int(dof[k]),
                "p_value": float(p[k]),
                "p_value_corrected": adjusted_p(float(p[k]), null, m),
            }
        )
    row = rows[0]
    if row["p_value_corrected"] >= alpha:
        return rows, None
    (a, _, side_a), (b, _, side_b) = tested[pairs[order[0]][0]], tested[pairs[order[0]][1]]
    saved = prob.conditions.side
    for e, side in ((a, side_a), (b, side_b)):
        if side is not None:
            set_side(prob, e.joint, side)
    f = prob.fit(list(current.effects) + [a, b], start=current)
    lr = max(current.cost - f.cost, 0.0)
    k_ab = a.n_params + b.n_params
    given = [max(prob.fit(list(current.effects) + [x], start=current).cost - f.cost, 0.0) for x in (b, a)]
    row.update(
        {
            "lr_stat": lr,
            "p_value": float(scipy.stats.chi2.sf(lr, k_ab)),
            "delta_bic": lr - k_ab * ln_n,
            "lr_given_other": given,
        }
    )
    p_given = [float(scipy.stats.chi2.sf(g, e.n_params)) for g, e in zip(given, (a, b), strict=True)]
    row["p_value_corrected"] = adjusted_p(row["p_value"], null, m)
    if row["p_value_corrected"] >= alpha or row["delta_bic"] <= 0 or max(p_given) >= alpha:
        prob.conditions = dataclasses.replace(prob.conditions, side=saved)
        row["status"] = "not added: not significant once refitted, no BIC gain, or a member not needed"
        return rows, None
    row["_fit"], row["_hold"] = f, prob.holdout(f, k=k_folds)
    row["holdout_rms_mm"] = rms(row["_hold"])
    return rows, ((a, b), row)
