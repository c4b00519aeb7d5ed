"""The plane-contact measurement system: a tool point touching one of several planes.

Plane k in W: unit normal ``n_k`` and offset ``d_k`` [mm] (the plane ``n_k . x = d_k``). The normal
has two parameters, tilts ``t = (tx, ty)`` [rad] in the tangent plane of a reference normal
``m_k`` (the model's ``n_W_ref``, set by the start):

    ``n_k = v / |v|``,  ``v = m_k + tx e1_k + ty e2_k``

with ``(e1_k, e2_k, m_k)`` right-handed and orthonormal (:func:`tangent_basis`); valid for any tilt
below 90 degrees, and near the reference the tilts are rotations of the normal in radians.

Residual of a row (pose q, plane k, measured signed distance s, 0 for a touch): the model's signed
distance minus the measured one, ``r = n_k . p_WQ(p, q) - d_k - s`` [mm]. Jacobian in closed form,
with ``J`` the tool point's (:func:`~kpioed_drake.tracker.measurement.world_point_jacobian`):
``dr/dp = n_k^T J``, ``dr/dt_i = (e_i . p - (n_k . e_i)(n_k . p)) / |v|``, ``dr/dd_k = -1``.

What planes cannot determine (the rank test of :mod:`kpioed_drake.tracker.contacts` finds it on the
data's poses): the planes are free, so a rigid motion of the robot's base moves them along (theta1,
d1 of a six-joint table, as against the tracker; a chain robot's gauge alike); a scaling of every
length of the robot scales every offset, so planes fix no scale; a parameter that moves the tool
point only along a plane is invisible to it (a plane perpendicular to joint 1's axis and a1 of a DH
table: zero column at the true plane; the start's plane, tilted by the robot's errors, shows it
faintly and the fit's standard deviation of it is then large); and a tool length along the normal
trades with the offset unless the tool meets the plane at varied angles.

:func:`plane_start`: the closed-form start of every plane (the least-squares plane of its rows' tool
points; the normal towards the flange, the side the tool comes from). Units: millimetres, radians.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.tracker.contactdata import PlaneData
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world, world_point_jacobian

COLLINEAR_RTOL = 1e-6
"""A plane's rows whose tool points' second singular value (about their centroid) is below this
times the first lie on one line: the plane through them is not determined."""


def tangent_basis(m: np.ndarray) -> np.ndarray:
    """(K, 2, 3) orthonormal ``(e1, e2)`` with ``(e1, e2, m)`` right-handed, for (K, 3) unit normals
    ``m``: ``e1`` the world axis least aligned with ``m``, made orthogonal to it."""
    m = np.atleast_2d(m)
    axis = np.eye(3)[np.argmin(np.abs(m), axis=1)]
    e1 = axis - np.sum(axis * m, axis=1, keepdims=True) * m
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(m, e1)], axis=1)


def _planes(model: TrackerModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(normals (K, 3), offsets (K,) [mm], tangent bases (K, 2, 3), |v| (K,)) of the model's planes."""
    lay = model.layout
    K = lay.contacts.planes
    if model.n_W_ref is None or model.n_W_ref.shape != (K, 3):
        raise ValueError(f"the model has no reference normals for its {K} planes (n_W_ref)")
    cols = lay.plane_columns(np.arange(K))
    t, d = model.p[cols[:, :2]], model.p[cols[:, 2]]
    E = tangent_basis(model.n_W_ref)
    v = model.n_W_ref + np.einsum("ki,kij->kj", t, E)
    norm = np.linalg.norm(v, axis=1)
    return v / norm[:, None], d, E, norm


def plane_normals(model: TrackerModel) -> tuple[np.ndarray, np.ndarray]:
    """The model's planes: unit normals (K, 3) and offsets (K,) [mm] in W."""
    n, d, _, _ = _planes(model)
    return n, d


def plane_residuals(model: TrackerModel, data: PlaneData) -> np.ndarray:
    """(n,) ``n_k . p_WQ - d_k - s`` [mm]: each row's signed distance minus the measured one."""
    n, d, _, _ = _planes(model)
    p_W = reflector_world(model, data.q, data.target)
    k = data.plane
    return np.sum(n[k] * p_W, axis=1) - d[k] - data.distance


def plane_jacobian(model: TrackerModel, data: PlaneData) -> tuple[np.ndarray, np.ndarray]:
    """Residuals and their Jacobian in closed form.

    Args:
        model: the model; its layout has the data's planes (``layout.contacts``), ``n_W_ref`` their
            reference normals.
        data: the plane rows.

    Returns:
        r: (n,) [mm]; H: (n, n_full) ``dr/dp`` [mm/rad, mm/mm].
    """
    n, d, E, norm = _planes(model)
    p_W, J = world_point_jacobian(model, data.q, data.target)
    k = data.plane
    nk = n[k]
    H = np.einsum("ni,nij->nj", nk, J)
    n_p = np.sum(nk * p_W, axis=1)
    e_p = np.einsum("nij,nj->ni", E[k], p_W)  # (n, 2): e_i . p
    n_e = np.einsum("nij,nj->ni", E[k], nk)  # (n, 2): n . e_i
    cols = model.layout.plane_columns(k)
    rows = np.arange(data.n)[:, None]
    H[rows, cols[:, :2]] = (e_p - n_e * n_p[:, None]) / norm[k][:, None]
    H[np.arange(data.n), cols[:, 2]] = -1.0
    return n_p - d[k] - data.distance, H


def plane_start(model: TrackerModel, data: PlaneData) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form start of every plane from ``model``'s tool points of its rows: the least-squares
    plane (normal: the smallest singular vector about the centroid), the normal pointing to the
    flange's side, the offset the mean of ``n . p - s``.

    Returns:
        normals (K, 3), offsets (K,) [mm].

    Raises:
        InputError: a plane whose rows' tool points lie on one line.
    """
    K = data.n_planes
    frames = model.frames(data.q)
    p_W = reflector_world(model, data.q, data.target)
    link = model.target_links(data.target)
    o_F = frames.at_link(link)[1]
    normals, offsets = np.zeros((K, 3)), np.zeros(K)
    for k in range(K):
        rows = np.flatnonzero(data.plane == k)
        x = p_W[rows] - p_W[rows].mean(axis=0)
        _, s, Vt = np.linalg.svd(x, full_matrices=False)
        if s[1] <= COLLINEAR_RTOL * max(s[0], 1e-300):
            raise InputError(
                f"{data.source}: plane {k} (0-based): its {rows.size} rows' tool points lie on one line; "
                "the plane through them is not determined"
            )
        n = Vt[-1]
        side = float(np.mean((o_F[rows] - p_W[rows]) @ n))
        if side < 0 or (side == 0 and n[np.argmax(np.abs(n))] < 0):
            n = -n
        normals[k] = n
        offsets[k] = float(np.mean(p_W[rows] @ n - data.distance[rows]))
    return normals, offsets
