"""Studentised residuals of a fit: hat-matrix blocks and the normalised residual of every pose.

The statistics the outlier test of a calibration (:mod:`kpioed_drake.calibration.robust`) compares
with chi^2(3): for a pose used in the fit its residual scaled by the residual covariance
``sigma^2 (I - H_ii)`` (the leverage ``H_ii`` of the 3x3 hat-matrix block makes a fitted point's
residual smaller than the noise), for an excluded pose its prediction error scaled by
``sigma^2 I + J_i Cp J_i^T``. A fit with a 6-DoF probe's orientation rows: the statistic is its
position rows' (their leverage in the whole fit). Units: residuals in millimetres, statistics
dimensionless.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.estimation.estimator import EstimationResult, response


def leverage_blocks(J: np.ndarray) -> np.ndarray:
    """(m, 3, 3) diagonal blocks of the hat matrix ``J (J^T J)^-1 J^T`` of a (3 m, k) Jacobian."""
    Q, _ = np.linalg.qr(J)
    Qb = Q.reshape(-1, 3, Q.shape[1])
    return np.einsum("mak,mbk->mab", Qb, Qb)


def normalized_residuals(result: EstimationResult) -> np.ndarray:
    """(n,) studentised squared residual norm of every pose, ~ chi^2(3) for a correct model.

    For a used pose i: ``r_i^T (sigma_i^2 (I - H_ii))^-1 r_i`` with ``H_ii`` the 3x3 hat-matrix
    block (the residual covariance of a fitted point is smaller than the noise by its leverage).
    For an excluded pose: ``r_i^T (sigma_i^2 I + J_i Cp J_i^T)^-1 r_i`` (prediction error).
    """
    sw2 = result.weights / result.sigma**2
    out = np.empty(result.residuals.shape[0])
    used = np.flatnonzero(result.mask)
    blocks = leverage_blocks(result.J)[: used.size]  # the position rows (orientation rows after them)
    out[used] = _quadratic_forms(np.eye(3) - blocks, result.residuals[used]) * sw2[used]
    other = np.flatnonzero(~result.mask)
    if other.size:
        _, H, E = response(result.model, result.effects, result.q[other], result.conditions.subset(other))
        Hf = np.concatenate([H[:, :, result.free], E], axis=2)
        V = np.einsum("mak,kl,mbl->mab", Hf, result.Cp, Hf)
        out[other] = _quadratic_forms(np.eye(3) / sw2[other, None, None] + V, result.residuals[other])
    return out


def _quadratic_forms(S: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(m,) ``r_i^T S_i^-1 r_i`` of (m, 3, 3) ``S`` and (m, 3) ``r`` (inf where ``S_i`` is singular)."""
    try:
        return np.einsum("ma,ma->m", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])
    except np.linalg.LinAlgError:  # some block singular: one at a time
        out = np.empty(len(r))
        for i, (Si, ri) in enumerate(zip(S, r, strict=True)):
            try:
                out[i] = float(ri @ np.linalg.solve(Si, ri))
            except np.linalg.LinAlgError:
                out[i] = np.inf
        return out
