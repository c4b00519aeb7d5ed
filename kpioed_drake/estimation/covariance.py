"""Covariance of the constrained least-squares estimate (paper eq. 19, 24c and the Appendix).

- :func:`kkt_covariance`: paper eq. (19)/(24c), ``C_v = [I 0] [[F1^T F1, F2^T], [F2, 0]]^-1 [I 0]^T``
  with ``v = (p, s)``, ``F1 = dh/dv / sigma`` (zero columns for s) and ``F2 = [Js, -I]`` from the
  explicit KPI constraint ``f2 = TCP(p, q_work) - s = 0`` (eq. 12, 24e).
- :func:`nullspace_covariance`: the Appendix form ``Z (Z^T F1^T F1 Z)^-1 Z^T``.
- :func:`covariance`: ``(J^T J)^-1`` of a weighted Jacobian (column-scaled Cholesky, or the
  pseudo-inverse of a singular one), the estimator's ``Cp``;
- :func:`kpi_covariance`: the cheap form ``Cp = (F1^T F1)^-1`` (Cholesky), ``Cs = Js Cp Js^T``
  (Appendix proposition: equal to the KKT blocks).

The design criteria built on these covariances, with their gradients, are in
:mod:`kpioed_drake.estimation.criteria`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


def kkt_covariance(F1: np.ndarray, F2: np.ndarray) -> np.ndarray:
    """Covariance ``C_v`` of paper eq. (19) by solving the KKT system.

    Args:
        F1: (m, nv) weighted Jacobian of the least-squares residuals w.r.t. v.
        F2: (n2, nv) Jacobian of the equality constraints w.r.t. v.

    Returns:
        (nv, nv) covariance.
    """
    nv, n2 = F1.shape[1], F2.shape[0]
    K = np.zeros((nv + n2, nv + n2))
    K[:nv, :nv] = F1.T @ F1
    K[:nv, nv:] = F2.T
    K[nv:, :nv] = F2
    rhs = np.zeros((nv + n2, nv))
    rhs[:nv] = np.eye(nv)
    return np.linalg.solve(K, rhs)[:nv]


def nullspace_covariance(F1: np.ndarray, F2: np.ndarray) -> np.ndarray:
    """Covariance ``Z (Z^T F1^T F1 Z)^-1 Z^T`` with Z spanning the null space of F2 (Appendix)."""
    Z = scipy.linalg.null_space(F2)
    M = Z.T @ F1.T @ F1 @ Z
    return Z @ np.linalg.solve(M, Z.T)


def kpi_kkt_matrices(F1p: np.ndarray, Js: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F1 and F2 over ``v = (p, s)`` for the explicit TCP KPI (eq. 24d, 24e)."""
    m, k = F1p.shape
    ns = Js.shape[0]
    F1 = np.hstack([F1p, np.zeros((m, ns))])
    F2 = np.hstack([Js, -np.eye(ns)])
    return F1, F2


def kpi_covariance(F1p: np.ndarray, Js: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Cp = (F1^T F1)^-1`` by Cholesky and ``Cs = Js Cp Js^T``.

    Raises:
        numpy.linalg.LinAlgError: if ``F1^T F1`` is not positive definite (parameters not
            identifiable from this design).
    """
    M = F1p.T @ F1p
    c = scipy.linalg.cho_factor(M)
    Cp = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
    return Cp, Js @ Cp @ Js.T


def covariance(J: np.ndarray, *, singular_ok: bool = False) -> np.ndarray:
    """``(J^T J)^-1`` of a weighted (m, k) Jacobian, from the column-scaled information matrix.

    Cholesky when the information is positive definite; otherwise, with ``singular_ok``, its
    pseudo-inverse (the parameters without information get none).

    Raises:
        numpy.linalg.LinAlgError: the information matrix is singular and ``singular_ok`` is False.
    """
    D = np.linalg.norm(J, axis=0)
    D[D == 0] = 1.0
    Js = J / D
    A = Js.T @ Js
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        if not singular_ok:
            raise
        return np.linalg.pinv(A) / np.outer(D, D)
    Linv = scipy.linalg.solve_triangular(L, np.eye(L.shape[0]), lower=True)
    return (Linv.T @ Linv) / np.outer(D, D)
