"""Forward kinematics and the closed-form identification Jacobian, vectorised over poses.

Implements paper eq. (1) with the DH/Hayati transforms of SPEC:

- DH:     ``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
- Hayati: ``T_i = Rz(theta_i + q_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``

and the derivative of a point ``p_WP`` fixed in the flange frame F (frame 6) with respect to
every kinematic parameter, in closed form: a rotation element with unit axis ``u`` through point
``o`` contributes the column ``u x (p_WP - o)``, a translation element the column ``u``. The
derivative of those columns with respect to the joint angles (needed for design gradients) is
closed form too: with ``w_j = z_{j-1}`` the axis of joint j through ``o_{j-1}``,

- for an element of transform i and j <= i: ``d(col)/dq_j = w_j x col`` (the whole element turns);
- for j > i: rotation element ``u x (w_j x (p_WP - o_{j-1}))``, translation element 0.

Units: millimetres and radians. Shapes: ``q`` is ``(n, 6)``; outputs carry the pose axis first.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.models import N_JOINTS, Robot
from kpioed_drake.parameters import PER_JOINT


def cross(a, b) -> np.ndarray:
    """``a x b`` over the last axis (length 3), broadcast over leading axes.

    Written out by components: ``numpy.cross`` spends most of its time on axis handling for the
    small arrays of this package.
    """
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _rot_z(c, s):
    R = np.zeros((*np.shape(c), 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _rot_x(c, s):
    R = np.zeros((*np.shape(c), 3, 3))
    R[..., 0, 0], R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = 1.0, c, -s, s, c
    return R


def _rot_y(c, s):
    R = np.zeros((*np.shape(c), 3, 3))
    R[..., 0, 0], R[..., 0, 2], R[..., 1, 1], R[..., 2, 0], R[..., 2, 2] = c, s, 1.0, -s, c
    return R


@dataclasses.dataclass
class Frames:
    """Link frames and identification elements for n poses.

    Attributes:
        R: (n, 7, 3, 3) orientation of frames 0..6 in W (frame 0 = W).
        o: (n, 7, 3) origins of frames 0..6 in W [mm].
        elem_u: (n, 6, 4, 3) unit direction of each parameter element (joint-major, the joint's
            own parameter order).
        elem_o: (n, 6, 4, 3) point on the axis of rotation elements [mm] (unused for translations).
        elem_rot: (6, 4) True for rotation elements, False for translation elements.
    """

    R: np.ndarray
    o: np.ndarray
    elem_u: np.ndarray
    elem_o: np.ndarray
    elem_rot: np.ndarray

    @property
    def joint_axes(self) -> np.ndarray:
        """(n, 6, 3) axis of joint j (= z of frame j-1)."""
        return self.R[:, :N_JOINTS, :, 2]

    @property
    def joint_points(self) -> np.ndarray:
        """(n, 6, 3) a point on the axis of joint j (= origin of frame j-1) [mm]."""
        return self.o[:, :N_JOINTS]


def _as_poses(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.shape[-1] != N_JOINTS:
        raise ValueError(f"q must have shape (n, 6), got {q.shape}")
    return q


def forward_kinematics(robot: Robot, q, geometry: np.ndarray | None = None) -> Frames:
    """Frames of all links and the identification elements.

    Args:
        robot: the robot (its conventions; its nominal geometry unless ``geometry`` is given).
        q: (n, 6) or (6,) joint angles [rad].
        geometry: (6, 4) kinematic parameters in the robot's storage order [rad, mm]; defaults to
            ``robot.geometry``.
    """
    q = _as_poses(q)
    g = robot.geometry if geometry is None else np.asarray(geometry, dtype=float)
    n = q.shape[0]
    R = np.empty((n, N_JOINTS + 1, 3, 3))
    o = np.empty((n, N_JOINTS + 1, 3))
    R[:, 0] = np.eye(3)
    o[:, 0] = 0.0
    eu = np.empty((n, N_JOINTS, PER_JOINT, 3))
    eo = np.empty((n, N_JOINTS, PER_JOINT, 3))
    erot = np.zeros((N_JOINTS, PER_JOINT), dtype=bool)
    for i, conv in enumerate(robot.conventions):
        Rp, op = R[:, i], o[:, i]
        ang = g[i, 0] + q[:, i]
        Rz = _rot_z(np.cos(ang), np.sin(ang))
        RA = Rp @ Rz  # frame after Rz(theta + q)
        xA = RA[..., 0]
        zp = Rp[..., 2]
        if conv == "dh":
            _, d, a, alpha = g[i]
            Rx = _rot_x(np.cos(alpha), np.sin(alpha))  # (3, 3), the same for all poses
            oi = op + d * zp + a * xA
            Ri = RA @ Rx
            # theta: rot about z_{i-1} at o_{i-1}; d: along z_{i-1}; a: along x_A; alpha: rot x_A at o_i
            eu[:, i, 0], eu[:, i, 1], eu[:, i, 2], eu[:, i, 3] = zp, zp, xA, xA
            eo[:, i, 0], eo[:, i, 1], eo[:, i, 2], eo[:, i, 3] = op, op, oi, oi
            erot[i] = (True, False, False, True)
        else:
            _, a, alpha, beta = g[i]
            Rx = _rot_x(np.cos(alpha), np.sin(alpha))  # (3, 3), the same for all poses
            Ry = _rot_y(np.cos(beta), np.sin(beta))
            oi = op + a * xA
            RB = RA @ Rx
            Ri = RB @ Ry
            yB = RB[..., 1]
            # theta: rot z_{i-1} at o_{i-1}; a: along x_A; alpha: rot x_A at o_i; beta: rot y_B at o_i
            eu[:, i, 0], eu[:, i, 1], eu[:, i, 2], eu[:, i, 3] = zp, xA, xA, yB
            eo[:, i, 0], eo[:, i, 1], eo[:, i, 2], eo[:, i, 3] = op, oi, oi, oi
            erot[i] = (True, False, True, True)
        R[:, i + 1] = Ri
        o[:, i + 1] = oi
    return Frames(R=R, o=o, elem_u=eu, elem_o=eo, elem_rot=erot)


def flange_point(frames: Frames, p_FP) -> np.ndarray:
    """(n, 3) world position of a point given in the flange frame [mm].

    ``p_FP`` is (3,) or (n, 3) (one point per pose, e.g. each row's target).
    """
    p_FP = np.asarray(p_FP, dtype=float)
    if p_FP.ndim == 2:
        return frames.o[:, N_JOINTS] + np.einsum("nij,nj->ni", frames.R[:, N_JOINTS], p_FP)
    return frames.o[:, N_JOINTS] + np.einsum("nij,...j->ni", frames.R[:, N_JOINTS], p_FP)


def point_jacobian(frames: Frames, p_FP, *, with_dq: bool = False):
    """Jacobian of a flange-fixed point w.r.t. the joint parameters and its flange coordinates.

    Args:
        frames: result of :func:`forward_kinematics` for n poses.
        p_FP: (3,) point in the flange frame [mm] (e.g. the reflector), or (n, 3) one per pose.
        with_dq: also return the derivative of the Jacobian w.r.t. the joint angles.

    Returns:
        p_WP: (n, 3) [mm].
        J: (n, 3, g + 3) with ``g = 6 * PER_JOINT`` (24): columns ``0..g-1`` the joint parameters in
            storage order (the joint rows of :mod:`kpioed_drake.parameters`) [mm/rad or mm/mm],
            columns ``g..g+2`` the flange coordinates of the point [mm/mm].
        dJ (only with ``with_dq``): (n, 6, 3, g + 3), ``dJ[k, j] = dJ[k] / dq_j`` [mm/rad^2 ...].
    """
    p = flange_point(frames, p_FP)  # (n,3)
    u, o = frames.elem_u, frames.elem_o  # (n,6,4,3)
    rot = frames.elem_rot  # (6,4)
    col_rot = cross(u, p[:, None, None, :] - o)
    cols = np.where(rot[None, :, :, None], col_rot, u)  # (n,6,4,3)
    n = p.shape[0]
    g = N_JOINTS * PER_JOINT
    J = np.empty((n, 3, g + 3))
    J[:, :, :g] = cols.reshape(n, g, 3).transpose(0, 2, 1)
    RF = frames.R[:, N_JOINTS]
    J[:, :, g:] = RF
    if not with_dq:
        return p, J
    w = frames.joint_axes  # (n,6,3)
    ow = frames.joint_points
    dP = cross(w, p[:, None, :] - ow)  # (n,6,3): dp/dq_j
    dJ = np.zeros((n, N_JOINTS, 3, g + 3))
    # element of transform i, joint j <= i: w_j x col
    full = cross(w[:, :, None, None, :], cols[:, None, :, :, :])  # (n,j,i,4,3)
    # element of transform i, joint j > i: rotation: u x dP_j; translation: 0
    part = cross(u[:, None, :, :, :], dP[:, :, None, None, :])  # (n,j,i,4,3)
    part = np.where(rot[None, None, :, :, None], part, 0.0)
    jj = np.arange(N_JOINTS)[:, None]
    ii = np.arange(N_JOINTS)[None, :]
    mask = (jj <= ii)[None, :, :, None, None]
    d = np.where(mask, full, part)  # (n,j,i,4,3)
    dJ[:, :, :, :g] = d.reshape(n, N_JOINTS, g, 3).transpose(0, 1, 3, 2)
    dJ[:, :, :, g:] = cross(w[:, :, None, :], RF.transpose(0, 2, 1)[:, None, :, :]).transpose(0, 1, 3, 2)
    return p, J, dJ


def point_velocity_jacobian(frames: Frames, p_W: np.ndarray, link: np.ndarray) -> np.ndarray:
    """Derivative of world points attached to links w.r.t. the joint angles.

    Args:
        frames: frames for n poses.
        p_W: (n, m, 3) world positions [mm].
        link: (m,) index of the frame each point is attached to (-1 or 0 = fixed).

    Returns:
        (n, m, 6, 3): ``dp_W[k, i] / dq_j`` [mm/rad].
    """
    w = frames.joint_axes  # (n,6,3)
    ow = frames.joint_points
    d = cross(w[:, None, :, :], p_W[:, :, None, :] - ow[:, None, :, :])  # (n,m,6,3)
    active = np.arange(1, N_JOINTS + 1)[None, :] <= np.asarray(link)[:, None]  # (m,6)
    return d * active[None, :, :, None]
