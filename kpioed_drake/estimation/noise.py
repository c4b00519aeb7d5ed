"""The noise the statistics of a fit rest on, and where it comes from.

Every chi^2, likelihood ratio and p-value of a diagnosis divides by one sigma per coordinate. It is

- **given** (``sigma_mm``: the user knows the noise of tracker and robot together);
- else **measured** from repeated poses: rows of the same joint values and target, their pooled
  scatter about each pose's mean (:func:`repeat_scatter`; the robot's repeatability and the
  tracker's noise together, at least ``MIN_REPEAT_DOF`` degrees of freedom);
- else the **default**, the tracker's noise.

That sigma is then checked against the data (:func:`residual_scale`): the residuals of the model with
every candidate effect at once (the most any set of named causes could explain, linearised at the
geometric fit) have a robust scale ``s`` (1.4826 times the median absolute residual, each divided by
``sqrt(1 - h_ii)``, h the leverage of the model's span). When ``s`` exceeds ``FAR`` times the sigma
(chi^2/dof of 9 and more with every candidate in the model), the sigma cannot be the noise of these
data: the robot's repeatability (or an error outside the candidate list) dominates it, every
candidate would be "significant", and the named set would follow the subset of poses. The tests and
the selection then rest on ``s`` instead, and the report says so (:class:`Noise`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

FAR = 3.0
"""The stated sigma is set aside when the residual scale of the model with every candidate exceeds
this many times it."""
MIN_REPEAT_DOF = 10
"""Degrees of freedom (3 per repeated row) repeated poses need to measure the noise."""
MAD_NORMAL = 1.4826
"""Median absolute deviation to standard deviation of a normal law."""
MIN_ROWS_OUTSIDE = 0.05
"""Residuals whose leverage leaves less than this share (``1 - h_ii``) are left out of the scale."""


@dataclasses.dataclass(frozen=True)
class Noise:
    """The noise a diagnosis rests on.

    Attributes:
        sigma_mm: the sigma every test uses [mm per coordinate].
        source: where it comes from: ``given``, ``repeated poses``, ``default`` or ``residuals``.
        stated_mm: the sigma given, measured or defaulted before the check [mm]; stated_source: its
            source.
        residual_scale_mm: the robust scale of the residuals of the model with every candidate [mm];
            residual_dof: the residuals' degrees of freedom.
        repeats: ``{"poses", "rows", "dof", "sigma_mm"}`` of the repeated poses, or None.
        text: the sentence the report prints.
    """

    sigma_mm: float
    source: Literal["given", "repeated poses", "default", "residuals"]
    stated_mm: float
    stated_source: str
    residual_scale_mm: float | None = None
    residual_dof: int | None = None
    repeats: dict[str, float] | None = None
    text: str = ""

    def as_dict(self) -> dict:
        """The JSON's ``noise``."""
        return dataclasses.asdict(self)


def repeat_scatter(q: np.ndarray, eta: np.ndarray, target: np.ndarray | None = None) -> dict | None:
    """The pooled scatter of repeated poses: rows with the same joint values and target, about their
    mean; ``{"poses", "rows", "dof", "sigma_mm"}`` or None with fewer than ``MIN_REPEAT_DOF``
    degrees of freedom.

    Args:
        q: (n, nj) joint values; eta: (n, 3) measured points [mm]; target: (n,) target or None.
    """
    q, eta = np.asarray(q, dtype=float), np.asarray(eta, dtype=float)
    if q.shape[0] < 2:
        return None
    key = q if target is None else np.column_stack([q, np.asarray(target, dtype=float)])
    _, group, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    dof = 3 * int(np.sum(count - 1))
    if dof < MIN_REPEAT_DOF:
        return None
    means = np.zeros((count.size, 3))
    np.add.at(means, group, eta)
    means /= count[:, None]
    ss = float(np.sum((eta - means[group]) ** 2))
    return {
        "poses": int(np.sum(count > 1)),
        "rows": int(np.sum(count[count > 1])),
        "dof": dof,
        "sigma_mm": float(np.sqrt(ss / dof)),
    }


def residual_scale(r: np.ndarray, M: np.ndarray) -> tuple[float, int]:
    """Robust scale of the residuals ``r`` (m,) [mm] beside the span of the columns ``M`` (m, k) (the
    model's and every candidate's): ``(scale, dof)`` with dof = m - rank."""
    r = np.asarray(r, dtype=float).reshape(-1)
    norms = np.linalg.norm(M, axis=0)
    M = M[:, norms > 0] / norms[norms > 0]
    if M.shape[1]:
        U, s, _ = np.linalg.svd(M, full_matrices=False)
        Q = U[:, s > 1e-8 * s.max()]
    else:
        Q = np.zeros((r.size, 0))
    out = r - Q @ (Q.T @ r)
    h = np.sum(Q**2, axis=1)
    keep = 1.0 - h > MIN_ROWS_OUTSIDE
    if not np.any(keep):
        return float("nan"), 0
    u = np.abs(out[keep]) / np.sqrt(1.0 - h[keep])
    return MAD_NORMAL * float(np.median(u)), int(r.size - Q.shape[1])


def stated(given: float | None, repeats: dict | None, default: float) -> tuple[float, str]:
    """The sigma before the check and its source: given, else measured on repeated poses, else the
    default."""
    if given is not None:
        return float(given), "given"
    if repeats is not None and repeats["sigma_mm"] > 0:
        return float(repeats["sigma_mm"]), "repeated poses"
    return float(default), "default"


def choose(sigma: float, source: str, scale: float, dof: int, repeats: dict | None) -> Noise:
    """The :class:`Noise` of the stated ``sigma`` (``source``) checked against the residual ``scale``
    (:func:`residual_scale`, ``dof``)."""
    kw = {"stated_mm": sigma, "stated_source": source, "residual_scale_mm": scale, "residual_dof": dof}
    what = {"given": "given (sigma_mm)", "repeated poses": "measured on repeated poses"}.get(
        source, "the default, the tracker's noise"
    )
    if repeats is not None:
        what += f"; {repeats['poses']} repeated poses scatter by {repeats['sigma_mm']:.3g} mm"
    if np.isfinite(scale) and scale > FAR * sigma:
        text = (
            f"sigma {scale:.3g} mm, the residuals' robust scale with every candidate effect in the model "
            f"({dof} dof): {scale / sigma:.0f} times the sigma {sigma:.3g} mm ({what}); the robot's "
            "repeatability or an error outside the candidate list dominates that noise, so the tests "
            f"and the selection rest on {scale:.3g} mm"
        )
        return Noise(sigma_mm=float(scale), source="residuals", repeats=repeats, text=text, **kw)
    text = (
        f"sigma {sigma:.3g} mm ({what}); the residuals with every candidate effect in the model have a "
        f"robust scale of {scale:.3g} mm"
    )
    return Noise(sigma_mm=float(sigma), source=source, repeats=repeats, text=text, **kw)
