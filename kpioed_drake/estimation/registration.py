"""The closed-form first registration of a fit: the tracker pose (rigid, Kabsch/Umeyama) and a
6-DoF probe's orientation on the flange (the chordal mean,
:func:`kpioed_drake.tracker.orientation.registered_probe`). Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world
from kpioed_drake.tracker.orientation import registered_probe


# ----------------------------------------------------------------------------------------------
def register_tracker(p_W: np.ndarray, p_T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform (no scaling) that best maps tracker-frame points onto world points.

    Minimises ``sum_i |p_W[i] - (R_WT p_T[i] + p_WT)|^2`` over proper rotations ``R_WT``
    (det = +1) and translations ``p_WT`` (Kabsch/Umeyama; if the unconstrained orthogonal optimum
    is a reflection, the axis of the smallest singular value is flipped).

    Args:
        p_W: (n, 3) points in W [mm] (e.g. nominal reflector positions).
        p_T: (n, 3) the same points measured in the tracker frame T [mm].

    Returns:
        R_WT (3, 3) and p_WT (3,) [mm], so that ``p_W ~= p_T @ R_WT.T + p_WT``.

    Raises:
        InputError: fewer than 3 points, mismatched shapes, or (nearly) collinear points.
    """
    p_W = np.asarray(p_W, dtype=float)
    p_T = np.asarray(p_T, dtype=float)
    if p_W.ndim != 2 or p_W.shape[1] != 3 or p_W.shape != p_T.shape:
        raise InputError(f"registration: expected two (n, 3) arrays, got {p_W.shape} and {p_T.shape}")
    if p_W.shape[0] < 3:
        raise InputError(f"registration: need at least 3 points, got {p_W.shape[0]}")
    c_W, c_T = p_W.mean(axis=0), p_T.mean(axis=0)
    A, B = p_T - c_T, p_W - c_W
    M = A.T @ B  # (3, 3) cross-covariance: sum a_i b_i^T
    U, S, Vt = np.linalg.svd(M)
    spread = np.linalg.svd(A, compute_uv=False)
    if spread[1] <= 1e-9 * max(spread[0], 1e-300):
        raise InputError("registration: the points are (nearly) collinear; the tracker pose is undetermined")
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d if d != 0 else 1.0])
    R_WT = Vt.T @ D @ U.T
    p_WT = c_W - R_WT @ c_T
    return R_WT, p_WT


def registered_model(
    model: TrackerModel, q: np.ndarray, eta: np.ndarray, *, target: np.ndarray | None, R_TP: np.ndarray | None
) -> TrackerModel:
    """``model`` with the tracker pose replaced by the registration of its reflector points to ``eta``.

    Small rotations zero, ``R_WT_ref`` the registered rotation; ``target``: (n,) each row's 0-based
    target. With a probe's measured orientations ``R_TP`` (n, 3, 3) and a probe layout, the probe's
    orientation on the flange too (:func:`~kpioed_drake.tracker.orientation.registered_probe`).
    """
    p_W = reflector_world(model, q, target)
    R_WT, p_WT = register_tracker(p_W, eta)
    p = model.p.copy()
    p[model.layout.tracker_position] = p_WT
    p[model.layout.tracker_rotation] = 0.0
    out = dataclasses.replace(model, p=p, R_WT_ref=R_WT)
    return out if R_TP is None or not model.layout.probe else registered_probe(out, q, R_TP)
