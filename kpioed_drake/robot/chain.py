"""Serial chains of revolute and prismatic joints (URDF robots): kinematics, error model and gauge.

A chain robot is a list of joint frames. Joint i has a fixed nominal placement ``X_{P_i J_i}`` in
the frame of link i-1 (``R_PJ``, ``p_PJ``: the URDF joint origin; link 0 is W, the base pose is
folded into joint 1's placement), a unit ``axis`` in J_i and a type. Link i's frame is J_i moved by
the joint: ``Rot(axis, q_i + off_i)`` (revolute) or ``Trans(axis (q_i + off_i))`` (prismatic).

Error model (paper eq. 1 generalised, 7 parameters per joint, in this order):

- ``off``: the joint-variable offset [rad or mm]; its column is dh/dq_i (as DH's theta);
- ``px, py, pz``: a translation of J_i along the nominal J_i axes [mm];
- ``rx, ry, rz``: small rotations of J_i about its x, then y, then z axis [rad], so that the
  placement is ``X_{P J} = X_PJ_nominal Trans(px, py, pz) Rx(rx) Ry(ry) Rz(rz)``.

The nominal values of all seven are 0. Every element is a rotation (unit axis ``u`` through a
point ``o``: column ``u x (p - o)``) or a translation (column ``u``), as the DH/Hayati elements of
:mod:`kpioed_drake.robot.kinematics`, so one closed form serves both. Placement elements of joint i are
upstream of joint i's motion; the offset is not.

Gauge: 7 per joint plus the tracker (6) and targets are far more than the data determine.
:func:`auto_gauge` chooses the estimated set by a rank-revealing QR of the column-normalised
Jacobian of a reflector on many seeded random poses (as FIGAROH chooses base parameters):
columns are taken in the preference order tracker, targets, then the joints from the base up
(offset, translations, rotations), and a column is kept only if it adds to the rank; the others
are held at nominal. Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
import functools
import threading

import numpy as np
import scipy.linalg

from kpioed_drake.robot.jointmap import JointMap

PER_JOINT = 7
"""Parameters per joint of a chain robot."""
ELEMENTS = ("off", "px", "py", "pz", "rx", "ry", "rz")
"""Names of a joint's parameters (suffixed with the joint number, e.g. ``off1``, ``rx3``)."""
GAUGE_POSES = 80
GAUGE_SEED = 20170710
GAUGE_RTOL = 1e-3
"""Relative threshold of :func:`auto_gauge` on the residual norm of a unit column: a column that
keeps less than this of its length outside the span of the kept ones is held. Exact dependencies
leave round-off (below 1e-8); a published URDF's rounded right angle (``rpy`` 1.571 for pi/2) leaves
about 2e-4, which no data can tell from the gauge (the shipped robots have no residual between
1e-10 and 1e-2)."""
ZERO_COLUMN = 1e-9
"""Columns shorter than this times the longest are zero (e.g. a joint that cannot move the reflector);
normalising their round-off to unit length would count it as rank."""
GENERIC_REFLECTOR = np.array([80.0, -60.0, 150.0])
"""Reflector offset [mm] for the automatic gauge when the model gives none (off every axis; the
URDF reader's)."""
_GENERIC_TRACKER = np.array([2730.88, 4554.68, 1397.67])
"""A tracker position for the rank test (any point in general position gives the same rank)."""


@dataclasses.dataclass(frozen=True)
class Chain:
    """Nominal joint frames of a serial chain (mm).

    Attributes:
        R_PJ: (n, 3, 3) orientation of joint frame J_i in link i-1's frame (link 0 = W).
        p_PJ: (n, 3) origin of J_i in link i-1's frame [mm].
        axis: (n, 3) unit joint axis in J_i.
        prismatic: (n,) True for prismatic joints (q in mm), False for revolute (q in rad).
        parent: (n,) 0-based index of the joint whose link carries joint i (-1: W), increasing
            order (``parent[i] < i``); None for a serial chain (``parent[i] = i - 1``). A tree is the
            union of the chains to several measured links (two arms on one torso).
    """

    R_PJ: np.ndarray
    p_PJ: np.ndarray
    axis: np.ndarray
    prismatic: np.ndarray
    parent: np.ndarray | None = None

    @property
    def n_joints(self) -> int:
        return int(self.prismatic.size)

    @property
    def parents(self) -> np.ndarray:
        """(n,) the parent joint of every joint (-1: W), serial or tree."""
        if self.parent is None:
            return np.arange(self.n_joints) - 1
        return np.asarray(self.parent, dtype=int)

    @functools.cached_property
    def paths(self) -> np.ndarray:
        """(n + 1, n) :func:`frame_paths` of :attr:`parents` (computed once per chain)."""
        return serial_paths(self.n_joints) if self.parent is None else frame_paths(self.parents)


def serial_paths(n: int) -> np.ndarray:
    """(n + 1, n) ``path[f, j] = j < f``: the :func:`frame_paths` of a serial chain of n joints."""
    return np.arange(n)[None, :] < np.arange(n + 1)[:, None]


def frame_paths(parent: np.ndarray) -> np.ndarray:
    """(n + 1, n) ``path[f, j]``: joint j moves link frame f (frame 0 = W, frame i + 1 = the link
    after joint i), for the parent joints ``parent`` (n,) (-1: W; ``parent[i] < i``).

    A serial chain gives ``path[f, j] = j < f``.
    """
    n = len(parent)
    path = np.zeros((n + 1, n), dtype=bool)
    for i, p in enumerate(parent):
        if not -1 <= p < i:
            raise ValueError(f"joint {i + 1}: parent {p + 1} must precede it (0 = W)")
        path[i + 1] = path[p + 1]
        path[i + 1, i] = True
    return path


def param_names(n_joints: int) -> list[str]:
    """``off1, px1, ..., rz1, off2, ...`` (7 per joint)."""
    return [f"{e}{i}" for i in range(1, n_joints + 1) for e in ELEMENTS]


def param_is_angle(chain: Chain) -> list[bool]:
    """Per joint parameter: True for angles (revolute offsets, rotations), False for lengths."""
    out = []
    for pris in chain.prismatic:
        out += [not pris, False, False, False, True, True, True]
    return out


def rot_axis(axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation about the unit ``axis`` (3,) by ``angle`` (...) [rad] (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    ang = np.asarray(angle, dtype=float)[..., None, None]
    return np.eye(3) + np.sin(ang) * K + (1.0 - np.cos(ang)) * (K @ K)


def _basic(k: int, angle: float) -> np.ndarray:
    return rot_axis(np.eye(3)[k], angle)


@dataclasses.dataclass
class ChainFrames:
    """Frames and elements of a chain for n poses (see :class:`kpioed_drake.robot.kinematics.Frames`)."""

    R: np.ndarray  # (n, nj+1, 3, 3)
    o: np.ndarray  # (n, nj+1, 3)
    elem_u: np.ndarray  # (n, nj, 7, 3)
    elem_o: np.ndarray  # (n, nj, 7, 3)
    elem_rot: np.ndarray  # (nj, 7)
    axes: np.ndarray  # (n, nj, 3) joint axes in W
    points: np.ndarray  # (n, nj, 3) joint origins o_J in W [mm]
    moved_by: np.ndarray  # (nj, 7) the frame whose moving joints move the element


def _joint_columns(chain: Chain, i: int, errors_i: np.ndarray) -> np.ndarray:
    """(3, 16) constants of joint ``i`` in its parent's frame: ``R_PA`` (3 columns), ``R_PB``'s y and
    ``R_PC``'s z columns (the placement rotations ``rx``, ``ry`` applied), ``R_PJ``, ``R_PJ K`` and
    ``R_PJ K^2`` (``K`` the axis's cross-product matrix; 3 columns each), the joint origin ``p_PJ``
    and the axis in the parent's frame."""
    _, px, py, pz, rx, ry, rz = errors_i
    MA = chain.R_PJ[i]
    MB = MA @ _basic(0, rx)
    MC = MB @ _basic(1, ry)
    MJ = MC @ _basic(2, rz)
    a = chain.axis[i]
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    MK = MJ @ K
    p = chain.p_PJ[i] + MA @ np.array([px, py, pz])
    return np.column_stack([MA, MB[:, 1], MC[:, 2], MJ, MK, MK @ K, p, MJ @ a])


COLUMNS_CACHED = 16
"""Chains and error sets whose joint constants :func:`joint_constants` keeps (a design or a fit
evaluates the same errors thousands of times; a fit's steps change them)."""
_LOCAL = threading.local()  # the cache, per thread


def joint_constants(chain: Chain, errors: np.ndarray) -> np.ndarray:
    """(nj, 3, 16) :func:`_joint_columns` of every joint of ``chain`` with ``errors`` (nj, 7),
    kept for the last :data:`COLUMNS_CACHED` chains and error sets (keyed by the chain object and
    the errors' bytes, per thread; read-only)."""
    errors = np.ascontiguousarray(errors, dtype=float)
    key = (id(chain), errors.tobytes())
    cache = _LOCAL.__dict__.setdefault("constants", {})
    hit = cache.get(key)
    if hit is not None and hit[0] is chain:
        return hit[1]
    G = np.stack([_joint_columns(chain, i, errors[i]) for i in range(chain.n_joints)])
    G.setflags(write=False)
    if len(cache) >= COLUMNS_CACHED:
        cache.pop(next(iter(cache)))
    cache[key] = (chain, G)
    return G


def _link_loop(
    chain: Chain, q: np.ndarray, errors: np.ndarray, joints: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joint loop of :func:`chain_frames`: link rotations ``R`` (nj+1, n, 3, 3) and origins
    ``o`` (nj+1, n, 3) [mm], joint-major, and every product ``G`` (nj, n, 3, 16) of a parent's
    rotation with a joint's constants.

    The loop does only what the next joint needs (one ``(3 n, 3) @ (3, 16)`` product of the
    parent's rotation with the joint's constants, and the joint's frame). ``joints`` (k,): the
    0-based joints it visits, ascending, each with its parent (None: all); the other joints' links
    and products are left unset (``numpy.empty``)."""
    n, nj = q.shape
    parent = chain.parents
    constants = joint_constants(chain, errors)
    s = q + errors[:, 0]
    sn = np.sin(s).T[:, :, None, None]  # (nj, n, 1, 1)
    cs = (1.0 - np.cos(s)).T[:, :, None, None]
    R = np.empty((nj + 1, n, 3, 3))  # joint-major while the loop runs: each slice contiguous
    o = np.empty((nj + 1, n, 3))
    R[0], o[0] = np.eye(3), 0.0
    G = np.empty((nj, n, 3, 16))  # every product of the parent's rotation with a constant
    for i in range(nj) if joints is None else joints:
        f = parent[i] + 1
        np.matmul(R[f].reshape(3 * n, 3), constants[i], out=G[i].reshape(3 * n, 16))
        Gi = G[i]
        oJ = o[f] + Gi[:, :, 14]
        if chain.prismatic[i]:
            R[i + 1] = Gi[:, :, 5:8]
            o[i + 1] = oJ + s[:, i, None] * Gi[:, :, 15]
        else:  # RJ @ rot_axis(axis, s) = RJ + sin(s) RJ K + (1 - cos(s)) RJ K^2
            R[i + 1] = Gi[:, :, 5:8] + sn[i] * Gi[:, :, 8:11] + cs[i] * Gi[:, :, 11:14]
            o[i + 1] = oJ
    return R, o, G


def chain_links(
    chain: Chain, q: np.ndarray, errors: np.ndarray, *, path_to: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The link frames of :func:`chain_frames` alone (the same numbers, bit for bit, about a third
    of its time on many poses): rotations (n, nj+1, 3, 3) and origins (n, nj+1, 3) [mm] of ``q``
    (n, nj) [rad or mm] with placement errors ``errors`` (nj, 7).

    ``path_to``: a link frame (0..nj) whose path from W alone is computed (the joints that move it,
    :attr:`Chain.paths`; another arm of a tree is skipped): the frames of W and of those joints'
    links are the same numbers, the others NaN. None: all frames."""
    joints = None if path_to is None else np.flatnonzero(chain.paths[path_to])
    R, o, _ = _link_loop(chain, q, errors, joints)
    if joints is not None:
        off = np.ones(chain.n_joints + 1, dtype=bool)
        off[0], off[joints + 1] = False, False
        R[off], o[off] = np.nan, np.nan
    return np.ascontiguousarray(R.transpose(1, 0, 2, 3)), np.ascontiguousarray(o.transpose(1, 0, 2))


def chain_frames(chain: Chain, q: np.ndarray, errors: np.ndarray) -> ChainFrames:
    """Forward kinematics of a chain with placement errors.

    The link frames come from the joint loop (:func:`_link_loop`); the elements are filled from
    all joints' products at once after it.

    Args:
        chain: nominal joint frames.
        q: (n, nj) joint variables [rad or mm].
        errors: (nj, 7) parameters ``off, px, py, pz, rx, ry, rz`` per joint [rad, mm].
    """
    n, nj = q.shape
    parent = chain.parents
    R, o, G = _link_loop(chain, q, errors)
    G = G.transpose(1, 0, 2, 3)  # (n, nj, 3, 16)
    axes = np.ascontiguousarray(G[..., 15])
    pts = np.ascontiguousarray(o[parent + 1].transpose(1, 0, 2) + G[..., 14])
    eu = np.empty((n, nj, PER_JOINT, 3))
    eu[:, :, 0] = axes
    eu[:, :, 1:4] = np.swapaxes(G[..., 0:3], -1, -2)  # RA's columns
    eu[:, :, 4] = eu[:, :, 1]  # then RA's x, RB's y and RC's z columns
    eu[:, :, 5], eu[:, :, 6] = G[..., 3], G[..., 4]
    eo = np.ascontiguousarray(np.broadcast_to(pts[:, :, None, :], (n, nj, PER_JOINT, 3)))
    rot = np.tile(np.array([True, False, False, False, True, True, True]), (nj, 1))
    rot[:, 0] = ~np.asarray(chain.prismatic, dtype=bool)
    moved = np.tile(parent[:, None] + 1, (1, PER_JOINT))  # placement: moved as the parent link
    moved[:, 0] = np.arange(1, nj + 1)  # the offset: as the joint's own link
    R = np.ascontiguousarray(R.transpose(1, 0, 2, 3))
    o = np.ascontiguousarray(o.transpose(1, 0, 2))
    return ChainFrames(R, o, eu, eo, rot, axes, pts, moved)


def auto_gauge(
    chain: Chain,
    lower: np.ndarray,
    upper: np.ndarray,
    p_FQ: np.ndarray,
    *,
    n_poses: int = GAUGE_POSES,
    seed: int = GAUGE_SEED,
    rtol: float = GAUGE_RTOL,
    joint_map: JointMap | None = None,
    links: np.ndarray | None = None,
    orientation: bool = False,
) -> tuple[str, ...]:
    """Names of the joint parameters held at nominal: those that do not add to the rank.

    The Jacobian of the reflector ``p_FQ`` [mm] ((3,), or (T, 3) for T targets each measured at
    every pose) in W, with the tracker's six columns ``-I`` and ``(p - p_WT) x e_k`` and the
    targets' three each, at ``n_poses`` seeded poses uniform in the limits is column-normalised;
    columns are visited in the preference order of the module docstring and kept when their
    residual after projection on the kept ones exceeds ``rtol``. The number kept equals the rank
    of a column-pivoted QR (checked). With a ``joint_map`` (:class:`~kpioed_drake.robot.jointmap.JointMap`,
    e.g. of ``<mimic>`` joints) the poses are those the controller can command: its axes drawn in
    the limits of the first joint each drives, mapped to joint values, clipped to the limits.
    ``links`` (T,): the frame each target is fixed in (a tree's targets on several links; None: the
    last joint's link). ``orientation``: a 6-DoF probe's orientations are measured too (at target
    0's link): rows of the probe frame's rotation (times :data:`ORIENTATION_ROW_MM`) and the
    probe's three rotation columns join, so that what only the orientations see is kept.
    """
    nj = chain.n_joints
    q = _gauge_poses(lower, upper, n_poses, np.random.default_rng(seed), joint_map, nj)
    targets = np.atleast_2d(np.asarray(p_FQ, dtype=float))
    A = _gauge_jacobian(chain, q, targets, links)
    n_always = 6 + 3 * targets.shape[0]
    if orientation:
        A = _with_orientation_rows(chain, q, A, links, n_always)
        n_always += 3
    norms = np.linalg.norm(A, axis=0)
    live = norms > ZERO_COLUMN * norms.max()  # an exactly zero column (round-off) stays zero
    A = np.where(live, A / np.where(live, norms, 1.0), 0.0)
    kept, held = _kept_columns(A, rtol, param_names(nj), n_always)
    _, Rq, _ = scipy.linalg.qr(A, mode="economic", pivoting=True)
    dq = np.abs(np.diag(Rq))
    rank = int(np.sum(dq > rtol * dq[0]))
    found = int(kept.sum())
    if rank != found:
        raise ValueError(
            f"gauge selection found rank {found}, pivoted QR {rank}; it would hold {', '.join(held)}"
        )
    return tuple(held)


def _gauge_poses(
    lower: np.ndarray,
    upper: np.ndarray,
    n_poses: int,
    rng: np.random.Generator,
    joint_map: JointMap | None,
    nj: int,
) -> np.ndarray:
    """(n_poses, nj) joint values for :func:`auto_gauge`: uniform in the limits, or through the
    ``joint_map`` from controller axes drawn in the limits of the first joint each drives."""
    if joint_map is None:
        return rng.uniform(lower, upper, size=(n_poses, nj))
    A, b = joint_map.A, joint_map.b
    first = np.argmax(A != 0, axis=0)  # the first joint each axis drives
    f = A[first, np.arange(A.shape[1])]
    lo_ax, up_ax = np.sort(np.stack([(lower[first] - b[first]) / f, (upper[first] - b[first]) / f]), axis=0)
    return np.clip(rng.uniform(lo_ax, up_ax, size=(n_poses, A.shape[1])) @ A.T + b, lower, upper)


def _gauge_jacobian(chain: Chain, q: np.ndarray, targets: np.ndarray, links: np.ndarray | None) -> np.ndarray:
    """(3 T n_poses, 6 + 3 T + 7 nj) Jacobian of the ``targets`` (T, 3) [mm] at the poses ``q``:
    the tracker's columns, the targets' and the joints' (``links``: each target's frame)."""
    n_poses, nj = q.shape
    fr = chain_frames(chain, q, np.zeros((nj, PER_JOINT)))
    T = targets.shape[0]
    links = np.full(T, nj) if links is None else np.broadcast_to(np.asarray(links, dtype=int), (T,))
    path = chain.paths
    blocks = []
    for t, p_t in enumerate(targets):
        f = links[t]
        p = fr.o[:, f] + np.einsum("nij,j->ni", fr.R[:, f], p_t)
        d = p[:, None, None, :] - fr.elem_o
        cols = np.where(fr.elem_rot[None, :, :, None], np.cross(fr.elem_u, d), fr.elem_u)
        cols = cols * path[f][None, :, None, None]
        joint_cols = cols.reshape(n_poses, nj * PER_JOINT, 3).transpose(0, 2, 1)
        eye = np.broadcast_to(np.eye(3), (n_poses, 3, 3))
        tracker_rot = np.cross((p - _GENERIC_TRACKER)[:, None, :], np.eye(3)[None]).transpose(0, 2, 1)
        target_cols = np.zeros((n_poses, 3, 3 * T))
        target_cols[:, :, 3 * t : 3 * t + 3] = fr.R[:, f]
        blocks.append(np.concatenate([-eye, tracker_rot, target_cols, joint_cols], axis=2))
    return np.concatenate(blocks, axis=0).reshape(3 * T * n_poses, -1)


ORIENTATION_ROW_MM = 1000.0
"""Length [mm] the rotation rows of :func:`auto_gauge` with orientations are scaled by (a reach), so
that a rotation weighs as the displacement it causes at a metre."""


def _with_orientation_rows(
    chain: Chain, q: np.ndarray, A: np.ndarray, links: np.ndarray | None, n_always: int
) -> np.ndarray:
    """``A`` (points' rows, columns tracker, targets, joints) with the probe frame's rotation rows
    (in W, times :data:`ORIENTATION_ROW_MM`) and the probe's three rotation columns after the targets'
    (the tracker's small rotation ``d`` about its origin turns the measured frame by ``-d``, as it
    moves a point by ``(p - p_WT) x d``)."""
    n_poses, nj = q.shape
    fr = chain_frames(chain, q, np.zeros((nj, PER_JOINT)))
    f = nj if links is None else int(np.asarray(links, dtype=int).reshape(-1)[0])
    u = np.where(fr.elem_rot[None, :, :, None], fr.elem_u, 0.0) * chain.paths[f][None, :, None, None]
    joint = u.reshape(n_poses, nj * PER_JOINT, 3).transpose(0, 2, 1)
    tracker = np.concatenate(
        [np.zeros((n_poses, 3, 3)), np.broadcast_to(-np.eye(3), (n_poses, 3, 3))], axis=2
    )
    rows = np.concatenate([tracker, np.zeros((n_poses, 3, n_always - 6)), joint], axis=2)
    rows = ORIENTATION_ROW_MM * rows.reshape(3 * n_poses, -1)
    probe = np.concatenate(
        [np.zeros((A.shape[0], 3)), ORIENTATION_ROW_MM * fr.R[:, f].reshape(3 * n_poses, 3)]
    )
    full = np.concatenate([A, rows], axis=0)
    return np.concatenate([full[:, :n_always], probe, full[:, n_always:]], axis=1)


def independent_columns(A: np.ndarray, rtol: float) -> np.ndarray:
    """(k,) bool: the columns of ``A`` (m, k; unit length, or zero) that add to the span of the kept
    ones before them, in order: their residual after projection on those (Gram-Schmidt, twice for
    orthogonality) exceeds ``rtol``."""
    basis: list[np.ndarray] = []
    kept = np.zeros(A.shape[1], dtype=bool)
    for k in range(A.shape[1]):
        v = A[:, k].copy()
        for _ in range(2):
            for b in basis:
                v -= (b @ v) * b
        r = np.linalg.norm(v)
        if r > rtol:
            basis.append(v / r)
            kept[k] = True
    return kept


def _kept_columns(A: np.ndarray, rtol: float, names: list[str], n_fixed: int) -> tuple[np.ndarray, list[str]]:
    """:func:`independent_columns` of ``A`` and the names of the joint columns held; the first
    ``n_fixed`` (tracker, targets) must all be kept."""
    kept = independent_columns(A, rtol)
    if not kept[:n_fixed].all():
        raise ValueError("tracker or target columns are dependent: reflector or chain degenerate")
    return kept, [names[k - n_fixed] for k in np.flatnonzero(~kept) if k >= n_fixed]
