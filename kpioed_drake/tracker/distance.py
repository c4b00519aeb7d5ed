"""The distance measurement system: lengths between tool points, or from a tool point to a pivot.

Model of a row of :class:`~kpioed_drake.tracker.contactdata.DistanceData` (tool points ``p_WQ`` of
eq. 3 before the tracker, :func:`~kpioed_drake.tracker.measurement.world_point_jacobian`):

- a pair row (poses i, j): ``d = |p_WQ(p, q_i) - p_WQ(p, q_j)|``;
- a pivot row (pose i, pivot c): ``d = |p_WQ(p, q_i) - p_WC|`` with the pivot's position ``p_WC``
  in W (``pivot{c}_x, _y, _z``, estimated);

residual ``r = d - (L + dL_b)``: the model minus the measured length ``L`` [mm], corrected by the
row's bar's length correction ``dL_b`` (``bar{b}_dL``; 0 for a row of known length). Jacobian in
closed form, with ``u = (p_i - p_j) / d`` (``p_j = p_WC`` for a pivot row) and ``J_i`` the tool
point's Jacobian: ``dr/dp = u^T (J_i - J_j)`` (``J_j = 0`` for a pivot), ``dr/dp_WC = -u^T``,
``dr/d dL_b = -1``. A distance is blind to where the robot stands: no tracker parameter enters it,
and a parameter that moves every tool point rigidly (theta1, d1 of the six-joint tables) has a zero
column in pair rows and trades exactly against the pivots' positions in pivot rows; the base
frame's six degrees of freedom are unobservable.

:func:`pivot_start`: the closed-form start of the pivots (a sphere fit: ``|p_i - c|^2 = L_i^2``
is linear in ``c`` and ``|c|^2``). Units: millimetres and radians.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.tracker.contactdata import DistanceData
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world, world_point_jacobian

SPHERE_RCOND = 1e-9
"""Relative singular value below which the linear sphere fit of a pivot is singular (its rows' tool
points on one plane or fewer than 4)."""


def _ends(model: TrackerModel, data: DistanceData, *, jac: bool):
    """Tool points (and Jacobians) of both ends: (n, 3) [and (n, 3, n_full)] each; the second end of
    a pivot row is its pivot (zero Jacobian but the pivot's columns, set by the caller)."""
    pair = data.is_pair
    q_j = np.where(pair[:, None], data.q_other, data.q)
    pivots = model.p[model.layout.pivot_columns(np.maximum(data.pivot, 0))] if data.n_pivots else 0.0
    if not jac:
        p_i = reflector_world(model, data.q, data.target)
        p_j = np.where(pair[:, None], reflector_world(model, q_j, data.target), pivots)
        return p_i, p_j
    p_i, J_i = world_point_jacobian(model, data.q, data.target)
    p_j, J_j = world_point_jacobian(model, q_j, data.target)
    p_j = np.where(pair[:, None], p_j, pivots)
    J_j = np.where(pair[:, None, None], J_j, 0.0)
    return p_i, p_j, J_i, J_j


def _corrections(model: TrackerModel, data: DistanceData) -> np.ndarray:
    """(n,) the rows' bar length corrections ``dL_b`` [mm] (0 for rows of known length)."""
    has_bar = data.bar >= 0
    if not has_bar.any():
        return np.zeros(data.n)
    return np.where(has_bar, model.p[model.layout.bar_columns(np.maximum(data.bar, 0))], 0.0)


def distance_residuals(model: TrackerModel, data: DistanceData) -> np.ndarray:
    """(n,) ``d_model - (L + dL_b)`` [mm] of every row."""
    p_i, p_j = _ends(model, data, jac=False)
    return np.linalg.norm(p_i - p_j, axis=1) - data.length - _corrections(model, data)


def distance_jacobian(model: TrackerModel, data: DistanceData) -> tuple[np.ndarray, np.ndarray]:
    """Residuals and their Jacobian in closed form.

    Args:
        model: the model; its layout has the data's pivots and bars (``layout.contacts``).
        data: the distance rows.

    Returns:
        r: (n,) ``d_model - (L + dL_b)`` [mm]; H: (n, n_full) ``dr/dp`` [mm/rad, mm/mm].
    """
    lay = model.layout
    p_i, p_j, J_i, J_j = _ends(model, data, jac=True)
    diff = p_i - p_j
    d = np.linalg.norm(diff, axis=1)
    u = diff / d[:, None]
    H = np.einsum("ni,nij->nj", u, J_i - J_j)
    k = np.flatnonzero(~data.is_pair)
    if k.size:
        H[k[:, None], lay.pivot_columns(data.pivot[k])] = -u[k]
    b = np.flatnonzero(data.bar >= 0)
    if b.size:
        H[b, lay.bar_columns(data.bar[b])] = -1.0
    return d - data.length - _corrections(model, data), H


def pivot_start(model: TrackerModel, data: DistanceData) -> np.ndarray:
    """(C, 3) closed-form start of the pivots' positions in W [mm]: the sphere fit of each pivot's
    rows (tool points of ``model``, the measured lengths).

    Raises:
        InputError: a pivot whose rows' tool points lie on one plane (or are fewer than 4): the
            linear fit does not determine it.
    """
    out = np.zeros((data.n_pivots, 3))
    p_W = reflector_world(model, data.q, data.target)
    for c in range(data.n_pivots):
        k = np.flatnonzero(data.pivot == c)
        A = np.column_stack([2.0 * p_W[k], -np.ones(k.size)])  # unknowns: p_WC, |p_WC|^2
        s = np.linalg.svd(A, compute_uv=False)
        if k.size < 4 or s[-1] <= SPHERE_RCOND * s[0]:
            raise InputError(
                f"{data.source}: pivot {c} (0-based): its {k.size} rows' tool points lie on one plane "
                "(or are fewer than 4); measure it from poses off that plane"
            )
        b = np.sum(p_W[k] ** 2, axis=1) - data.length[k] ** 2
        out[c] = np.linalg.lstsq(A, b, rcond=None)[0][:3]
    return out
