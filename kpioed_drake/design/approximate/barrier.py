"""The cone program of the approximate design over a finite pool, by a log-barrier Newton method.

The dual of the L-optimal approximate design over candidates with rows ``F_i`` (module docstring of
:mod:`kpioed_drake.design.approximate.design`),

    max_Y tr(K^T Y)   s.t.   g_i(Y) = ||F_i Y||_F^2 <= 1   for every candidate i,

is solved by the barrier method: for a falling ``mu``, Newton's method minimises
``-tr(K^T Y) / mu - sum_i log(1 - g_i(Y))`` from the previous minimiser (a self-concordant
function: damped steps keep every ``g_i < 1`` and converge), each ``mu`` started by a step along the
central path's tangent. At a minimiser ``K = sum_i lambda_i F_i^T F_i Y`` with
``lambda_i = 2 mu / (1 - g_i)`` and the duality gap is ``m mu``. Those multipliers lose digits where
a cone is active (``1 - g_i`` about 1e-12), so the barrier stops at a gap of 1e-8 and Newton's
method on the weights of its support (:func:`polish_weights`) gives ``w``; ``Y = M(w)^-1 K``
(:func:`.pool.solve_pool` takes it where its bound is larger) then meets ``Phi(w)`` to about 1e-11
(measured 1e-13 to 3e-11).

Why not a general conic solver: the Newton matrix has the structure
``(sum_i c_i F_i^T F_i) kron I + U diag(d) U^T`` (``U``: the columns ``vec(F_i^T F_i Y)``), which
numpy forms with two matrix products, while a general solver's sparse factorisation of the same
problem fills in; on 200 candidates of the 18-joint twin it is about six times faster than Clarabel
with the same weights to 2e-8 and the same ``Phi`` to 2e-11 (docs/certificate.md).

Units: those of ``F`` and ``K`` (mm and the parameters' units); ``Y`` (k, c).
"""

from __future__ import annotations

import math

import numpy as np

SHRINK = 10.0
"""Factor by which ``mu`` falls between centring steps."""
NEWTON_TOL = 1e-9
"""A centring step ends when the squared Newton decrement is below this (or stalls below
:data:`STALL_BELOW`, where rounding sets a floor)."""
STALL_BELOW = 1e-4
"""Below this squared decrement a step that does not shrink it fourfold ends the centring."""
MAX_NEWTON = 15
"""Most Newton steps per centring (the last ones, at a tiny ``mu``, stall on rounding)."""
SUPPORT_LAMBDA = 1e-6
"""Multipliers below this fraction of the largest leave the support before the polish."""
BARRIER_GAP = 1e-8
"""The barrier stops at this relative duality gap at the latest: beyond it the slacks ``1 - g_i``
of active cones (about 1e-12) lose digits and Newton stalls; :func:`polish_weights` then gives the
weights to about 1e-12."""
MAX_STAGES = 40
"""Most values of ``mu`` (each :data:`SHRINK` times smaller): a gap of 1e-8 takes about ten."""
POLISH_STEPS = 8
"""Most Newton steps of :func:`polish_weights`."""
POLISH_TOL = 1e-14
"""The polish stops when no weight moves by more than this."""
ARMIJO = 0.01
"""Sufficient decrease of the barrier function in the backtracking line search."""


def settings() -> dict:
    """The method's settings (part of the certificate cache key: they move its last digits)."""
    names = ("SHRINK", "NEWTON_TOL", "STALL_BELOW", "MAX_NEWTON", "SUPPORT_LAMBDA", "ARMIJO", "BARRIER_GAP")
    names += ("MAX_STAGES", "POLISH_STEPS", "POLISH_TOL")
    return {"method": "log-barrier Newton", **{name: globals()[name] for name in names}}


def _rows(Fs: np.ndarray, Y: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``F_i Y`` (m, r, c) and the slacks ``1 - g_i`` (m,) of the stacked rows ``Fs`` (m r, k)."""
    B = (Fs @ Y).reshape(m, -1, Y.shape[1])
    return B, 1.0 - np.einsum("iac,iac->i", B, B)


def _max_step(B: np.ndarray, D: np.ndarray, s: np.ndarray) -> float:
    """The largest ``a`` with ``||B_i + a D_i||^2 < 1`` for every i (``s = 1 - ||B_i||^2 > 0``)."""
    a2 = np.einsum("iac,iac->i", D, D)
    a1 = 2.0 * np.einsum("iac,iac->i", B, D)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # huge steps: root ~ 0
        root = 2.0 * s / (a1 + np.sqrt(a1 * a1 + 4.0 * a2 * s))  # the positive root, stably
    return float(np.min(np.where(np.isnan(root), 0.0, root)))


class _Barrier:
    """The barrier function of one pool: its value, Newton step, centring and support."""

    def __init__(self, F: np.ndarray, K: np.ndarray):
        self.m, self.r, self.k = F.shape
        self.nc = K.shape[1]
        self.Fs = F.reshape(self.m * self.r, self.k)
        self.FT = np.ascontiguousarray(F.transpose(0, 2, 1))
        self.K, self.Kv = K, K.reshape(-1)

    def value(self, Y: np.ndarray, mu: float) -> float:
        """``-tr(K^T Y) / mu - sum log(1 - g_i)``; inf outside the cones."""
        _, s = _rows(self.Fs, Y, self.m)
        return float(-np.sum(self.K * Y) / mu - np.sum(np.log(s))) if np.all(s > 0.0) else math.inf

    def newton(self, Y: np.ndarray, mu: float) -> tuple[np.ndarray, float, np.ndarray]:
        """The Newton step (k, c), its squared decrement and the Newton matrix (k c, k c)."""
        B, s = _rows(self.Fs, Y, self.m)
        c = 2.0 / s
        U = (self.FT @ B).reshape(self.m, -1)  # vec(F_i^T F_i Y), row-major
        grad = -self.Kv / mu + c @ U
        A = (self.Fs * np.repeat(c, self.r)[:, None]).T @ self.Fs  # sum c_i F_i^T F_i
        H = np.kron(A, np.eye(self.nc)) + (U.T * (c * c)) @ U
        step = -np.linalg.solve(H, grad)
        return step.reshape(self.k, self.nc), float(-grad @ step), H

    def feasible_step(self, Y: np.ndarray, D: np.ndarray, fraction: float) -> float:
        """``min(1, fraction x`` the largest step along ``D`` that stays inside every cone)."""
        B, s = _rows(self.Fs, Y, self.m)
        return min(1.0, fraction * _max_step(B, (self.Fs @ D).reshape(self.m, -1, self.nc), s))

    def centre(self, Y: np.ndarray, mu: float) -> tuple[np.ndarray, np.ndarray]:
        """Damped Newton from ``Y`` to the minimiser for ``mu``; the last Newton matrix."""
        previous = math.inf
        for _ in range(MAX_NEWTON):
            step, dec2, H = self.newton(Y, mu)
            if dec2 < NEWTON_TOL or (dec2 < STALL_BELOW and dec2 > 0.25 * previous):
                break
            previous = dec2
            a, f0 = self.feasible_step(Y, step, 0.99), self.value(Y, mu)
            while a > 1e-12 and self.value(Y + a * step, mu) > f0 - ARMIJO * a * dec2:
                a *= 0.5
            Y = Y + a * step
        return Y, H

    def support(self, Y: np.ndarray, mu: float) -> tuple[np.ndarray, np.ndarray]:
        """The candidates whose barrier multipliers ``2 mu / (1 - g_i)`` are not negligible
        (:data:`SUPPORT_LAMBDA`) and their multipliers normalised to sum 1."""
        _, s = _rows(self.Fs, Y, self.m)
        lam = 2.0 * mu / s
        on = np.flatnonzero(lam > SUPPORT_LAMBDA * lam.max())
        return on, lam[on] / lam[on].sum()


def polish_weights(F: np.ndarray, K: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Newton's method for ``min Phi(w)`` over the weights of the candidates ``F`` (s, r, k) on the
    simplex, from ``w`` (s,) > 0; a weight a step would make negative leaves the support.

    ``dPhi/dw_i = -||F_i X||^2`` and ``d2Phi/dw_i dw_j = 2 <F_i M^-1 F_j^T, (F_i X)(F_j X)^T>`` with
    ``X = M(w)^-1 K``: at the optimum of the support the barrier's multipliers (which lose digits
    where a cone is active) become exact, and ``Phi(w)`` meets the dual.

    Returns:
        (s,) weights (sum 1, zeros where they left).
    """
    _, r, k = F.shape
    w = np.asarray(w, dtype=float).copy()
    for _ in range(POLISH_STEPS):
        on = np.flatnonzero(w > 0.0)
        Fo = F[on].reshape(-1, k)
        M = Fo.T @ (Fo * np.repeat(w[on], r)[:, None])
        Minv = np.linalg.inv(M)
        X = Minv @ K
        B = Fo @ X  # (s r, c)
        P = (Fo @ Minv @ Fo.T) * (B @ B.T)
        H = 2.0 * P.reshape(len(on), r, len(on), r).sum(axis=(1, 3))
        d = np.einsum("ia,ia->i", B.reshape(len(on), -1), B.reshape(len(on), -1))
        kkt = np.block([[H, np.ones((len(on), 1))], [np.ones((1, len(on))), np.zeros((1, 1))]])
        step = np.linalg.solve(kkt, np.append(d, 0.0))[:-1]
        new = w[on] + step
        if np.any(new <= 0.0):  # to the first weight reaching zero, which leaves
            i = int(np.argmin(np.where(step < 0.0, -w[on] / np.where(step < 0.0, step, -1.0), np.inf)))
            new = w[on] + (-w[on][i] / step[i]) * step
            new[i] = 0.0
        w[on] = np.maximum(new, 0.0)
        w /= w.sum()
        if np.max(np.abs(step)) < POLISH_TOL:
            break
    return w


def barrier_dual(F: np.ndarray, K: np.ndarray, *, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """The optimum weights and dual matrix of the pool with rows ``F`` (m, r, k) and KPI factor
    ``K`` (k, c), to a duality gap of ``rtol`` times the dual value (the barrier to
    :data:`BARRIER_GAP` at most, then the polish).

    Starts from ``Y`` of the uniform weights scaled into the cones (``max g = 1/4``) with
    ``mu = 2 tr(K^T Y) / m``.

    Returns:
        w: (m,) weights (sum 1, :func:`polish_weights` on the barrier's support); Y: (k, c) the
        barrier's last (every ``g_i < 1``, not scaled to ``max g = 1``).

    Raises:
        numpy.linalg.LinAlgError: the candidates do not determine the parameters.
        FloatingPointError: no barrier path (``tr(K^T M^-1 K) = 0``), a step that overflows, or
            the gap not reached.
    """
    with np.errstate(divide="raise", over="raise", invalid="raise"):  # trouble: FloatingPointError
        return _path(_Barrier(F, K), F, K, rtol)


def _path(bar: _Barrier, F: np.ndarray, K: np.ndarray, rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`barrier_dual` along the central path of ``bar``."""
    M = bar.Fs.T @ bar.Fs / bar.m
    X = np.linalg.solve(M, K)
    FX = (bar.Fs @ X).reshape(bar.m, -1)
    Y = 0.5 * X / math.sqrt(float(np.max(np.einsum("ia,ia->i", FX, FX))))
    mu = 2.0 * float(np.sum(K * Y)) / bar.m
    for _ in range(MAX_STAGES):
        if not mu > 0.0:  # a KPI the candidates do not see (tr(K^T Y) = 0): no barrier path
            break
        Y, H = bar.centre(Y, mu)
        if bar.m * mu <= max(rtol, BARRIER_GAP) * float(np.sum(K * Y)):
            on, lam = bar.support(Y, mu)
            w = np.zeros(bar.m)
            w[on] = polish_weights(F[on], K, lam)
            return w, Y
        new = mu / SHRINK  # a step along the central path's tangent: H dY = K (1/new - 1/mu)
        tangent = np.linalg.solve(H, bar.Kv * (1.0 / new - 1.0 / mu)).reshape(bar.k, bar.nc)
        Y = Y + bar.feasible_step(Y, tangent, 0.9) * tangent
        mu = new
    raise FloatingPointError("the barrier method did not reach its gap")
