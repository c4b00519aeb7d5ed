"""Lateral joint compliance without trusting the model file's masses: a moment basis per joint.

``lateral_compliance:j`` (:mod:`.compliance`) turns everything joint j carries about the axis point
``C = a_j`` by ``omega = c P M_j`` (``P = I - a a^T``, ``a`` the joint axis in W) with the gravity
moment of links k = j..n about C,

    M_j(q) = 1e-3 sum_k  m_k (o_k - C) x g  +  (R_k (m_k c_k)) x g   =  X_j^full(q) pi_j   [N m]

linear in the first mass moments ``pi_j = (m_k, m_k c_k)_k`` [kg, kg mm] of those links (the same
moments as :mod:`.gravity_basis`). Not every combination is seen by ``P M_j``: the columns of
``P X_j^full`` (scaled to unit RMS over the reference poses, the 3 components of every pose as
rows) are reduced by an SVD to their ``r_j`` independent directions ``V_j``, and the effect
``lateral_compliance_basis:j`` turns the carried links by

    omega(q) = P(q) X_j^full(q) (V_j / D_j) theta,   theta (r_j,) [rad]

(``theta = c V_j^T D_j pi_j`` for the physical form). Every parameter is a rigid rotation about C,
so each is one :class:`~.compliance.Rotation` and the measurement model treats it as a compliance.
A rotation that is the same in the frame of the link before joint j, or in joint j's own frame, at
every pose tilts the joint's axis or the next frame as the geometric parameters do, so the SVD runs
on the regressor with those parts projected out: the basis keeps what the geometry cannot take.
Like the joint basis, it is sized on the data's own poses where the reference basis is singular on
them (:func:`size_on_poses`) and stored with the values in a model file. A payload that is the same
at every pose is a link moment (in the span); one that varies is not supported.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from kpioed_drake.effects.basis_store import ReducedBasis, own_basis, with_basis
from kpioed_drake.effects.compliance import Rotation
from kpioed_drake.effects.gravity import gravity_model, memoized, nominal_frames, reference_poses, robot_key
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import cross, parent_frame, subtree_links
from kpioed_drake.robot.models import Robot

FAMILY = "lateral_compliance_basis"
_N_REF = 500
_RANK_TOL = 1e-7
"""Relative singular value below which a direction of the moments is not seen across the axis."""
_POSE_RANK_TOL = 1e-5
"""The same on the data's poses (rounded angles, see :data:`.gravity_basis._POSE_RANK_TOL`)."""
_CACHE: dict = {}


def moment_regressor(
    robot: Robot, q: np.ndarray, joint: int, *, with_dq: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`_moment_regressor`, memoized (:func:`~.gravity.memoized`; read-only arrays)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return memoized(
        "moment",
        robot,
        q,
        (int(joint), bool(with_dq)),
        lambda: _moment_regressor(robot, q, joint, with_dq=with_dq),
    )


def _moment_regressor(robot: Robot, q, joint: int, *, with_dq: bool = False):
    """``P X_j^full`` of joint ``joint`` (1-based, revolute) at poses ``q`` (n, nj) [rad, mm].

    Returns:
        X (n, 3, 4 L) [N m per kg, N m per kg mm] (L links from ``joint`` on, columns per link
        ``m, m c_x, m c_y, m c_z``), the pivots C (n, 3) [mm]; with ``with_dq`` also dX
        (n, nj, 3, 4 L) and dC (n, nj, 3).
    """
    if robot.prismatic[joint - 1]:
        raise InputError(f"{FAMILY}:{joint}: joint {joint} of {robot.name} is prismatic, not a bearing")
    q = np.atleast_2d(np.asarray(q, dtype=float))
    fr = nominal_frames(robot, q)
    g = gravity_model(robot).g
    n, nj, k = q.shape[0], fr.n_joints, joint
    C, a = fr.joint_points[:, k - 1], fr.joint_axes[:, k - 1]
    links = subtree_links(robot, k)  # the links joint k carries
    o, R = fr.o[:, links], fr.R[:, links]  # (n, L, 3), (n, L, 3, 3)
    cols = np.concatenate([(o - C[:, None])[:, :, None, :], R.transpose(0, 1, 3, 2)], axis=2)  # (n,L,4,3)
    raw = 1e-3 * cross(cols, g)  # (n, L, 4, 3): the moment of each first-moment component
    P = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
    X = np.einsum("nab,nlcb->nalc", P, raw).reshape(n, 3, -1)
    if not with_dq:
        return X, C
    moved = fr.path[links]  # (L, nj): joint i moves link l
    dC = np.where(fr.axis_movers(k)[None, :, None], fr.joint_motion(C), 0.0)  # (n, nj, 3): C moves
    vo = np.where(moved[None, :, :, None], fr.joint_motion(o), 0.0) - dC[:, None]  # (n, L, nj, 3)
    w = fr.joint_axes[:, None, :, None, :]  # (n, 1, nj, 1, 3)
    rev = ~fr.prismatic[None, None, :, None, None] & moved[None, :, :, None, None]
    dR = np.where(rev, cross(w, R.transpose(0, 1, 3, 2)[:, :, None]), 0.0)  # (n, L, nj, 3 cols, 3)
    dcols = np.concatenate([vo[:, :, :, None, :], dR], axis=3)  # (n, L, nj, 4, 3)
    draw = 1e-3 * cross(dcols, g)
    dX = np.einsum("nab,nljcb->njalc", P, draw).reshape(n, nj, 3, -1)
    for i in range(k - 1):  # the joints before j turn the axis: dP = -(da a^T + a da^T)
        if fr.prismatic[i]:
            continue
        da = cross(fr.joint_axes[:, i], a)
        flat = raw.reshape(n, -1, 3)  # (n, 4 L, 3)
        dPm = -(da[:, None, :] * np.einsum("na,npa->np", a, flat)[..., None])
        dPm -= a[:, None, :] * np.einsum("na,npa->np", da, flat)[..., None]
        dX[:, i] += dPm.transpose(0, 2, 1)
    return X, C, dX, dC


@dataclasses.dataclass(frozen=True)
class LateralBasis(ReducedBasis):
    """The identifiable moment basis of one joint's lateral compliance (:class:`ReducedBasis`)."""

    def rotations(
        self, robot: Robot, q: np.ndarray, *, with_dq: bool = False, on: np.ndarray | None = None
    ) -> list[Rotation]:
        """The :class:`~.compliance.Rotation` of each parameter at poses ``q`` (n, nj); with ``on``
        (n,) 0/1, zero on the rows whose point the joint does not carry (another arm of a tree).
        Without ``with_dq`` memoized (:func:`~.gravity.memoized`; a fit's iterations ask for the
        same poses again): the rotations depend on the commanded poses and the basis only."""
        if not with_dq:
            key = (int(self.joint), self.D.tobytes(), self.V.tobytes(), None if on is None else on.tobytes())
            M, C = memoized("lateral_m", robot, np.asarray(q, float), key, lambda: self._m(robot, q, on))
            return [Rotation(M[r], C) for r in range(self.rank)]
        out = moment_regressor(robot, q, self.joint, with_dq=with_dq)
        T = self.V / self.D[:, None]
        m = np.einsum("nap,pr->nra", out[0], T)
        if not with_dq:
            return [Rotation(m[:, r], out[1]) for r in range(self.rank)]
        dm = np.einsum("njap,pr->nrja", out[2], T)
        if on is not None:
            m, dm = m * on[:, None, None], dm * on[:, None, None, None]
        return [Rotation(m[:, r], out[1], dm[:, r], out[3]) for r in range(self.rank)]

    def _m(self, robot: Robot, q: np.ndarray, on: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(r, n, 3) rotation vectors per unit parameter (times ``on``) and the pivots (n, 3)."""
        X, C = moment_regressor(robot, q, self.joint)
        M = np.einsum("nap,pr->rna", X, self.V / self.D[:, None])
        return (M if on is None else M * on[None, :, None]), C


def _reduced(X: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(D, V)`` of a regressor ``X`` (n, 3, p): column RMS over the 3 n rows and the right
    singular vectors of the scaled columns above ``tol`` times the largest singular value."""
    A = X.reshape(-1, X.shape[-1])
    D = np.sqrt(np.mean(A**2, axis=0))
    keep = D > 1e-12 * max(float(D.max()), 1e-300)
    D = np.where(keep, D, 1.0)
    _, s, Vt = np.linalg.svd(A / D * keep, full_matrices=False)
    big = s > tol * s[0] if s.size and s[0] > 1e-12 else np.zeros_like(s, dtype=bool)
    return D, Vt[big].T


def _varying(robot: Robot, q, joint: int) -> np.ndarray:
    """(n, 3, p) the part of the regressor at ``q`` that the geometric parameters cannot take: in
    the frame of the link before ``joint``, a rotation fixed in that frame or in the joint's own
    frame (whose axes there are the columns of ``R_{j-1}^T R_j``; j - 1: the parent link of a tree)
    tilts the joint's axis or the next frame as the joint rows' parameters do; those six pose
    functions are projected out."""
    X, _ = moment_regressor(robot, q, joint)
    fr = nominal_frames(robot, q)
    R0, R1 = fr.R[:, parent_frame(robot, joint)], fr.R[:, joint]
    Xf = np.einsum("nba,nbp->nap", R0, X)
    n = Xf.shape[0]
    G = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), np.einsum("nba,nbc->nac", R0, R1)], axis=2)
    A, Gm = Xf.reshape(3 * n, -1), G.reshape(3 * n, -1)
    A = A - Gm @ np.linalg.lstsq(Gm, A, rcond=None)[0]
    return A.reshape(Xf.shape)


def lateral_basis(robot: Robot, joint: int) -> LateralBasis:
    """The robot's own basis of ``joint`` (sized on data, or a model file's), else the (cached)
    reference basis over :data:`_N_REF` seeded poses in the joint box."""
    own = own_basis(robot, f"{FAMILY}:{joint}")
    if own is not None:
        return LateralBasis(joint, *own)
    key = (robot_key(robot), joint)
    if key not in _CACHE:
        _CACHE[key] = LateralBasis(
            joint, *_reduced(_varying(robot, reference_poses(robot, _N_REF), joint), _RANK_TOL)
        )
    return _CACHE[key]


def pose_rank(robot: Robot, q: np.ndarray, joint: int) -> int:
    """The rank of joint ``joint``'s moment basis on poses ``q`` beyond a rotation that is the same
    at every pose (the geometry's frame errors take it): 0 when nothing varies across the axis."""
    return _reduced(_varying(robot, np.atleast_2d(np.asarray(q, dtype=float)), joint), _POSE_RANK_TOL)[
        1
    ].shape[1]


def size_on_poses(
    robot: Robot, q: np.ndarray, joints: Iterable[int]
) -> tuple[Robot, dict[int, tuple[int, int]]]:
    """``robot`` with the lateral bases of ``joints`` sized on the data's poses ``q`` where the
    reference basis is singular on them (the rule of
    :func:`~kpioed_drake.effects.gravity_basis.size_on_poses`); ``robot`` itself unchanged.

    Returns:
        (robot, ``{joint: (rank on the reference poses, rank on q)}`` of the joints re-sized).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = {}
    for j in joints:
        ref = lateral_basis(robot, j)
        if ref.rank == 0:
            continue
        Xc = _varying(robot, q, j)
        A = np.einsum("nap,pr->nar", Xc, ref.V / ref.D[:, None]).reshape(-1, ref.rank)
        s = np.linalg.svd(A / np.maximum(np.linalg.norm(A, axis=0), 1e-300), compute_uv=False)
        if int(np.sum(s > _POSE_RANK_TOL * s[0])) == ref.rank:
            continue
        D, V = _reduced(Xc, _POSE_RANK_TOL)
        robot = with_basis(robot, f"{FAMILY}:{j}", D, V)
        out[j] = (ref.rank, V.shape[1])
    return robot, out


def resolve(effect, robot: Robot, payload_kg=None, *, n_given: int | None = None):
    """``effect`` with its parameter count ``r_j`` for this robot (``n_given``: values given, checked).

    Raises:
        InputError: a prismatic joint, no moment across the axis, a payload that varies over the
            data, or ``n_given`` other than r_j.
    """
    if payload_kg is not None and np.ptp(np.atleast_1d(np.asarray(payload_kg, dtype=float))) > 0:
        raise InputError(
            f"effect {effect.name}: a payload that varies over the data is not supported by the mass-free "
            "lateral basis (use lateral_compliance with the link masses)"
        )
    lb = lateral_basis(robot, effect.joint)
    if lb.rank == 0:
        raise InputError(f"effect {effect.name}: gravity has no moment across joint {effect.joint}'s axis")
    if n_given is not None:
        if n_given != lb.rank:
            raise InputError(
                f"effect {effect.name}: {n_given} values given; joint {effect.joint} has {lb.rank} moments"
            )
        return effect
    values = None
    if effect.values is not None:
        v = np.zeros(lb.rank)
        m = min(lb.rank, len(effect.values))
        v[:m] = effect.values[:m]
        values = tuple(float(x) for x in v)
    return dataclasses.replace(effect, n_basis=lb.rank, values=values)


def massless_joints(robot: Robot) -> list[int]:
    """The revolute joints (1-based) whose carried links the model file gives no masses: those
    whose lateral compliance only this basis can model."""
    return [
        j
        for j in range(1, robot.n_joints + 1)
        if not robot.prismatic[j - 1] and not robot.masses[subtree_links(robot, j)].any()
    ]


def candidates(
    robot: Robot | None, q: np.ndarray, payload_kg: float | np.ndarray | None = None
) -> tuple[list[tuple[int, int]], list[str]]:
    """The lateral-basis candidates of a diagnosis: every revolute joint whose carried links the
    model file gives no masses (their moment is unknown, not zero) and whose moment across the axis
    varies over the poses ``q`` (n, nj) [rad]; none with a payload that varies (not supported).

    Returns:
        (``[(joint, n_basis)]``, notes on the joints left out).
    """
    if robot is None or not robot:
        return [], []
    q = np.atleast_2d(np.asarray(q, dtype=float))
    joints = massless_joints(robot)
    if not joints:
        return [], []
    if payload_kg is not None and np.ptp(np.atleast_1d(np.asarray(payload_kg, dtype=float))) > 0:
        return [], [f"{FAMILY} is not a candidate: the payload varies over the data (not supported)"]
    out, still = [], []
    for j in joints:
        rank = lateral_basis(robot, j).rank
        (out if rank and pose_rank(robot, q, j) else still).append((j, rank))
    notes = (
        [f"{FAMILY} of joint(s) {', '.join(str(j) for j, _ in still)} is not a candidate: gravity's moment "
         "across the axis is the same at every one of these poses (the geometry's frame errors take it)"]
        if still
        else []
    )  # fmt: skip
    return out, notes
