"""Laser-tracker measurement model (paper eq. 3 and 4).

The parameter vector ``p`` and its layout (joint rows, tracker pose, reflector offset, the gauge
and the free subset) are defined in :mod:`kpioed_drake.robot.parameters`; :class:`TrackerModel` reads
its parts through the layout.

Model response (eq. 3): ``h(p, q) = R_WT^T (p_WQ(p, q) - p_WT)``, the reflector in the tracker
frame. Incidence (eq. 4): ``cos(beta) = z_F . (p_WT - p_WQ)/|p_WT - p_WQ| >= cos(30 deg)``.

Several targets (SMRs) per pose: ``p_WQ`` is the point of each row's target ``t`` (0-based index
into the targets of the layout; its offset ``p_FQ_t`` sits at ``layout.target(t)``). Functions
taking ``target=None`` measure target 0 (the reflector), exactly as with one target.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from kpioed_drake.robot.kinematics import (
    Frames,
    flange_point,
    forward_kinematics,
    point_jacobian,
)
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.parameters import FIXED_NAMES, N_FULL, ParameterLayout, parameter_layout  # noqa: F401  (re-exported: the layout's historical home)


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def small_rotation(r: np.ndarray) -> np.ndarray:
    """``Rx(r0) @ Ry(r1) @ Rz(r2)`` (3, 3)."""
    return _rot(0, r[0]) @ _rot(1, r[1]) @ _rot(2, r[2])


@dataclasses.dataclass(frozen=True)
class TrackerModel:
    """Robot + tracker + reflector: everything the measurement model needs.

    Attributes:
        robot: the robot (conventions, limits).
        p: (n_full,) parameter values [rad, mm] (33 for a six-joint robot).
        R_WT_ref: (3, 3) reference tracker orientation the small rotations refer to.
        layout: where each parameter sits in ``p`` and which are estimated.
        R_FP_ref: (3, 3) reference orientation of a 6-DoF probe's frame P on the flange the probe's
            small rotations refer to (``layout.probe``), or the model file's probe orientation, or
            None (no orientation known: points only).
        n_W_ref: (K, 3) reference unit normals in W of the contact planes the planes' tilts refer
            to (``layout.contacts``, :mod:`kpioed_drake.tracker.plane`), or None (no planes).
    """

    robot: Robot
    p: np.ndarray
    R_WT_ref: np.ndarray
    layout: ParameterLayout
    R_FP_ref: np.ndarray | None = None
    n_W_ref: np.ndarray | None = None

    @property
    def geometry(self) -> np.ndarray:
        """(n_joints, per_joint) joint rows [rad, mm]."""
        return self.p[self.layout.joints].reshape(self.layout.geometry_shape())

    @property
    def p_WT(self) -> np.ndarray:
        """(3,) tracker position in W [mm]."""
        return self.p[self.layout.tracker_position]

    @property
    def p_FP(self) -> np.ndarray:
        """(3,) where a payload's weight acts in the flange frame [mm] for the effects' gravity
        torques: the model file's ``payload_point_mm`` (a calibration with effects fixes it at its
        start's reflector offset, so that the fit and the file it writes agree), else the reflector
        offset."""
        point = self.robot.payload_point
        return self.p_FQ if point is None else point

    @property
    def R_WT(self) -> np.ndarray:
        """(3, 3) tracker orientation: the reference times the small rotations."""
        return self.R_WT_ref @ small_rotation(self.p[self.layout.tracker_rotation])

    @property
    def R_FP(self) -> np.ndarray | None:
        """(3, 3) the probe frame's orientation on the flange: ``small_rotation(r_FP) @ R_FP_ref``
        (the reference alone without the probe's parameters; None without a reference)."""
        if self.R_FP_ref is None or not self.layout.probe:
            return self.R_FP_ref
        return small_rotation(self.p[self.layout.probe_rotation]) @ self.R_FP_ref

    @property
    def p_FQ(self) -> np.ndarray:
        """(3,) reflector offset (target 0) in the flange frame [mm]."""
        return self.p[self.layout.target(0)]

    @property
    def target_offsets(self) -> np.ndarray:
        """(T, 3) offsets of every target in the flange frame [mm]."""
        return self.p[self.layout.targets].reshape(self.layout.n_targets, 3)

    def target_points(self, target: np.ndarray | None = None) -> np.ndarray:
        """Flange-frame offsets of the rows' targets: (3,) target 0 if ``target`` is None, else
        (n, 3) for the (n,) 0-based target indices [mm]."""
        if target is None:
            return self.p_FQ
        return self.target_offsets[check_targets(self.layout, target)]

    def target_links(self, target: np.ndarray | None = None) -> np.ndarray | None:
        """The frames the rows' targets are fixed in: None (the flange; a serial robot, or
        ``target`` None) or (n,) frame indices of a tree robot's targets on several links."""
        if target is None or self.robot.target_links is None:
            return None
        return self.robot.target_links[check_targets(self.layout, target)]

    def with_params(self, p: np.ndarray) -> TrackerModel:
        return dataclasses.replace(self, p=np.asarray(p, dtype=float))

    def rebased(self) -> TrackerModel:
        """Same model with the tracker's (and a probe's) small rotations folded into ``R_WT_ref``
        (``R_FP_ref``)."""
        p = self.p.copy()
        p[self.layout.tracker_rotation] = 0.0
        if not self.layout.probe:
            return dataclasses.replace(self, p=p, R_WT_ref=self.R_WT)
        p[self.layout.probe_rotation] = 0.0
        return dataclasses.replace(self, p=p, R_WT_ref=self.R_WT, R_FP_ref=self.R_FP)

    def frames(self, q: np.ndarray) -> Frames:
        return forward_kinematics(self.robot, q, self.geometry)


def check_targets(layout: ParameterLayout, target: np.ndarray | Sequence[int]) -> np.ndarray:
    """(n,) 0-based target indices as integers.

    Raises:
        ValueError: an index outside ``0 .. layout.n_targets - 1``.
    """
    t = np.asarray(target)
    if t.ndim != 1 or (t.size and (t.min() < 0 or t.max() >= layout.n_targets)):
        raise ValueError(f"target indices must be (n,) in 0..{layout.n_targets - 1}, got {t!r}")
    return t.astype(int)


def nominal_model(robot: Robot, cell: Cell) -> TrackerModel:
    """The nominal model: the robot's table, the cell's tracker pose and reflector offset (target
    0), and the robot file's further targets (``targets_mm``).

    An extended model file with ``estimated_errors`` is the model its fit estimated: the robot of
    its reference geometry (on which the effects are evaluated) with the file's rows as parameters
    (:mod:`kpioed_drake.robot.reference`). A model file's probe orientation (``probe_rpy_deg``) is the
    model's ``R_FP_ref`` (the layout holds no probe parameters:
    :func:`kpioed_drake.tracker.orientation.with_probe` adds them)."""
    R_FP = robot.R_FP
    ref = robot.reference
    geometry = robot.geometry if ref is None else ref.geometry
    robot = robot if ref is None else ref.robot
    layout = parameter_layout(robot)
    p = np.zeros(layout.size)
    p[layout.joints] = geometry.ravel()
    p[layout.tracker_position] = cell.p_WT
    p[layout.target(0)] = cell.p_FQ
    for t in range(1, layout.n_targets):
        p[layout.target(t)] = robot.targets[t]
    return TrackerModel(robot=robot, p=p, R_WT_ref=cell.R_WT, layout=layout, R_FP_ref=R_FP)


def hold_unused_targets(model: TrackerModel, target: np.ndarray | None) -> TrackerModel:
    """``model`` with the offsets of the targets no row measures held at nominal (not estimated).

    ``target``: (n,) 0-based target of each row (None: only target 0 is measured). A model with
    one target, or data using all of them, is returned unchanged.
    """
    lay = model.layout
    used = {0} if target is None else set(np.unique(target).tolist())
    unused = [t for t in range(lay.n_targets) if t not in used]
    if not unused:
        return model
    names = tuple(lay.names[i] for t in unused for i in range(lay.size)[lay.target(t)])
    held = tuple(n for i, n in enumerate(lay.names) if i not in set(lay.free.tolist()))
    layout = parameter_layout(
        model.robot, fixed=held + names, n_targets=lay.n_targets, probe=lay.probe, contacts=lay.contacts
    )
    return dataclasses.replace(model, layout=layout)


def reflector_world(model: TrackerModel, q: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) position in W of each row's target (``target`` (n,) 0-based; None: target 0) [mm]."""
    return flange_point(model.frames(q), model.target_points(target), model.target_links(target))


def world_point_jacobian(
    model: TrackerModel, q: np.ndarray, target: np.ndarray | None = None, *, frames: Frames | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The rows' target points in W and their Jacobian w.r.t. the full parameter vector.

    ``p_WQ(p, q)`` of eq. 3 before the tracker: no tracker column (nor any other) is nonzero but
    the joint rows' and the row's target offset's (``target`` (n,) 0-based; None: target 0).

    Returns:
        p_WQ: (n, 3) [mm]; J: (n, 3, n_full) dp_WQ/dp [mm/rad, mm/mm].
    """
    lay = model.layout
    frames = model.frames(q) if frames is None else frames
    p_WQ, JW = point_jacobian(frames, model.target_points(target), link=model.target_links(target))
    nj = lay.joints.stop
    J = np.zeros((p_WQ.shape[0], 3, lay.size))
    J[:, :, lay.joints] = JW[:, :, :nj]
    _set_target_columns(J, JW[:, :, nj : nj + 3], lay, target)
    return p_WQ, J


def measure(model: TrackerModel, q: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """Model response h(p, q) (eq. 3): (n, 3) target positions in the tracker frame [mm].

    ``target``: (n,) 0-based target index of each row (None: target 0, the reflector).
    """
    p_WQ = reflector_world(model, q, target)
    return (p_WQ - model.p_WT) @ model.R_WT


def _set_target_columns(H: np.ndarray, block: np.ndarray, layout: ParameterLayout, target) -> None:
    """Write the flange-offset columns ``block`` (n, ..., 3) of every row into its target's columns
    of ``H`` (n, ..., n_full); target 0 for all rows when ``target`` is None."""
    if target is None:
        H[..., layout.target(0)] = block
        return
    target = check_targets(layout, target)
    for t in range(layout.n_targets):
        rows = target == t
        H[rows, ..., layout.target(t)] = block[rows]


def tracker_jacobian(
    model: TrackerModel,
    p_WQ: np.ndarray,
    JW: np.ndarray,
    *,
    scale: np.ndarray | None = None,
    offset: np.ndarray | None = None,
    target: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Response in the tracker frame and its Jacobian w.r.t. the full parameter vector.

    ``h = R_TW (s p_WQ - p_WT - offset)``: the reflector points ``p_WQ``, optionally scaled about W
    by ``s`` (thermal expansion) and shifted by ``offset`` (tracker drift).

    Args:
        model: the model (tracker pose, layout).
        p_WQ: (n, 3) reflector points in W [mm].
        JW: (n, 3, n_joint_params + 3) their Jacobian from
            :func:`~kpioed_drake.robot.kinematics.point_jacobian`.
        scale: (n,) length scale s (default 1).
        offset: (n, 3) shift of the tracker origin in W [mm] (default 0).
        target: (n,) 0-based target of each row, whose offset columns the flange columns of
            ``JW`` fill (default: target 0).

    Returns:
        h: (n, 3) [mm]; H: (n, 3, n_full) dh/dp.
    """
    lay = model.layout
    nj = lay.joints.stop
    R_TW = model.R_WT.T
    x = p_WQ - model.p_WT
    if scale is not None:
        x = scale[:, None] * p_WQ - model.p_WT
    if offset is not None:
        x = x - offset
    h = x @ R_TW.T
    H = np.zeros((h.shape[0], 3, lay.size))
    H[:, :, lay.joints] = np.einsum("ab,nbc->nac", R_TW, JW[:, :, :nj])
    H[:, :, lay.tracker_position] = -R_TW
    H[:, :, lay.tracker_rotation] = _rotation_columns(model, h)
    _set_target_columns(H, np.einsum("ab,nbc->nac", R_TW, JW[:, :, nj : nj + 3]), lay, target)
    if scale is not None:
        H[:, :, lay.joints] *= scale[:, None, None]
        H[:, :, lay.targets] *= scale[:, None, None]
    return h, H


def _rotation_columns(model: TrackerModel, h: np.ndarray) -> np.ndarray:
    """(n, 3, 3) dh/dr_k of ``h = Rr^T v``, ``v = R_ref^T x = Rr h``: ``G_k v``, ``G_k = d(Rr^T)/dr_k``."""
    r = model.p[model.layout.tracker_rotation]
    v = h @ small_rotation(r).T
    return np.stack([v @ G.T for G in _drot_transposed(r)], axis=-1)


def measurement_jacobian(
    model: TrackerModel,
    q: np.ndarray,
    *,
    with_dq: bool = False,
    frames: Frames | None = None,
    target: np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    """Jacobian of :func:`measure` w.r.t. the full parameter vector (33 entries for six joints).

    ``frames`` is ``model.frames(q)`` if the caller has it already; ``target`` (n,) the 0-based
    target of each row (None: target 0).

    Returns:
        h: (n, 3) [mm].
        H: (n, 3, n_full) dh/dp.
        dH (with ``with_dq``): (n, n_joints, 3, n_full), derivative of H w.r.t. the joint angles.
    """
    lay = model.layout
    frames = model.frames(q) if frames is None else frames
    link = model.target_links(target)
    out = point_jacobian(frames, model.target_points(target), link=link, with_dq=with_dq)
    p_WQ, JW = out[0], out[1]
    h, H = tracker_jacobian(model, p_WQ, JW, target=target)
    if not with_dq:
        return h, H
    R_TW = model.R_WT.T
    nj = lay.joints.stop
    dJW = out[2]
    dH = np.zeros((h.shape[0], lay.n_joints, 3, lay.size))
    dH[..., lay.joints] = np.einsum("ab,njbc->njac", R_TW, dJW[..., :nj])
    _set_target_columns(dH, np.einsum("ab,njbc->njac", R_TW, dJW[..., nj : nj + 3]), lay, target)
    dp_dq = frames.joint_motion(p_WQ)  # (n, nj, 3)
    on = frames.point_path(link)
    if on is not None:
        dp_dq = dp_dq * on[:, :, None]
    dh_dq = dp_dq @ R_TW.T
    r = model.p[lay.tracker_rotation]
    dv = dh_dq @ small_rotation(r).T
    for k, G in enumerate(_drot_transposed(r)):
        dH[:, :, :, lay.tracker_rotation.start + k] = dv @ G.T
    return h, H, dH


def _drot_transposed(r) -> list[np.ndarray]:
    """``d(Rr^T)/dr_k`` for ``Rr = Rx(r0) Ry(r1) Rz(r2)``, k = 0, 1, 2."""
    Rx, Ry, Rz = _rot(0, r[0]), _rot(1, r[1]), _rot(2, r[2])
    Gx = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float)
    Gy = np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], dtype=float)
    Gz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=float)
    return [(Rx @ Gx @ Ry @ Rz).T, (Rx @ Ry @ Gy @ Rz).T, (Rx @ Ry @ Rz @ Gz).T]


def incidence_cosine(
    model: TrackerModel, q: np.ndarray, *, frames: Frames | None = None, target: np.ndarray | None = None
) -> np.ndarray:
    """(n,) cosine of the incidence angle between the reflector axis z_F and the line of sight
    (to each row's target; ``target`` None: target 0)."""
    frames = model.frames(q) if frames is None else frames
    link = model.target_links(target)
    p = flange_point(frames, model.target_points(target), link)
    g = model.p_WT - p
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    return np.einsum("ni,ni->n", frames.at_link(link)[0][..., 2], g)


def target_incidence(
    model: TrackerModel, q: np.ndarray, target: int, *, frames: Frames | None = None
) -> np.ndarray:
    """(n,) :func:`incidence_cosine` of every pose ``q`` (n, nj) to the target ``target`` (0-based);
    ``frames`` need to hold only the frame of the target's link
    (:attr:`~kpioed_drake.robot.models.Robot.target_frames`)."""
    frames = model.frames(q) if frames is None else frames
    if model.layout.n_targets == 1:
        return incidence_cosine(model, q, frames=frames)
    return incidence_cosine(model, q, frames=frames, target=np.full(frames.o.shape[0], target))


def incidence_cosines(model: TrackerModel, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
    """(n, T) :func:`incidence_cosine` of every pose to each of the model's T targets."""
    frames = model.frames(q) if frames is None else frames
    return np.stack(
        [target_incidence(model, q, t, frames=frames) for t in range(model.layout.n_targets)], axis=1
    )


def kpi_jacobian(
    model: TrackerModel, q_work: np.ndarray, tool_offset: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """The KPI: TCP position in W at ``q_work`` and its Jacobian w.r.t. the full parameter vector.

    The TCP is the reflector point plus ``tool_offset`` (flange axes, [mm]); the tracker parameters
    do not move it (their columns are zero).

    Returns:
        s: (3,) [mm]; Js: (3, n_full).
    """
    frames = model.frames(np.asarray(q_work, dtype=float)[None, :])
    p, J = point_jacobian(frames, model.p_FQ + np.asarray(tool_offset, dtype=float))
    lay = model.layout
    nj = lay.joints.stop
    Js = np.zeros((3, lay.size))
    Js[:, lay.joints] = J[0, :, :nj]
    Js[:, lay.target(0)] = J[0, :, nj : nj + 3]
    return p[0], Js
