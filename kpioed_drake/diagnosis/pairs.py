"""Pairs of candidates that cancel: the joint score test of correlated candidates.

Forward selection tests one candidate at a time. Two effects whose columns are correlated once the
model's span is projected out can cancel each other: each alone leaves a small score, together they
explain much (a *suppressor pair*), e.g. ``thermal_expansion`` and ``tracker_drift`` when
temperature and time both grow over the campaign; the forward selection then names neither.

When no single candidate qualifies, :func:`correlated_pairs` lists the pairs of candidates whose
projected bases have a largest canonical correlation of at least
:data:`~kpioed_drake.diagnosis.options.PAIR_CORRELATION` (fixed by the poses, not by the residuals),
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

from kpioed_drake.diagnosis.fit import Fit, FitProblem, independent
from kpioed_drake.diagnosis.options import PAIR_CORRELATION
from kpioed_drake.diagnosis.records import PairTest
from kpioed_drake.effects.model import Effect
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


def pair_bases(bases: list[np.ndarray], pairs: list[tuple[int, int, float]]) -> list[np.ndarray]:
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
    prob: FitProblem,
    current: Fit,
    tested: list[tuple[Effect, np.ndarray, np.ndarray | None]],
    r: np.ndarray,
    *,
    alpha: float,
    ln_n: float,
    k_folds: int,
) -> tuple[list[PairTest], PairTest | None, FitProblem]:
    """The joint test of correlated pairs, after a selection step that added nothing.

    Args:
        prob, current: the fit problem and the current model's fit.
        tested: ``(effect, basis, side)`` per identifiable candidate of the step: its orthonormal
            projected basis (m, k) and, for a backlash, the side it was scored with (else None).
        r: (m,) the current weighted residuals.
        alpha: family-wise level over the pairs; ln_n: ``ln(3 n)`` of BIC; k_folds: held-out folds.

    Returns:
        (tests, best, problem): up to :data:`MAX_ROWS` pair tests (strongest score first); the
        accepted pair's test (``tests[0]`` with its refit and held-out residuals) or None; and the
        problem from now on (a refitted pair's backlashes keep the sides they were scored with). A
        pair is accepted when significant (family-wise p < alpha), with a BIC gain with both
        members' parameters, each member significant given the other (uncorrected p < alpha).
    """
    pairs = correlated_pairs([u for _, u, _ in tested], min_corr=PAIR_CORRELATION)
    if not pairs:
        return [], None, prob
    joint = pair_bases([u for _, u, _ in tested], pairs)
    stat = scores(joint, r)
    dof = np.array([B.shape[1] for B in joint])
    p = scipy.stats.chi2.sf(stat, dof)
    m = len(joint)
    null = min_p_null(joint) if p.min() < 2 * alpha else None
    order = np.argsort(-(stat - dof * ln_n))
    tests = [
        PairTest(
            effects=(tested[pairs[k][0]][0], tested[pairs[k][1]][0]),
            canonical_correlation=pairs[k][2],
            score=float(stat[k]),
            dof=int(dof[k]),
            p_value=float(p[k]),
            p_value_corrected=adjusted_p(float(p[k]), null, m),
        )
        for k in order[:MAX_ROWS]
    ]
    if tests[0].p_value_corrected >= alpha:
        return tests, None, prob
    (a, _, side_a), (b, _, side_b) = tested[pairs[order[0]][0]], tested[pairs[order[0]][1]]
    trial = prob
    for e, side in ((a, side_a), (b, side_b)):
        if side is not None:
            trial = trial.with_side(e.joint, side)
    added = ([a, b], [b], [a])  # the pair, then each member alone: independent fits, at once
    f, *alone = independent(
        lambda k: trial.fit(list(current.effects) + added[k], start=current), 3, size=current.J.size
    )
    lr = max(current.cost - f.cost, 0.0)
    k_ab = a.n_params + b.n_params
    given = [max(x.cost - f.cost, 0.0) for x in alone]
    p_lr = float(scipy.stats.chi2.sf(lr, k_ab))
    top = dataclasses.replace(
        tests[0],
        lr_stat=lr,
        p_value=p_lr,
        p_value_corrected=adjusted_p(p_lr, null, m),
        delta_bic=lr - k_ab * ln_n,
        lr_given_other=tuple(given),
    )
    p_given = [float(scipy.stats.chi2.sf(g, e.n_params)) for g, e in zip(given, (a, b), strict=True)]
    if top.p_value_corrected >= alpha or top.delta_bic <= 0 or max(p_given) >= alpha:
        status = "not added: not significant once refitted, no BIC gain, or a member not needed"
        return [dataclasses.replace(top, status=status), *tests[1:]], None, prob
    hold = trial.holdout(f, k=k_folds)
    top = dataclasses.replace(top, fit=f, holdout=hold, holdout_rms_mm=rms(hold))
    return [top, *tests[1:]], top, trial
