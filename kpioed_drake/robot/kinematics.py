"""Forward kinematics and the closed-form identification Jacobian, vectorised over poses.

Implements paper eq. (1) with the DH/Hayati transforms of SPEC:

- DH:     ``T_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
- Hayati: ``T_i = Rz(theta_i + q_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``

and the derivative of a point ``p_WP`` fixed in the flange frame F (frame 6) with respect to
every kinematic parameter, in closed form: a rotation element with unit axis ``u`` through point
``o`` contributes the column ``u x (p_WP - o)``, a translation element the column ``u``. The
derivative of those columns with respect to the joint angles (needed for design gradients) is
closed form too: with ``w_j = z_{j-1}`` the axis of joint j through ``o_{j-1}``,

- for an element moved by joint j (of transform i and j <= i): ``d(col)/dq_j = w_j x col`` (the
  whole element turns);
- otherwise: rotation element ``u x (w_j x (p_WP - o_{j-1}))``, translation element 0.

A prismatic joint j (chain robots, :mod:`kpioed_drake.robot.chain`) moves downstream points by ``w_j``:
columns of elements it moves do not change, rotation columns of upstream elements change by
``u x w_j``, translation columns by 0. The same closed forms serve the chain robots, whose frames
and elements :func:`forward_kinematics` takes from :func:`kpioed_drake.robot.chain.chain_frames`.

Units: millimetres and radians (prismatic joints: millimetres). Shapes: ``q`` is
``(n, n_joints)``; outputs carry the pose axis first.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.robot.chain import chain_frames, chain_links, serial_paths
from kpioed_drake.robot.models import Robot


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
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


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices ``[v]x`` (``[v]x b = v x b``) of vectors ``v`` (..., 3)."""
    S = np.zeros((*v.shape, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


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
    """Link frames and identification elements for n poses of a robot of nj joints, P parameters each.

    Attributes:
        R: (n, nj + 1, 3, 3) orientation of frames 0..nj in W (frame 0 = W, frame nj = flange).
        o: (n, nj + 1, 3) origins of frames 0..nj in W [mm].
        elem_u: (n, nj, P, 3) unit direction of each parameter element (joint-major, the joint's
            own parameter order).
        elem_o: (n, nj, P, 3) point on the axis of rotation elements [mm] (unused for translations).
        elem_rot: (nj, P) True for rotation elements, False for translation elements.
        joint_axes: (n, nj, 3) axis w_j of joint j in W (DH: z of frame j-1).
        joint_points: (n, nj, 3) a point on the axis of joint j [mm] (DH: origin of frame j-1).
        prismatic: (nj,) True for prismatic joints.
        moved_by: (nj, P) the frame whose moving joints move the element (``path[moved_by]``;
            DH: every element of row i, frame i).
        path: (nj + 1, nj) ``path[f, j]``: joint j moves frame f (serial: ``j < f``; a tree robot's
            :attr:`kpioed_drake.robot.chain.Chain.paths`).
        tip: the frame of the flange (the link of target 0; serial: nj).
    """

    R: np.ndarray
    o: np.ndarray
    elem_u: np.ndarray
    elem_o: np.ndarray
    elem_rot: np.ndarray
    joint_axes: np.ndarray
    joint_points: np.ndarray
    prismatic: np.ndarray
    moved_by: np.ndarray
    path: np.ndarray | None = None
    tip: int | None = None

    def __post_init__(self):
        nj = self.n_joints
        if self.path is None:
            self.path = serial_paths(nj)
        if self.tip is None:
            self.tip = nj

    @property
    def n_joints(self) -> int:
        return int(self.prismatic.size)

    def repeated(self, times: int) -> Frames:
        """The frames of every pose ``times`` times in a row (poses ``0, 0, .., 1, 1, ..``): those
        of ``np.repeat(q, times, axis=0)`` without a second forward kinematics."""
        if times == 1:
            return self
        per_pose = ("R", "o", "elem_u", "elem_o", "joint_axes", "joint_points")
        return dataclasses.replace(self, **{f: np.repeat(getattr(self, f), times, axis=0) for f in per_pose})

    def point_path(self, link: int | np.ndarray | None = None) -> np.ndarray | None:
        """(n, nj) ``path[link]``: the joints that move points on ``link`` (scalar or (n,) one per
        pose; None: the tip); None when every joint does (the serial flange: no mask needed)."""
        f = self.tip if link is None else link
        if np.ndim(f) == 0 and f == self.n_joints and self.path[f].all():
            return None
        return np.broadcast_to(self.path[np.asarray(f, dtype=int)], (self.R.shape[0], self.n_joints))

    def axis_movers(self, joint: int) -> np.ndarray:
        """(nj,) bool: the joints that move joint ``joint``'s (1-based) axis, strictly before it."""
        before = self.path[joint].copy()
        before[joint - 1] = False
        return before

    def at_link(self, link: int | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(R (n, 3, 3), o (n, 3))`` of the frame ``link`` ((n,) one per pose, scalar, or None:
        the tip)."""
        f = self.tip if link is None else link
        if np.ndim(f) == 0:
            return self.R[:, int(f)], self.o[:, int(f)]
        k = np.arange(self.R.shape[0])
        f = np.asarray(f, dtype=int)
        return self.R[k, f], self.o[k, f]

    def joint_motion(self, p_W: np.ndarray) -> np.ndarray:
        """(n, ..., nj, 3) ``dp/dq_j`` of world points ``p_W`` (n, ..., 3) moved by every joint:
        ``w_j x (p - o_j)`` (revolute) or ``w_j`` (prismatic) [mm/rad, mm/mm]."""
        extra = p_W.ndim - 2
        w = self.joint_axes.reshape(self.joint_axes.shape[:1] + (1,) * extra + self.joint_axes.shape[1:])
        ow = self.joint_points.reshape(w.shape)
        rev = cross(w, p_W[..., None, :] - ow)
        if not self.prismatic.any():
            return rev
        return np.where(self.prismatic[:, None], np.broadcast_to(w, rev.shape), rev)


def link_paths(robot: Robot) -> np.ndarray:
    """(nj + 1, nj) ``path[f, j]``: joint j moves link frame f (:attr:`Frames.path`, without poses)."""
    return serial_paths(robot.n_joints) if robot.chain is None else robot.chain.paths


def parent_frame(robot: Robot, joint: int) -> int:
    """The frame of the link that carries joint ``joint`` (1-based): ``joint - 1`` of a serial
    robot, its parent joint's link in a tree (0: W)."""
    return joint - 1 if robot.chain is None else int(robot.chain.parents[joint - 1]) + 1


def subtree_links(robot: Robot, joint: int) -> np.ndarray:
    """The link frames joint ``joint`` (1-based) moves, ascending: ``joint .. nj`` of a serial robot,
    its own branch of a tree (the weights it carries)."""
    return np.flatnonzero(link_paths(robot)[:, joint - 1])


def _as_poses(q, n_joints: int) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.shape[-1] != n_joints:
        raise ValueError(f"q must have shape (n, {n_joints}), got {q.shape}")
    return q


def _repeats(q: np.ndarray) -> int:
    """``k`` > 1 when every pose of ``q`` (n, nj) is on k rows in a row (the rows of a pose's k
    targets, ``np.repeat(poses, k, axis=0)``), else 1."""
    n = q.shape[0]
    k = 1
    while k < n and np.array_equal(q[k], q[0]):
        k += 1
    if k == 1 or n % k or k == n:
        return 1
    blocks = q.reshape(n // k, k, -1)
    return k if np.array_equal(blocks, np.broadcast_to(blocks[:, :1], blocks.shape)) else 1


def forward_kinematics(robot: Robot, q: np.ndarray, geometry: np.ndarray | None = None) -> Frames:
    """Frames of all links and the identification elements.

    Args:
        robot: the robot (its conventions; its nominal geometry unless ``geometry`` is given).
        q: (n, nj) or (nj,) joint angles [rad] (prismatic joints [mm]).
        geometry: (nj, P) kinematic parameters in the robot's storage order [rad, mm]; defaults to
            ``robot.geometry``.
    """
    nj = robot.n_joints
    q = _as_poses(q, nj)
    times = _repeats(q)
    if times > 1:  # every pose on `times` rows in a row (its targets): the poses once, then repeated
        return forward_kinematics(robot, q[::times], geometry).repeated(times)
    g = robot.geometry if geometry is None else np.asarray(geometry, dtype=float)
    if robot.chain is not None:
        c = chain_frames(robot.chain, q, g)
        return Frames(
            c.R,
            c.o,
            c.elem_u,
            c.elem_o,
            c.elem_rot,
            c.axes,
            c.points,
            robot.chain.prismatic,
            c.moved_by,
            robot.chain.paths,
            robot.tip,
        )
    n = q.shape[0]
    R = np.empty((n, nj + 1, 3, 3))
    o = np.empty((n, nj + 1, 3))
    R[:, 0] = np.eye(3)
    o[:, 0] = 0.0
    P = robot.per_joint
    eu = np.empty((n, nj, P, 3))
    eo = np.empty((n, nj, P, 3))
    erot = np.zeros((nj, P), dtype=bool)
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
    moved = np.tile(np.arange(1, nj + 1)[:, None], (1, P))
    return Frames(R, o, eu, eo, erot, R[:, :nj, :, 2], o[:, :nj], np.zeros(nj, dtype=bool), moved)


def link_frames(robot: Robot, q: np.ndarray, *, path_to: int | None = None) -> Frames:
    """The link frames of :func:`forward_kinematics` (nominal geometry) for tests of where links
    are (incidence, feasibility of many random poses): on a chain robot the same ``R`` and ``o``,
    bit for bit, in about a third of the time, without the identification elements and joint axes
    (zero-length arrays: these frames serve no Jacobian); on a DH/Hayati robot all of
    :func:`forward_kinematics`.

    Args:
        robot: the robot; q: (n, nj) or (nj,) joint angles [rad] (prismatic joints [mm]).
        path_to: on a chain robot, only the frames on the path from W to this link frame
            (0..nj; the others NaN: :func:`kpioed_drake.robot.chain.chain_links`); None: all.
    """
    q = _as_poses(q, robot.n_joints)
    if robot.chain is None:
        return forward_kinematics(robot, q)
    R, o = chain_links(robot.chain, q, robot.geometry, path_to=path_to)
    n, nj = q.shape
    none = np.zeros((n, 0, 3))
    return Frames(
        R,
        o,
        np.zeros((n, 0, 7, 3)),
        np.zeros((n, 0, 7, 3)),
        np.zeros((0, 7), dtype=bool),
        none,
        none,
        robot.chain.prismatic,
        np.zeros((0, 7), dtype=int),
        robot.chain.paths,
        robot.tip,
    )


def flange_point(frames: Frames, p_FP: np.ndarray, link: int | np.ndarray | None = None) -> np.ndarray:
    """(n, 3) world position of a point given in the flange frame [mm].

    ``p_FP`` is (3,) or (n, 3) (one point per pose, e.g. each row's target); ``link`` the frame it
    is fixed in: None (the flange, ``frames.tip``), an index, or (n,) one per pose (the targets of a
    tree robot sit on several links).
    """
    p_FP = np.asarray(p_FP, dtype=float)
    R, o = frames.at_link(link)
    if p_FP.ndim == 2:
        return o + np.einsum("nij,nj->ni", R, p_FP)
    return o + np.einsum("nij,...j->ni", R, p_FP)


def point_jacobian(
    frames: Frames, p_FP: np.ndarray, *, link: int | np.ndarray | None = None, with_dq: bool = False
) -> tuple[np.ndarray, ...]:
    """Jacobian of a flange-fixed point w.r.t. the joint parameters and its flange coordinates.

    Args:
        frames: result of :func:`forward_kinematics` for n poses (nj joints, P parameters each).
        p_FP: (3,) point in the flange frame [mm] (e.g. the reflector), or (n, 3) one per pose.
        link: the frame the point is fixed in (None: the flange; an index or (n,) one per pose);
            the joints off its path (another arm of a tree) get zero columns.
        with_dq: also return the derivative of the Jacobian w.r.t. the joint variables.

    Returns:
        p_WP: (n, 3) [mm].
        J: (n, 3, g + 3) with ``g = nj * P`` (24 for the six-joint tables): columns ``0..g-1`` the
            joint parameters in storage order (the joint rows of :mod:`kpioed_drake.robot.parameters`)
            [mm/rad or mm/mm], columns ``g..g+2`` the flange coordinates of the point [mm/mm].
        dJ (only with ``with_dq``): (n, nj, 3, g + 3), ``dJ[k, j] = dJ[k] / dq_j`` [mm/rad^2 ...].
    """
    p = flange_point(frames, p_FP, link)  # (n,3)
    on = frames.point_path(link)  # None or (n, nj): the joints that move the point
    u, o = frames.elem_u, frames.elem_o  # (n,nj,P,3)
    rot = frames.elem_rot  # (nj,P)
    nj, P = rot.shape
    col_rot = cross(u, p[:, None, None, :] - o)
    cols = np.where(rot[None, :, :, None], col_rot, u)  # (n,nj,P,3)
    if on is not None:
        cols = cols * on[:, :, None, None]
    n = p.shape[0]
    g = nj * P
    J = np.empty((n, 3, g + 3))
    J[:, :, :g] = cols.reshape(n, g, 3).transpose(0, 2, 1)
    RF = frames.at_link(link)[0]
    J[:, :, g:] = RF
    if not with_dq:
        return p, J
    w = frames.joint_axes  # (n,nj,3)
    pris = frames.prismatic.any()
    dP = frames.joint_motion(p)  # (n,nj,3): dp/dq_j
    if on is not None:
        dP = dP * on[:, :, None]
    dJ = np.empty((n, nj, 3, g + 3))
    # element moved by joint j: revolute w_j x col, prismatic 0 (as batched products [w_j]x @ cols)
    Wx = skew(np.where(frames.prismatic[None, :, None], 0.0, w) if pris else w)  # (n,j,3,3)
    full = Wx @ J[:, None, :, :g]  # (n,j,3,g)
    # element upstream of joint j: rotation: u x dP_j = -[dP_j]x u; translation: 0
    uT = (u * rot[None, :, :, None]).reshape(n, g, 3).transpose(0, 2, 1)  # (n,3,g)
    if on is not None:  # elements off the point's path (another arm) stay zero
        uT = uT * np.repeat(on, P, axis=1)[:, None, :]
    part = -skew(dP) @ uT[:, None]  # (n,j,3,g)
    mask = frames.path[frames.moved_by].transpose(2, 0, 1).reshape(nj, g)  # joint j moves element c
    dJ[:, :, :, :g] = np.where(mask[None, :, None, :], full, part)
    dJ[:, :, :, g:] = Wx @ RF[:, None]  # columns w_j x (flange axes); prismatic joints 0
    if on is not None:
        dJ[:, :, :, g:] *= on[:, :, None, None]
    return p, J, dJ


def point_velocity_jacobian(frames: Frames, p_W: np.ndarray, link: np.ndarray) -> np.ndarray:
    """Derivative of world points attached to links w.r.t. the joint variables.

    Args:
        frames: frames for n poses.
        p_W: (n, m, 3) world positions [mm].
        link: (m,) index of the frame each point is attached to (-1 or 0 = fixed).

    Returns:
        (n, m, nj, 3): ``dp_W[k, i] / dq_j`` [mm/rad, mm/mm for prismatic joints].
    """
    d = frames.joint_motion(p_W)  # (n,m,nj,3)
    link = np.asarray(link, dtype=int)
    active = frames.path[np.maximum(link, 0)] & (link > 0)[:, None]  # (m,nj)
    return d * active[None, :, :, None]
