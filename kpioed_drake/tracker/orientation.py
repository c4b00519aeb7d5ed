"""The orientation part of a 6-DoF probe's measurement (a laser tracker's T-Mac): model, residual,
Jacobian, and the probe's first registration.

A 6-DoF probe measures, beside its origin (the reflector point of paper eq. 3, target 0's offset
``p_FQ``), the orientation of its frame P in the tracker frame T. The model:

    ``R_TP(p, q) = R_WT^T R_WF(q) R_FP``,  ``R_FP = small_rotation(r_FP) @ R_FP_ref``

with the flange orientation ``R_WF`` of the forward kinematics (eq. 1; a tree robot: target 0's
link), the tracker's orientation ``R_WT`` and the probe's three small rotations ``r_FP`` on the
flange (``probe_rx, probe_ry, probe_rz`` of :mod:`kpioed_drake.robot.parameters`, present when the
layout has ``probe``).

Residual of a row: the rotation vector ``e = log(R_meas R_model^T)`` (3,) [rad] in tracker axes,
the small rotation that takes the model's orientation to the measured one. Its derivative: a
parameter change turns the model by ``dw = Omega dp`` (tracker axes), and
``de = -Jr^-1(e) dw`` with the inverse right Jacobian of SO(3), so that the "model Jacobian"
:func:`orientation_jacobian` returns is ``Jr^-1(e) Omega`` (the position rows' convention:
residual = measured - model, d residual / dp = -H). ``Omega``'s columns in closed form:

- a joint's rotation element of unit axis ``u`` (W) on the probe link's path: ``R_TW u``;
  translation elements (and elements off the path): 0;
- the tracker's small rotations: ``vee(G_k Rr)``, ``G_k = d(Rr^T)/dr_k``;
- the probe's: ``R_TW R_WF vee(dS_k S^T)`` with ``S = small_rotation(r_FP)``;
- translations (tracker position, target offsets): 0.

Units: radians. Shapes: ``q`` (n, n_joints); outputs carry the row axis first.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from kpioed_drake.robot.kinematics import Frames, skew
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.tracker.measurement import TrackerModel, _drot_transposed, small_rotation

MEASURES = ("point", "pose")
"""What a pose of a design measures: the reflector point, or a 6-DoF probe's position and orientation."""
SMALL_ANGLE = 1e-4
"""Below this angle [rad] the inverse right Jacobian's coefficient takes its series value (1/12)."""


def vee(S: np.ndarray) -> np.ndarray:
    """(..., 3) the vector of (..., 3, 3) skew(-ish) matrices: ``(S21 - S12, S02 - S20, S10 - S01) / 2``."""
    return 0.5 * np.stack(
        [S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]], axis=-1
    )


def rotation_log(R: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors [rad] of (n, 3, 3) rotations (angle in [0, pi], axis times angle)."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def inverse_right_jacobian(e: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``Jr^-1(e) = I + [e]/2 + (1/t^2 - (1 + cos t)/(2 t sin t)) [e]^2`` of rotation
    vectors ``e`` (n, 3) [rad], ``t = |e|``: ``log(exp(e) exp(d)) = e + Jr^-1(e) d + O(d^2)``."""
    e = np.asarray(e, dtype=float)
    t = np.linalg.norm(e, axis=-1)
    small = t < SMALL_ANGLE
    ts = np.where(small, 1.0, t)
    c = np.where(small, 1.0 / 12.0 + t**2 / 720.0, 1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    E = skew(e)
    return np.eye(3) + 0.5 * E + c[..., None, None] * (E @ E)


def chordal_mean(R: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation nearest (Frobenius) to the mean of (n, 3, 3) rotations (a proper rotation)."""
    U, _, Vt = np.linalg.svd(np.mean(R, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def with_probe(model: TrackerModel, R_FP_ref: np.ndarray | None = None) -> TrackerModel:
    """``model`` with the probe's three small rotations in its layout (zero) and the reference
    ``R_FP_ref`` (default: the model's own, else the identity until :func:`registered_probe`).

    The layout keeps the model's held parameters and targets; ``extra_gauge`` (a points-only gauge) is
    no longer applied, and a chain robot's automatic gauge is replaced by its gauge with orientations.
    """
    lay = model.layout
    if lay.probe:
        return (
            model
            if R_FP_ref is None
            else dataclasses.replace(model, R_FP_ref=np.asarray(R_FP_ref, dtype=float))
        )
    rob = model.robot
    base = parameter_layout(rob, n_targets=lay.n_targets)
    gauge = set(base.names) - set(base.free_names)  # the points' gauge, not applied with orientations
    held = set(lay.names) - set(lay.free_names) - gauge
    layout = parameter_layout(rob, n_targets=lay.n_targets, probe=True)
    free = set(layout.free_names)
    fixed = tuple(n for n in layout.names if n not in free) + tuple(sorted(held))
    layout = parameter_layout(rob, fixed=fixed, n_targets=lay.n_targets, probe=True)
    ref = R_FP_ref if R_FP_ref is not None else (model.R_FP_ref if model.R_FP_ref is not None else np.eye(3))
    p = np.concatenate([model.p, np.zeros(3)])
    return dataclasses.replace(model, p=p, layout=layout, R_FP_ref=np.asarray(ref, dtype=float))


def probe_orientation(model: TrackerModel, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
    """(n, 3, 3) ``R_TP(p, q)``: the probe frame's orientation in the tracker frame the model predicts.

    Raises:
        ValueError: the model has no probe orientation (``R_FP_ref`` None).
    """
    R_FP = _R_FP(model)
    frames = model.frames(q) if frames is None else frames
    R_WF = frames.at_link(None)[0]
    return model.R_WT.T @ R_WF @ R_FP


def _R_FP(model: TrackerModel) -> np.ndarray:
    R_FP = model.R_FP
    if R_FP is None:
        raise ValueError("the model has no probe orientation (R_FP_ref): data without orientations")
    return R_FP


def registered_probe(model: TrackerModel, q: np.ndarray, R_TP: np.ndarray) -> TrackerModel:
    """``model`` (with a probe layout) with ``R_FP_ref`` the chordal mean of
    ``R_WF(q_i)^T R_WT R_TP_i`` over the rows (its tracker orientation as registered) and the
    probe's small rotations zero: the closed-form first registration of the probe on the flange."""
    R_WF = model.frames(q).at_link(None)[0]
    R = chordal_mean(np.swapaxes(R_WF, 1, 2) @ model.R_WT @ R_TP)
    p = model.p.copy()
    p[model.layout.probe_rotation] = 0.0
    return dataclasses.replace(model, p=p, R_FP_ref=R)


def orientation_residuals(
    model: TrackerModel, q: np.ndarray, R_TP: np.ndarray, *, frames: Frames | None = None
) -> np.ndarray:
    """(n, 3) ``log(R_meas R_model^T)`` [rad], tracker axes: the measured minus the modelled orientation."""
    R_model = probe_orientation(model, q, frames=frames)
    return rotation_log(np.asarray(R_TP, dtype=float) @ np.swapaxes(R_model, 1, 2))


def angular_jacobian(model: TrackerModel, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
    """(n, 3, n_full) ``Omega = dw/dp``: the model orientation's small rotation (tracker axes) per
    parameter [rad/rad, rad/mm] (the columns of the module docstring)."""
    lay = model.layout
    frames = model.frames(q) if frames is None else frames
    n = frames.R.shape[0]
    R_TW = model.R_WT.T
    Om = np.zeros((n, 3, lay.size))
    u = np.where(frames.elem_rot[None, :, :, None], frames.elem_u, 0.0)  # (n, nj, P, 3)
    on = frames.point_path(None)
    if on is not None:
        u = u * on[:, :, None, None]
    nj, P = frames.elem_rot.shape
    Om[:, :, lay.joints] = np.einsum("ab,ncb->nac", R_TW, u.reshape(n, nj * P, 3))
    r = model.p[lay.tracker_rotation]
    Rr = small_rotation(r)
    Om[:, :, lay.tracker_rotation] = np.stack([vee(G @ Rr) for G in _drot_transposed(r)], axis=-1)[None]
    if lay.probe:
        s = model.p[lay.probe_rotation]
        S = small_rotation(s)
        w_F = np.stack([vee(dS.T @ S.T) for dS in _drot_transposed(s)], axis=-1)  # (3, 3) columns k
        R_TF = R_TW @ frames.at_link(None)[0]
        Om[:, :, lay.probe_rotation] = R_TF @ w_F
    return Om


def orientation_jacobian(
    model: TrackerModel, q: np.ndarray, R_TP: np.ndarray, *, frames: Frames | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Orientation residuals and their model Jacobian.

    Args:
        model: the model (with a probe orientation).
        q: (n, n_joints) joint values [rad; mm].
        R_TP: (n, 3, 3) measured probe orientations in the tracker frame.
        frames: ``model.frames(q)`` if the caller has them.

    Returns:
        e: (n, 3) residuals ``log(R_meas R_model^T)`` [rad]; H: (n, 3, n_full) ``Jr^-1(e) Omega``,
        so that ``de/dp = -H``.
    """
    frames = model.frames(q) if frames is None else frames
    e = orientation_residuals(model, q, R_TP, frames=frames)
    return e, inverse_right_jacobian(e) @ angular_jacobian(model, q, frames=frames)


def world_orientation_errors(
    model: TrackerModel, q: np.ndarray, R_TP: np.ndarray, R_WT: np.ndarray
) -> np.ndarray:
    """(n, 3) ``log((R_WT R_meas) (R_WF R_FP)^T)`` [rad] in W axes: the measured orientations taken
    to W with the tracker frame ``R_WT`` ((3, 3), or (n, 3, 3) one per row: a cross-registration's
    halves) against the model's prediction (``model.R_FP``; its own tracker frame is not used)."""
    R_WP = model.frames(q).at_link(None)[0] @ _R_FP(model)
    return rotation_log(np.asarray(R_WT) @ np.asarray(R_TP, dtype=float) @ np.swapaxes(R_WP, 1, 2))


def angular_jacobian_dq(model: TrackerModel, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
    """(n, n_joints, 3, n_full) ``d Omega / d q_j`` of :func:`angular_jacobian` [rad/rad^2, ...].

    A revolute joint j turns every axis it moves by ``w_j x``: a joint element's column ``R_TW u``
    (element moved by j) becomes ``R_TW (w_j x u)``, the probe's ``R_TW R_WF w_F`` (joint j on the
    probe link's path) ``R_TW (w_j x R_WF w_F)``; prismatic joints, elements upstream of j and the
    tracker's columns: 0.
    """
    lay = model.layout
    frames = model.frames(q) if frames is None else frames
    n = frames.R.shape[0]
    nj, P = frames.elem_rot.shape
    R_TW = model.R_WT.T
    on = frames.point_path(None)
    u = np.where(frames.elem_rot[None, :, :, None], frames.elem_u, 0.0)  # (n, nj, P, 3)
    if on is not None:
        u = u * on[:, :, None, None]
    w = np.where(frames.prismatic[None, :, None], 0.0, frames.joint_axes)  # (n, nj, 3)
    if on is not None:
        w = w * on[:, :, None]
    Wx = skew(w)  # (n, nj, 3, 3)
    moved = frames.path[frames.moved_by].transpose(2, 0, 1).reshape(nj, nj * P)  # joint j moves element c
    turned = Wx @ u.reshape(n, 1, nj * P, 3).swapaxes(-1, -2)  # (n, nj, 3, nj P): w_j x u_c
    dOm = np.zeros((n, nj, 3, lay.size))
    dOm[..., lay.joints] = R_TW @ np.where(moved[None, :, None, :], turned, 0.0)
    if lay.probe:
        s = model.p[lay.probe_rotation]
        S = small_rotation(s)
        w_F = np.stack([vee(dS.T @ S.T) for dS in _drot_transposed(s)], axis=-1)  # (3, 3)
        dOm[..., lay.probe_rotation] = R_TW @ Wx @ (frames.at_link(None)[0] @ w_F)[:, None]
    return dOm


def tcp_angular_jacobian(model: TrackerModel, q_work: np.ndarray) -> np.ndarray:
    """(3, n_full) the TCP frame's small rotation in W per parameter at ``q_work`` (n_joints,)
    [rad/rad, rad/mm]: the angular Jacobian of the tool's orientation, the orientation KPI's
    ``Js_rot``. The tool is fixed to the flange and, with a probe (``layout.probe``), to the probe
    as the position KPI's TCP is to the reflector: its columns are the joints' rotation elements on
    the path (``u``, W), the probe's rotations (``R_WF w_F``) and 0 for the tracker and all
    translations (:func:`angular_jacobian` turned back to W, the tracker's columns zero).
    """
    Om = angular_jacobian(model, np.asarray(q_work, dtype=float)[None, :])[0]
    Js = model.R_WT @ Om
    Js[:, model.layout.tracker_rotation] = 0.0
    return Js
