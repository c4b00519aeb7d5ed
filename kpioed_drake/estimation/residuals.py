"""Studentised residuals of a fit: hat-matrix blocks and the normalised residual of every pose.

The statistics the outlier test of a calibration (:mod:`kpioed_drake.calibration.robust`) compares
with chi^2(3): for a pose used in the fit its residual scaled by the residual covariance
``sigma^2 (I - H_ii)`` (the leverage ``H_ii`` of the 3x3 hat-matrix block makes a fitted point's
residual smaller than the noise), for an excluded pose its prediction error scaled by
``sigma^2 I + J_i Cp J_i^T``. A fit with a 6-DoF probe's orientation rows has a second statistic
per pose, its orientation residual ``e_i = log(R_meas R_model^T)`` the same way
(:func:`orientation_normalized_residuals`): whitened by its noise ``sigma_rot_i`` and scaled by
``I - H_ii`` of its orientation rows (their leverage in the whole fit), or for an excluded pose by
``diag(sigma_rot_i^2) + Jr_i Cp Jr_i^T``; each part chi^2(3) under a correct model.
:func:`pose_statistics` gives both with one QR. Units: residuals in millimetres and radians,
statistics dimensionless.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.estimation.estimator import EstimationResult, response
from kpioed_drake.tracker.orientation import orientation_jacobian


def leverage_blocks(J: np.ndarray) -> np.ndarray:
    """(m, 3, 3) diagonal blocks of the hat matrix ``J (J^T J)^-1 J^T`` of a (3 m, k) Jacobian."""
    Q, _ = np.linalg.qr(J)
    Qb = Q.reshape(-1, 3, Q.shape[1])
    return np.einsum("mak,mbk->mab", Qb, Qb)


def pose_statistics(result: EstimationResult) -> np.ndarray:
    """(parts, n) the studentised statistics of every pose (:func:`normalized_residuals`, then with
    a probe's orientations :func:`orientation_normalized_residuals`): parts 1 or 2, one QR."""
    blocks = leverage_blocks(result.J)
    t = normalized_residuals(result, blocks=blocks)
    t_rot = orientation_normalized_residuals(result, blocks=blocks)
    return t[None] if t_rot is None else np.stack([t, t_rot])


def normalized_residuals(result: EstimationResult, *, blocks: np.ndarray | None = None) -> np.ndarray:
    """(n,) studentised squared residual norm of every pose, ~ chi^2(3) for a correct model.

    For a used pose i: ``r_i^T (sigma_i^2 (I - H_ii))^-1 r_i`` with ``H_ii`` the 3x3 hat-matrix
    block (the residual covariance of a fitted point is smaller than the noise by its leverage).
    For an excluded pose: ``r_i^T (sigma_i^2 I + J_i Cp J_i^T)^-1 r_i`` (prediction error).
    ``blocks``: :func:`leverage_blocks` of ``result.J`` if the caller has them.
    """
    sw2 = result.weights / result.sigma**2
    out = np.empty(result.residuals.shape[0])
    used = np.flatnonzero(result.mask)
    blocks = leverage_blocks(result.J) if blocks is None else blocks
    blocks = blocks[: used.size]  # the position rows (orientation rows after them)
    out[used] = _quadratic_forms(np.eye(3) - blocks, result.residuals[used]) * sw2[used]
    other = np.flatnonzero(~result.mask)
    if other.size:
        _, H, E = response(result.model, result.effects, result.q[other], result.conditions.subset(other))
        Hf = np.concatenate([H[:, :, result.free], E], axis=2)
        V = np.einsum("mak,kl,mbl->mab", Hf, result.Cp, Hf)
        out[other] = _quadratic_forms(np.eye(3) / sw2[other, None, None] + V, result.residuals[other])
    return out


def orientation_normalized_residuals(
    result: EstimationResult, *, blocks: np.ndarray | None = None, noise: np.ndarray | None = None
) -> np.ndarray | None:
    """(n,) the studentised orientation statistic of every pose (None without orientations),
    ~ chi^2(3) for a correct model.

    For a used pose i, ``z_i = e_i / s_i`` (the orientation residual whitened per axis by its noise
    ``s_i = sigma_rot_i / sqrt(w_i)`` [rad]) and ``z_i^T (I - H_ii)^-1 z_i`` with ``H_ii`` the
    hat-matrix block of its three orientation rows (after the 3 m position rows of ``result.J``).
    For an excluded pose: ``e_i^T (diag(s_i^2) + Jr_i Cp Jr_i^T)^-1 e_i`` (prediction error,
    ``Jr_i`` the orientation residual's model Jacobian over the estimated parameters).

    Args:
        result: a fit with orientations.
        blocks: :func:`leverage_blocks` of ``result.J`` if the caller has them.
        noise: (n, 3) the noise ``s_i`` to test at instead [rad] (the leverage stays the fit's).
    """
    if result.R_TP is None or result.rot_residuals is None or result.sigma_rot is None:
        return None
    e = result.rot_residuals
    s = result.sigma_rot / np.sqrt(result.weights)[:, None] if noise is None else np.asarray(noise)
    out = np.empty(e.shape[0])
    used = np.flatnonzero(result.mask)
    blocks = leverage_blocks(result.J) if blocks is None else blocks
    out[used] = _quadratic_forms(np.eye(3) - blocks[used.size : 2 * used.size], e[used] / s[used])
    other = np.flatnonzero(~result.mask)
    if other.size:
        _, Hr = orientation_jacobian(result.model, result.q[other], result.R_TP[other])
        Hf = Hr[:, :, result.free]
        V = np.einsum("mak,kl,mbl->mab", Hf, result.Cp, Hf)
        out[other] = _quadratic_forms(V + s[other, :, None] ** 2 * np.eye(3), e[other])
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
