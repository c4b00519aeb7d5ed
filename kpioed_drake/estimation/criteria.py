"""The design criteria (paper eq. 24a, eq. 8): one resolved record per criterion.

Every criterion is a function ``phi(M)`` of the information ``M = F1^T F1 (+ M0)`` of a weighted
identification Jacobian ``F1`` (m, k) (paper eq. 24d; ``M0``: information of further poses held
fixed). With ``G = d phi / d M`` (symmetric), ``d phi = tr(G dM)`` gives the adjoint
``d phi / d F1 = 2 F1 G``, which the optimiser contracts with ``d F1 / d q``.

=========  =====================================================  ==============================
name       value                                                  ``G = d phi / d M``
=========  =====================================================  ==============================
``kpi``    tr(Cs)/3 = tr(Js M^-1 Js^T)/3 [mm^2] (the paper)       ``-X X^T / 3``, ``X = M^-1 Js^T``
``param``  tr(P^T M^-1 P), P = diag(scale) (SPEC) [mm^2]          ``-X X^T``, ``X = M^-1 P``
``d``      -log det M (D-optimality) [-]                          ``-M^-1``
``o1``     -(prod mu)^(1/r)/sqrt(r) (Borm-Menq, eq. 8) [-]        ``-o1/(2r) M^-1``
=========  =====================================================  ==============================

``mu`` are the r singular values of ``F1``, so ``(prod mu)^(1/r) = det(M)^(1/(2r))``.

Several KPIs (paper, Outlook): ``kpi`` of the stacked, weighted Jacobian of
:meth:`kpioed_drake.estimation.problem.Problem.Js` is the weighted mean of the working poses' variances; the
worst case needs each variance ``v_k = tr(Js_k M^-1 Js_k^T)/3`` with its adjoint, which
:func:`kpi_each` gives from one Cholesky factor.
:class:`Criterion` also holds each criterion's normalisation (the size its changes are measured
against) and its label for tables. The heuristic is a design method, not a criterion
(:mod:`kpioed_drake.design`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from types import MappingProxyType

import numpy as np
import scipy.linalg

from kpioed_drake.errors import InputError

_Phi = Callable[[tuple, np.ndarray, np.ndarray, np.ndarray], tuple[float, np.ndarray]]


def _kpi(c, M, Js, scale):
    X = scipy.linalg.cho_solve(c, Js.T)  # M^-1 Js^T
    return float(np.sum(Js * X.T)) / 3.0, -(X @ X.T) / 3.0


def _param(c, M, Js, scale):
    Minv = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
    value = float(np.sum(np.diag(Minv) * scale * scale))
    X = Minv * scale[None, :]
    return value, -(X @ X.T)


def _log_det(c) -> float:
    """log det M of a Cholesky factor ``c`` of M."""
    return 2.0 * float(np.sum(np.log(np.diag(c[0]))))


def _d(c, M, Js, scale):
    Minv = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
    return -_log_det(c), -Minv


def _o1(c, M, Js, scale):
    Minv = scipy.linalg.cho_solve(c, np.eye(M.shape[0]))
    r = M.shape[0]
    o1 = np.exp(_log_det(c) / (2.0 * r)) / np.sqrt(r)
    return -o1, -o1 / (2.0 * r) * Minv


@dataclasses.dataclass(frozen=True)
class Criterion:
    """A design criterion ``phi(F1^T F1)``: its value, gradient, normalisation and labels."""

    name: str
    """Key on the command line, in files and in results: ``kpi``, ``param``, ``d`` or ``o1``."""
    label: str
    """Short name for tables and printed summaries (e.g. ``KPI``, ``standard (param)``)."""
    description: str
    """What the value is, with its unit (e.g. ``tr(Cs)/3 [mm^2]``)."""
    phi: _Phi = dataclasses.field(repr=False)
    """``phi(c, M, Js, scale) -> (value, G)``: value and ``G = d value / d M`` (k, k) from the
    Cholesky factor ``c`` of ``M`` (``scipy.linalg.cho_factor``), ``Js`` (3, k) and ``scale`` (k,)."""
    logarithmic: bool = False
    """The value is a logarithm: its differences matter, not its ratios (see :meth:`normalisation`)."""

    def normalisation(self, value: float, n_params: int) -> float:
        """Size against which changes of the criterion near ``value`` are measured.

        A solve's cost is divided by it (O(1) at the start) and a block sweep's decrease is
        relative to it. ``|value|`` for the variance-like criteria (kpi, param positive; o1
        negative); for a logarithm (``d``) the number of parameters ``n_params`` (changes of the
        mean log-eigenvalue).
        """
        return n_params if self.logarithmic else max(abs(value), 1e-300)

    def evaluate(
        self,
        F1: np.ndarray,
        Js: np.ndarray,
        scale: np.ndarray,
        *,
        with_grad: bool = True,
        M0: np.ndarray | None = None,
    ) -> float | tuple[float, np.ndarray]:
        """The criterion of a weighted Jacobian and its derivative with respect to ``F1``.

        Args:
            F1: (m, k) weighted identification Jacobian ``dh/dp / sigma`` (rows: measured
                coordinates, pose-major).
            Js: (3, k) KPI Jacobian at ``q_work``.
            scale: (k,) parameter scaling of ``param`` (SPEC: 1 for lengths, the reach for angles).
            with_grad: also return the derivative.
            M0: (k, k) information of further measurements held fixed, added to ``F1^T F1``;
                None: none.

        Returns:
            value, and with ``with_grad`` the (m, k) derivative ``d value / d F1 = 2 F1 G``.

        Raises:
            numpy.linalg.LinAlgError: if ``F1^T F1 (+ M0)`` is singular.
        """
        M = F1.T @ F1
        if M0 is not None:
            M = M + M0
        value, G = self.phi(scipy.linalg.cho_factor(M), M, Js, scale)
        if not with_grad:
            return value
        return value, 2.0 * F1 @ G


TABLE: MappingProxyType[str, Criterion] = MappingProxyType(
    {
        c.name: c
        for c in (
            Criterion(
                "kpi", "KPI", "tr(Cs)/3, the TCP's average variance at q_work (the paper) [mm^2]", _kpi
            ),
            Criterion("param", "standard (param)", "SPEC-scaled tr(Cp) (the standard method) [mm^2]", _param),
            Criterion("d", "D-optimal", "-log det(F1^T F1) (D-optimality) [-]", _d, logarithmic=True),
            Criterion("o1", "O1 (Borm-Menq)", "-(prod mu)^(1/r)/sqrt(r), mu: singular values of F1 [-]", _o1),
        )
    }
)
"""Every criterion by name."""
CRITERIA: tuple[str, ...] = tuple(TABLE)
"""Names of the criteria an optimiser can minimise: ``kpi``, ``param``, ``d``, ``o1``."""


def kpi_each(
    F1: np.ndarray, Js_each: np.ndarray, *, M0: np.ndarray | None = None, with_grad: bool = True
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Each working pose's variance ``v_k = tr(Js_k M^-1 Js_k^T)/3`` and its derivative w.r.t. F1.

    Args:
        F1: (m, k) weighted identification Jacobian.
        Js_each: (K, 3, k) KPI Jacobians at the K working poses.
        M0: (k, k) information of further poses held fixed; None: none.
        with_grad: also return the derivatives.

    Returns:
        values (K,) [mm^2], and with ``with_grad`` the derivatives (K, m, k)
        ``d v_k / d F1 = 2 F1 G_k``, ``G_k = -X_k X_k^T / 3``, ``X_k = M^-1 Js_k^T``.

    Raises:
        numpy.linalg.LinAlgError: if ``F1^T F1 (+ M0)`` is singular.
    """
    M = F1.T @ F1
    if M0 is not None:
        M = M + M0
    c = scipy.linalg.cho_factor(M)
    X = [scipy.linalg.cho_solve(c, J.T) for J in Js_each]  # M^-1 Js_k^T, (k, 3) each
    values = np.array([float(np.sum(J * Xk.T)) / 3.0 for J, Xk in zip(Js_each, X, strict=True)])
    if not with_grad:
        return values
    return values, np.stack([-2.0 / 3.0 * (F1 @ Xk) @ Xk.T for Xk in X])


def resolve(name: str) -> Criterion:
    """The :class:`Criterion` called ``name``.

    Raises:
        InputError: unknown name.
    """
    try:
        return TABLE[name]
    except (KeyError, TypeError):
        raise InputError(f"unknown criterion {name!r}; expected one of {', '.join(CRITERIA)}") from None
