"""Covariance of the constrained least-squares estimate and the design criteria.

- :func:`kkt_covariance`: paper eq. (19)/(24c), ``C_v = [I 0] [[F1^T F1, F2^T], [F2, 0]]^-1 [I 0]^T``
  with ``v = (p, s)``, ``F1 = dh/dv / sigma`` (zero columns for s) and ``F2 = [Js, -I]`` from the
  explicit KPI constraint ``f2 = TCP(p, q_work) - s = 0`` (eq. 12, 24e).
- :func:`nullspace_covariance`: the Appendix form ``Z (Z^T F1^T F1 Z)^-1 Z^T``.
- :func:`kpi_covariance`: the cheap form ``Cp = (F1^T F1)^-1`` (Cholesky), ``Cs = Js Cp Js^T``
  (Appendix proposition: equal to the KKT blocks).
- :func:`criterion`: design criteria of a Jacobian ``F1`` and their derivative with respect to
  ``F1`` (adjoint form), used by the optimiser: ``kpi`` = tr(Cs)/3 [mm^2], ``param`` =
  tr(P^T Cp P) with SPEC's scaling, ``d`` = -log det(F1^T F1), ``o1`` = -(prod mu)^(1/r)/sqrt(r)
  (Borm-Menq, paper eq. 8).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

CRITERIA = ("kpi", "param", "d", "o1")


def information(F1: np.ndarray) -> np.ndarray:
    """Fisher information ``F1^T F1`` of a (m, k) Jacobian."""
    return F1.T @ F1


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


def criterion(
    name: str,
    F1: np.ndarray,
    Js: np.ndarray,
    scale: np.ndarray,
    *,
    with_grad: bool = True,
    M0: np.ndarray | None = None,
):
    """Design criterion of a weighted Jacobian and its derivative with respect to F1.

    Args:
        name: ``kpi``, ``param``, ``d`` or ``o1``.
        F1: (m, k) weighted identification Jacobian (rows = measurements / sigma).
        Js: (3, k) KPI Jacobian.
        scale: (k,) parameter scaling of the ``param`` criterion (SPEC: 1 for lengths, the reach
            for angles).
        M0: (k, k) information of further measurements held fixed, added to ``F1^T F1`` (e.g.
            the poses outside the block being optimised); None: none.

    Returns:
        value, and with ``with_grad`` the (m, k) derivative ``d value / d F1``. For
        ``f = g(M)``, ``M = F1^T F1``, ``df = tr(G dM)`` gives ``d f / d F1 = 2 F1 G``.

    Raises:
        numpy.linalg.LinAlgError: if ``F1^T F1`` is singular.
    """
    M = F1.T @ F1
    if M0 is not None:
        M = M + M0
    c = scipy.linalg.cho_factor(M)
    if name == "kpi":
        X = scipy.linalg.cho_solve(c, Js.T)  # M^-1 Js^T
        value = float(np.sum(Js * X.T)) / 3.0
        G = -(X @ X.T) / 3.0
    elif name == "param":
        Minv = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
        S = scale
        value = float(np.sum(np.diag(Minv) * S * S))
        X = Minv * S[None, :]
        G = -(X @ X.T)
    elif name in ("d", "o1"):
        Minv = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
        logdet = 2.0 * float(np.sum(np.log(np.diag(c[0]))))
        if name == "d":
            value, G = -logdet, -Minv
        else:
            r = M.shape[0]
            o1 = np.exp(logdet / (2.0 * r)) / np.sqrt(r)
            value, G = -o1, -o1 / (2.0 * r) * Minv
    else:
        raise ValueError(f"unknown criterion {name!r}; expected one of {CRITERIA}")
    if not with_grad:
        return value
    return value, 2.0 * F1 @ G
