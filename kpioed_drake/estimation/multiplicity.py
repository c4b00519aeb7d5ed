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
the model's span (:func:`~kpioed_drake.estimation.identifiability.projected_basis`), a chi-square(k_c)
variable; jointly, the stacked ``g = [U_1 ... U_M]^T eps`` is Gaussian with covariance
``G = W^T W = R^T R`` (``W`` the stacked bases, ``R`` its QR factor). :func:`min_p_null` draws
``g = xi R`` (``xi ~ N(0, I)``, seeded: the same data give the same decision), the p-value of each
block from its chi-square law, and their minimum; a candidate's family-wise p-value is the share of
draws whose minimum is at most its own p-value (:func:`adjusted_p`), never more than Bonferroni's.

*Weighted* min-p (Westfall, Kropf and Finos 2004, "Weighted FWE-controlling methods in
high-dimensional situations"): with weights ``w_c`` (mean 1, :func:`normalized`) the statistic is
the minimum of ``p_c / w_c``, and a candidate's family-wise p-value the share of null minima at or
below its ``p_c / w_c``. The level holds exactly for any weights fixed before the residuals are
seen; a candidate with a smaller weight needs a smaller p-value. A selection step gives each
candidate effect weight 1, and a backlash's sides other than its expected one weight 1 together
(:func:`~kpioed_drake.diagnosis.sides.side_weights`): those sides choose the backlash's column from
the data and cost the other candidates one test, not one per side.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.special

N_DRAWS = 10000
"""Monte Carlo draws of the null minimum p-value (resolution 1e-4; at a level of 0.01 the relative
standard error of the adjusted p-value is 10 %)."""
SEED = 20170601
"""Seed of the draws (fixed: a diagnosis is deterministic)."""


def min_p_null(
    bases: Sequence[np.ndarray],
    *,
    weights: np.ndarray | Sequence[float] | None = None,
    n_draws: int = N_DRAWS,
    seed: int = SEED,
) -> np.ndarray:
    """(n_draws,) sorted null minima of the weighted p-values ``p_c / w_c`` over candidates with
    orthonormal bases ``bases``.

    Args:
        bases: list of (m, k_c) orthonormal bases (the part of each candidate's weighted columns
            outside the model's span); k_c >= 1.
        weights: (len(bases),) positive weights of the weighted min-p test (:func:`normalized`,
            mean 1); None: all 1 (the unweighted min-p).
        n_draws: Monte Carlo draws.
        seed: their seed.
    """
    W = np.concatenate(bases, axis=1)
    R = np.linalg.qr(W, mode="r")  # W^T W = R^T R: g = xi R with xi ~ N(0, I)
    g = np.random.default_rng(seed).standard_normal((n_draws, R.shape[0])) @ R
    ks = np.array([U.shape[1] for U in bases])
    w = normalized(weights, len(bases))
    stat = np.add.reduceat(g**2, np.concatenate([[0], np.cumsum(ks)[:-1]]), axis=1)  # |g_c|^2
    # the smallest p-value of candidates with k degrees of freedom and one weight is that of their
    # largest statistic
    groups = sorted({(int(k), float(x)) for k, x in zip(ks, w, strict=True)})
    p = [chi2_sf(np.max(stat[:, (ks == k) & (w == x)], axis=1), k) / x for k, x in groups]
    return np.sort(np.min(p, axis=0))


def chi2_sf(x: np.ndarray, k: int) -> np.ndarray:
    """Survival function of chi-square(k) at ``x``: closed forms for k = 1, 2, 3 (``erfc`` and
    ``exp``, equal to :func:`scipy.stats.chi2.sf` to rounding and about 100 times faster on the
    null draws), :func:`scipy.special.chdtrc` otherwise."""
    if k == 1:
        return scipy.special.erfc(np.sqrt(0.5 * x))
    if k == 2:
        return np.exp(-0.5 * x)
    if k == 3:
        return scipy.special.erfc(np.sqrt(0.5 * x)) + np.sqrt(2.0 * x / np.pi) * np.exp(-0.5 * x)
    return scipy.special.chdtrc(k, x)


def normalized(weights: np.ndarray | Sequence[float] | None, n: int) -> np.ndarray:
    """(n,) weights of a weighted min-p test scaled to mean 1 (None: all 1). Weighted Bonferroni
    with these weights rejects candidate c when ``p_c <= alpha w_c / n``: its family-wise level is
    ``sum_c alpha w_c / n = alpha``."""
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,) or not np.all(w > 0):
        raise ValueError(f"weights must be {n} positive numbers, got shape {w.shape}")
    return w * (n / w.sum())


def adjusted_p(p: float, null_min_p: np.ndarray | None, m: int, *, weight: float = 1.0) -> float:
    """Family-wise p-value of a candidate with marginal p-value ``p`` and normalized weight
    ``weight`` (:func:`normalized`): the share of null minima (:func:`min_p_null`, sorted) at or
    below ``p / weight``, at least ``p`` and at most weighted Bonferroni's ``p m / weight``; below
    the draws' resolution ``p / weight`` times the effective number of tests (``0.01 / q``, ``q``
    the 1 % quantile of the null minima). ``null_min_p`` None (no draws: no candidate near the
    level): Bonferroni's ``min(1, p m / weight)``."""
    pw = p / weight
    if null_min_p is None:
        return float(min(1.0, pw * m))
    share = np.searchsorted(null_min_p, pw, side="right") / null_min_p.size
    if share == 0:  # below the draws' resolution: p times the effective number of tests at 1 %
        share = pw * max(1.0, effective_tests(null_min_p))
    return float(min(1.0, pw * m, max(share, p)))


def effective_tests(null_min_p: np.ndarray, level: float = 0.01) -> float:
    """Effective number of tests at ``level``: ``level / q`` with ``q`` the ``level`` quantile of
    the null minimum p-values (:func:`min_p_null`); the number of candidates for independent ones,
    1 for identical ones."""
    return level / float(np.quantile(null_min_p, level))


def critical_p(alpha: float, null_min_p: np.ndarray | None, m: int, *, weight: float = 1.0) -> float:
    """The marginal p-value a candidate of normalized weight ``weight`` needs for a family-wise
    p-value below ``alpha`` (at least weighted Bonferroni's ``alpha weight / m``, which it is when
    ``null_min_p`` is None)."""
    if null_min_p is None:
        return alpha * weight / m
    q = float(np.quantile(null_min_p, alpha))
    return weight * max(alpha / m, q)
