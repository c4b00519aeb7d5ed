"""Family-wise p-values of a selection step: the min-p method over correlated candidates.

A selection step tests every candidate effect against the same residuals and adds the best one, so
its level must hold for the *smallest* p-value over the candidates. Bonferroni (``p * m``) assumes
the worst case; the candidates' columns are strongly correlated (the elasticity and the backlash of
one joint, the harmonics and the scale of one gear), so it is conservative and costs power near the
detection threshold. The single-step min-p method (Westfall and Young 1993, *Resampling-Based
Multiple Testing*, algorithm 2.8) gives the exact family-wise p-value instead.

Under "no effect" the weighted residuals of the current fit are ``r = (I - P) eps`` with
``eps ~ N(0, I)`` and P the projector on the model's columns. Candidate c's score statistic is
``|U_c^T r|^2 = |U_c^T eps|^2`` with ``U_c`` (m, k_c) the orthonormal basis of its columns outside
the model's span (:func:`~kpioed_drake.diagnosis.selection.projected_basis`), a chi-square(k_c)
variable; jointly, the stacked ``g = [U_1 ... U_M]^T eps`` is Gaussian with covariance
``G = W^T W = R^T R`` (``W`` the stacked bases, ``R`` its QR factor). :func:`min_p_null` draws
``g = xi R`` (``xi ~ N(0, I)``, seeded: the same data give the same decision), the p-value of each
block from its chi-square law, and their minimum; a candidate's family-wise p-value is the share of
draws whose minimum is at most its own p-value (:func:`adjusted_p`), never more than Bonferroni's.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

N_DRAWS = 10000
"""Monte Carlo draws of the null minimum p-value (resolution 1e-4; at a level of 0.01 the relative
standard error of the adjusted p-value is 10 %)."""
SEED = 20170601
"""Seed of the draws (fixed: a diagnosis is deterministic)."""


def min_p_null(bases, *, n_draws: int = N_DRAWS, seed: int = SEED) -> np.ndarray:
    """(n_draws,) sorted null minimum p-values over candidates with orthonormal bases ``bases``.

    Args:
        bases: list of (m, k_c) orthonormal bases (the part of each candidate's weighted columns
            outside the model's span); k_c >= 1.
        n_draws: Monte Carlo draws.
        seed: their seed.
    """
    W = np.concatenate(bases, axis=1)
    R = np.linalg.qr(W, mode="r")  # W^T W = R^T R: g = xi R with xi ~ N(0, I)
    g = np.random.default_rng(seed).standard_normal((n_draws, R.shape[0])) @ R
    ks = np.array([U.shape[1] for U in bases])
    stat = np.add.reduceat(g**2, np.concatenate([[0], np.cumsum(ks)[:-1]]), axis=1)  # |g_c|^2
    # the smallest p-value of the candidates with k degrees of freedom is that of their largest statistic
    logp = [scipy.stats.chi2.logsf(np.max(stat[:, ks == k], axis=1), k) for k in np.unique(ks)]
    return np.sort(np.exp(np.min(logp, axis=0)))


def adjusted_p(p: float, null_min_p: np.ndarray | None, m: int) -> float:
    """Family-wise p-value of a candidate with marginal p-value ``p``: the share of null minima at or
    below it (:func:`min_p_null`, sorted), at least ``p`` and at most Bonferroni's ``p * m``; below
    the draws' resolution ``p`` times the effective number of tests (``0.01 / q``, ``q`` the 1 %
    quantile of the null minima). ``null_min_p`` None (no draws: no candidate near the level):
    Bonferroni's ``min(1, p m)``."""
    if null_min_p is None:
        return float(min(1.0, p * m))
    share = np.searchsorted(null_min_p, p, side="right") / null_min_p.size
    if share == 0:  # below the draws' resolution: p times the effective number of tests at 1 %
        share = p * max(1.0, 0.01 / float(np.quantile(null_min_p, 0.01)))
    return float(min(1.0, p * m, max(share, p)))


def critical_p(alpha: float, null_min_p: np.ndarray | None, m: int) -> float:
    """The marginal p-value a candidate needs for a family-wise p-value below ``alpha`` (at least
    Bonferroni's ``alpha / m``, which it is when ``null_min_p`` is None)."""
    if null_min_p is None:
        return alpha / m
    q = float(np.quantile(null_min_p, alpha))
    return max(alpha / m, q)
