"""Joint elasticity without trusting the model file's masses: a gravity basis per joint.

The gravity torque of joint j is linear in the first mass moments of the links it carries
(links k = j..6, ``pi_k = (m_k, m_k c_k)``, ``c_k`` the centre of mass in link frame k [mm]):

    tau_j(q) = sum_k  g . (w_j x (o_k - a_j)) m_k  +  (R_k^T (g x w_j)) . (m_k c_k)      (x 1e-3)
             = Y_j^full(q) pi_j

with ``w_j``/``a_j`` the axis of joint j and a point on it, ``o_k``/``R_k`` the origin and
orientation of link frame k (numpy kinematics, nominal geometry, robot base = Drake's W) and ``g``
Drake's gravity vector in W [m/s^2]. Not every moment is seen by ``tau_j``: the columns of
``Y_j^full`` (scaled to unit RMS over :func:`~kpioed_drake.effects.gravity.reference_poses`) are
reduced by an SVD over those poses to their ``r_j`` independent directions ``V_j`` (the minimal
identifiable set of joint j): ``Y_j(q) = (Y_j^full(q) / D_j) V_j`` (n, r_j) and
``beta_j = V_j^T (D_j pi_j)`` [N m], so that ``tau_j = Y_j beta_j`` exactly.

The effect ``joint_elasticity_basis:j`` deflects joint j by ``dq_j = Y_j(q) . theta_j`` with
``theta_j = c_j beta_j`` [rad] estimated linearly (any masses and centres of mass of the links).
A payload (a point mass at the reflector point, torque ``tau_pay_j``) is a known moment: if the
payload is the same at every pose it is a link-6 moment and lies in the span of ``Y_j``; if it
varies over the data, ``c_j`` is identifiable on its own and the effect has one more parameter,
``c_j`` multiplying ``tau_pay_j(q)`` (:func:`resolve_basis` with the data's payload). The model
file's moments ``beta_j^file`` are the reference: :func:`basis_compliance` reports the compliance
``c_j = <Y theta, Y beta^file> / |Y beta^file|^2`` over the reference poses (the compliance that
reproduces the fitted deflection best with the model file's torques) and the moment ratio
``|theta| / (c_j |beta^file|)``.

The side of a backlash (``sign tau_j``) is uncertain where the torque is: :func:`torque_std` is
the standard deviation of ``tau_j(q)`` when each file mass and centre of mass is off by
:data:`MASS_PRIOR_SPREAD` (linear propagation through ``Y_j^full``), and :func:`expected_side` the
expectation of the true side under that prior, ``erf(tau_j / (sqrt 2 std))`` (+-1 where the file's
torque is certain, about 0 where its sign is not known).

Joint 1: with gravity along its axis ``r_1 = 0`` and :func:`resolve_basis` refuses it; the check
is the torque range, not the joint number (a tilted base or gravity makes it identifiable).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np
import scipy.special

from kpioed_drake.effects.basis_store import ReducedBasis, own_basis, with_basis
from kpioed_drake.effects.gravity import gravity_model, memoized, nominal_frames, reference_poses, robot_key
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import cross, subtree_links
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.measurement import TrackerModel

FAMILY = "joint_elasticity_basis"
_N_REF = 500
_RANK_TOL = 1e-7
"""Relative singular value below which a direction of the moments is not seen by tau_j."""
_POSE_RANK_TOL = 1e-5
"""The same on the data's poses (:func:`size_on_poses`): their angles are rounded (a file's decimals,
an encoder's steps, about 1e-6 rad), so a coupling such as ``q_4 = -(q_2 + q_3)`` holds only to that
and leaves singular values of about 1e-10 to 1e-7 relative that no deflection can be fitted to."""
_CACHE: dict = {}
MASS_PRIOR_SPREAD = 0.3
"""Assumed uncertainty of the model file's link masses and centres of mass (each +-30 %, uniform):
mass ``m (1 + a)``, centre of mass shifted by ``d`` times its distance from the
link frame (100 mm when the file puts it at the origin), ``a, d ~ U(-s, s)``."""
COM_SCALE_AT_ORIGIN_MM = 100.0
"""The centre-of-mass shift scale of a link whose file centre of mass is at its frame origin [mm]."""


def com_scales(coms: np.ndarray) -> np.ndarray:
    """(L,) the scale of each link's centre-of-mass uncertainty under the mass prior [mm]: its
    distance from the link frame's origin, :data:`COM_SCALE_AT_ORIGIN_MM` where that is 0."""
    r = np.linalg.norm(np.atleast_2d(coms), axis=1)
    return np.where(r > 0, r, COM_SCALE_AT_ORIGIN_MM)


def link_regressor(
    robot: Robot, q: np.ndarray, joint: int, *, g: np.ndarray | None = None, with_dq: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`_link_regressor`, memoized (:func:`~.gravity.memoized`; read-only arrays)."""
    g = gravity_model(robot).g if g is None else np.asarray(g, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    extra = (int(joint), g.tobytes(), bool(with_dq))
    return memoized("link", robot, q, extra, lambda: _link_regressor(robot, q, joint, g=g, with_dq=with_dq))


def _link_regressor(robot: Robot, q, joint: int, *, g=None, with_dq: bool = False):
    """Full gravity regressor of joint ``joint`` (1-based) over its downstream links.

    Args:
        robot: the robot (nominal geometry).
        q: (n, 6) joint angles [rad].
        joint: 1-based joint j.
        g: (3,) gravity in W [m/s^2] (default: Drake's, :class:`~.gravity.GravityModel`).
        with_dq: also the joint-angle derivative.

    Returns:
        Y (n, 4 (7 - j)) [N m per kg, N m per kg mm], columns per link k = j..6:
        ``m_k, m_k c_kx, m_k c_ky, m_k c_kz``; with ``with_dq`` also dY (n, 6, 4 (7 - j)).
    """
    g = gravity_model(robot).g if g is None else np.asarray(g, dtype=float)
    fr = nominal_frames(robot, q)
    n = fr.o.shape[0]
    j = joint - 1
    w, a = fr.joint_axes, fr.joint_points  # (n, 6, 3)
    wj, aj = w[:, j], a[:, j]
    nj, pris = fr.n_joints, fr.prismatic
    links = subtree_links(robot, joint)  # the links joint j carries (its branch of a tree)
    upstream = fr.axis_movers(joint)
    gxw = cross(g[None, :], wj)  # (n, 3)
    Y = np.empty((n, 4 * len(links)))
    dY = np.zeros((n, nj, Y.shape[1])) if with_dq else None
    for col, k in zip(range(0, Y.shape[1], 4), links, strict=True):
        Rk, ok = fr.R[:, k], fr.o[:, k]
        if pris[j]:  # a prismatic joint carries the links' weight: a force [N per kg], no moments
            Y[:, col], Y[:, col + 1 : col + 4] = wj @ g, 0.0
            for i in np.flatnonzero(upstream) if with_dq else ():  # the revolute joints before j turn w_j
                if not pris[i]:
                    dY[:, i, col] = cross(w[:, i], wj) @ g
            continue
        X = cross(wj, ok - aj)  # (n, 3)
        Y[:, col] = 1e-3 * (X @ g)
        Y[:, col + 1 : col + 4] = 1e-3 * np.einsum("nab,na->nb", Rk, gxw)
        if not with_dq:
            continue
        for i in np.flatnonzero(fr.path[k]):  # the joints that move link k
            wi = w[:, i]
            if pris[i]:  # a translation: before joint j nothing changes, after it link k moves by w_i
                if not upstream[i] and i != j:
                    dY[:, i, col] = 1e-3 * (cross(wj, wi) @ g)
                continue
            if upstream[i]:  # the whole chain from joint j on turns about w_i
                dX = cross(wi, X)
                dgxw = cross(g[None, :], cross(wi, wj))
            else:  # only link k turns (about w_i through a_i); w_j and a_j stay
                dX = cross(wj, cross(wi, ok - a[:, i]))
                dgxw = np.zeros_like(gxw)
            dY[:, i, col] = 1e-3 * (dX @ g)
            # d(R_k^T v) = R_k^T (dv - w_i x v)
            dv = dgxw - cross(wi, gxw)
            dY[:, i, col + 1 : col + 4] = 1e-3 * np.einsum("nab,na->nb", Rk, dv)
    return (Y, dY) if with_dq else Y


def link_moments(robot: Robot, joint: int) -> np.ndarray:
    """(4 (7 - j),) the model file's first moments of links j..6: ``m_k, m_k c_k`` [kg, kg mm]."""
    ks = subtree_links(robot, joint)
    m = robot.masses[ks]
    return np.concatenate([m[:, None], m[:, None] * robot.coms[ks]], axis=1).reshape(-1)


@dataclasses.dataclass(frozen=True)
class JointBasis(ReducedBasis):
    """The minimal identifiable gravity basis of one joint (:class:`ReducedBasis`; ``D`` over the full
    regressor's columns).

    Attributes:
        beta_file: (r,) the model file's moments in this basis [N m].
        g: (3,) the gravity vector used [m/s^2].
    """

    beta_file: np.ndarray
    g: np.ndarray

    def regressor(
        self, robot: Robot, q: np.ndarray, *, with_dq: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Y_j (n, r) [N m per N m]; with ``with_dq`` also dY_j (n, 6, r)."""
        out = link_regressor(robot, q, self.joint, g=self.g, with_dq=with_dq)
        T = self.V / self.D[:, None]
        if not with_dq:
            return out @ T
        return out[0] @ T, out[1] @ T


def _reduced(Y: np.ndarray, tol: float = _RANK_TOL) -> tuple[np.ndarray, np.ndarray]:
    """``(D, V)`` of a full regressor ``Y`` (n, p) over n poses: the RMS of each column (1 for a
    column that is zero at every pose) and the (p, r) right singular vectors of the scaled columns
    whose singular value is at least ``tol`` times the largest (none if the torque is zero at
    every pose)."""
    n = Y.shape[0]
    D = np.sqrt(np.mean(Y**2, axis=0))
    scale = max(float(D.max()), 1e-300)
    keep = D > 1e-12 * scale
    D = np.where(keep, D, 1.0)
    _, s, Vt = np.linalg.svd(Y / D * keep, full_matrices=False)
    big = s > tol * s[0] if s[0] > 1e-9 * np.sqrt(n) else np.zeros_like(s, dtype=bool)
    return D, Vt[big].T


def _rank(A: np.ndarray) -> int:
    """The numerical column rank of ``A`` at :data:`_POSE_RANK_TOL` (columns scaled to unit norm)."""
    n = np.linalg.norm(A, axis=0)
    s = np.linalg.svd(A / np.where(n > 0, n, 1.0), compute_uv=False)
    return int(np.sum(s > _POSE_RANK_TOL * s[0])) if s.size and s[0] > 0 else 0


def joint_basis(robot: Robot, joint: int, *, g: np.ndarray | None = None) -> JointBasis:
    """The :class:`JointBasis` of ``joint``: the robot's own where it has one (sized on a data set's
    poses, :func:`size_on_poses`, or stored in its model file's ``effects:``), else the (cached)
    reference basis, the SVD of the scaled full regressor over :data:`_N_REF` seeded poses in the
    joint box with directions below ``_RANK_TOL`` times the largest singular value (or all, if the
    torque is zero everywhere) dropped. ``g``: another gravity (always the reference basis)."""
    if g is None:
        own = _own_basis(robot, joint)
        if own is not None:
            return own
    return reference_basis(robot, joint, g=g)


def reference_basis(robot: Robot, joint: int, *, g: np.ndarray | None = None) -> JointBasis:
    """The (cached) reference basis of ``joint`` over the joint box (see :func:`joint_basis`)."""
    g = gravity_model(robot).g if g is None else np.asarray(g, dtype=float)
    key = _key(robot, joint, g)
    if key not in _CACHE:
        D, V = _reduced(link_regressor(robot, reference_poses(robot, _N_REF), joint, g=g))
        beta = V.T @ (D * link_moments(robot, joint))
        _CACHE[key] = JointBasis(joint, D, V, beta, g)
    return _CACHE[key]


def _own_basis(robot: Robot, joint: int) -> JointBasis | None:
    own = own_basis(robot, f"{FAMILY}:{joint}")
    return None if own is None else _basis(robot, joint, *own)


def _basis(robot: Robot, joint: int, D, V) -> JointBasis:
    D = np.asarray(D, dtype=float)
    V = np.asarray(V, dtype=float).reshape(len(D), -1)
    return JointBasis(joint, D, V, V.T @ (D * link_moments(robot, joint)), gravity_model(robot).g)


def pose_rank(robot: Robot, q: np.ndarray, joint: int, *, centered: bool = True) -> int:
    """The rank of joint ``joint``'s gravity basis on the poses ``q`` (n, nj) [rad]: how many
    combinations of the link moments its torque distinguishes there, with ``centered`` beyond a
    torque that is the same at every pose (whose deflection is the joint's offset). 0: gravity
    exerts no torque on the joint at these poses for any link masses (``centered=False``; e.g. a
    joint about the vertical axis), or none that varies (``centered``)."""
    Y = link_regressor(robot, np.atleast_2d(np.asarray(q, dtype=float)), joint)
    return _reduced(Y - Y.mean(axis=0) if centered else Y, _POSE_RANK_TOL)[1].shape[1]


def size_on_poses(robot: Robot, q: np.ndarray) -> tuple[Robot, dict[int, tuple[int, int]]]:
    """``robot`` with every joint's basis sized on the data's own poses ``q`` (n, nj) [rad] where the
    reference basis is singular on them (a coupled joint, e.g. ``q_4 = -(q_2 + q_3)``, a fixed or
    barely moving joint make some columns of ``Y_j`` dependent on these poses, and no number of such
    poses helps; a link whose orientation the coupling keeps, e.g. an upright chest, adds a torque
    that is the same at every pose, a deflection the joint's offset absorbs). Where the reference
    basis's columns on ``q`` together with a constant column are rank deficient (at
    :data:`_POSE_RANK_TOL`), the basis reduced on ``q`` with the columns' means removed (a constant
    torque is the joint's offset) becomes the returned robot's (and what a model file written from
    it stores); elsewhere the reference basis stays. ``robot`` itself is not changed.

    Returns:
        (robot, ``{joint: (rank on the reference poses, rank on q)}`` of the joints re-sized).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out, sized = {}, robot
    for j in range(1, robot.n_joints + 1):
        ref = joint_basis(robot, j)
        Y = link_regressor(robot, q, j, g=ref.g)
        ones = np.ones((Y.shape[0], 1))
        if ref.rank == 0 or _rank(np.hstack([ones, Y @ (ref.V / ref.D[:, None])])) == ref.rank + 1:
            continue
        D, V = _reduced(Y - Y.mean(axis=0), _POSE_RANK_TOL)
        sized = with_basis(sized, f"{FAMILY}:{j}", D, V)
        out[j] = (ref.rank, V.shape[1])
    return sized, out


def unloaded_candidates(
    robot: Robot | None, q: np.ndarray, joints: Iterable[int], payload_kg: float | np.ndarray | None = None
) -> tuple[list, list[str]]:
    """The elasticity candidates of the joints whose gravity torque with the model file's masses is
    zero at every pose ``q`` (n, nj) [rad] (``joints``, 1-based), with the true reason for each one
    left out: a joint whose torque is zero for any link masses at these poses (rank 0 of its basis
    there: its axis is vertical) has no elasticity to see, nor one whose torque is the same at every
    pose (its offset); a joint whose torque is zero only because the file gives its links no mass
    gets the mass-free ``joint_elasticity_basis:j`` (sized by :func:`size_on_poses`) and no
    backlash (the side of its torque is unknown). Without ``robot`` a zero torque is taken for a
    vertical axis (a false ``robot`` too).

    Returns:
        (candidates, notes): ``[(joint, n_basis)]`` of the basis candidates (n_basis = the basis
        rank, plus 1 when the payload varies) and the notes on those left out.
    """
    robot = robot or None
    cands, notes, massless = [], [], []
    for j in (int(x) for x in joints):
        rank = pose_rank(robot, q, j) if robot is not None else 0
        if rank == 0:
            why = (
                f"gravity's torque on joint {j} is the same at every one of these poses (its deflection is "
                "the joint's offset)"
                if robot is not None and pose_rank(robot, q, j, centered=False)
                else f"joint {j} turns about the vertical axis at these poses, gravity exerts no torque on it"
            )
            notes.append(f"joint_elasticity:{j} and backlash:{j} are not candidates: {why}")
            continue
        cands.append((j, joint_basis(robot, j).rank + int(payload_varies(payload_kg))))
        massless.append(str(j))
    if massless:
        js = ", ".join(massless)
        notes.append(
            f"joint_elasticity and backlash of joint(s) {js} are not candidates: the model file gives the "
            "links these joints carry no masses (their gravity torque is unknown, not zero); "
            f"{FAMILY} of joint(s) {js} (the torque of any link masses, sized on these poses) is the "
            "candidate instead"
        )
    return cands, notes


def _key(robot: Robot, joint: int, g: np.ndarray) -> tuple:
    return (robot_key(robot), joint, g.tobytes())


def store_basis(robot: Robot, joint: int, D: np.ndarray, V: np.ndarray) -> Robot:
    """``robot`` with ``D`` (p,) and ``V`` (p, r) as joint ``joint``'s basis (``robot`` unchanged), so
    that values estimated with these columns multiply them again.

    Raises:
        InputError: ``D``/``V`` do not fit joint ``joint``'s full regressor of ``robot``.
    """
    jb = check_basis(robot, joint, D, V)
    return with_basis(robot, f"{FAMILY}:{joint}", jb.D, jb.V)


def check_basis(robot: Robot, joint: int, D: np.ndarray, V: np.ndarray) -> JointBasis:
    """The basis ``D`` (p,), ``V`` (p, r) (e.g. a model file's) of joint ``joint``, checked.

    Raises:
        InputError: ``D``/``V`` do not fit joint ``joint``'s full regressor of ``robot``.
    """
    D = np.asarray(D, dtype=float).reshape(-1)
    p = link_moments(robot, joint).size
    if D.shape != (p,) or np.any(D <= 0):
        raise InputError(
            f"joint {joint} of {robot.name}: expected {p} positive basis RMS values, got {D.size}"
        )
    V = np.asarray(V, dtype=float)
    if V.size % p:
        raise InputError(
            f"joint {joint} of {robot.name}: the basis directions must have {p} rows, got {V.size} numbers"
        )
    return _basis(robot, joint, D, V)


def payload_varies(payload_kg: float | np.ndarray | None) -> bool:
    """True if the payload takes more than one value over the data."""
    if payload_kg is None:
        return False
    p = np.atleast_1d(np.asarray(payload_kg, dtype=float))
    return bool(p.size > 1 and np.ptp(p) > 0)


def resolve_basis(effect, model: TrackerModel, payload_kg=None, *, n_given: int | None = None):
    """``effect`` (a ``joint_elasticity_basis``) with its parameter count for this robot and data:
    the rank ``r_j`` of joint j's basis, plus one (``c_j`` of the payload torque) when the payload
    varies over the data. ``n_given``: a count already chosen (values given), checked instead.

    Raises:
        InputError: gravity exerts no torque on the joint (``r_j = 0``, e.g. a vertical joint 1),
            or ``n_given`` is neither r_j nor r_j + 1.
    """
    jb = joint_basis(model.robot, effect.joint)
    if jb.rank == 0:
        raise InputError(
            f"effect {effect.name}: gravity exerts no torque on joint {effect.joint} of {model.robot.name} "
            "(its axis is parallel to gravity at every pose), so its elasticity has no effect"
        )
    if n_given is not None:
        if n_given not in (jb.rank, jb.rank + 1):
            raise InputError(
                f"effect {effect.name}: {n_given} values given; joint {effect.joint} of {model.robot.name} "
                f"has {jb.rank} basis moments (plus 1 for a varying payload)"
            )
        return effect
    n = jb.rank + int(payload_varies(payload_kg))
    values = None
    if effect.values is not None:
        v = np.zeros(n)
        m = min(n, len(effect.values))
        v[:m] = effect.values[:m]
        values = tuple(float(x) for x in v)
    return dataclasses.replace(effect, n_basis=n, values=values)


def resolve_all(effects, model: TrackerModel, payload_kg=None) -> list:
    """``effects`` with every ``joint_elasticity_basis`` sized for this robot and payload
    (:func:`resolve_basis`); the other effects unchanged."""
    return [
        resolve_basis(e, model, payload_kg, n_given=e.n_basis if e.values is not None else None)
        if e.family == FAMILY
        else e
        for e in effects
    ]


def basis_factors(model: TrackerModel, q, effect, *, tau=None, payload_kg=None, with_dq: bool = False):
    """The deflection factors of ``joint_elasticity_basis:j``: ``d dq_j / d values``.

    Args:
        model: the model (its robot's nominal geometry and the file's masses for the payload split).
        q: (n, 6) commanded angles [rad].
        effect: a resolved basis effect (``n_basis`` = r_j or r_j + 1).
        tau: (n, 6) gravity torques with the payload (as in the estimation's conditions); the
            payload torque is ``tau_j - Y_j beta_file``; computed from ``payload_kg`` if not given.
        payload_kg: scalar or (n,), used when ``tau`` is not given or with ``with_dq``.
        with_dq: also the joint-angle derivative.

    Returns:
        f (n, n_basis); with ``with_dq`` also df (n, 6, n_basis).
    """
    robot = model.robot
    jb = joint_basis(robot, effect.joint)
    out = jb.regressor(robot, q, with_dq=with_dq)
    Y, dY = out if with_dq else (out, None)
    if effect.n_params == jb.rank:
        return (Y, dY) if with_dq else Y
    j = effect.joint - 1
    gm = gravity_model(robot)
    pay = payload_kg is not None and np.any(np.asarray(payload_kg) != 0)
    if tau is not None:
        tp = tau[:, j] - Y @ jb.beta_file
    elif pay:
        tp = gm.payload_torques(q, payload_kg, model.p_FP)[:, j]
    else:
        tp = np.zeros(Y.shape[0])
    f = np.concatenate([Y, tp[:, None]], axis=1)
    if not with_dq:
        return f
    dtp = (
        gm.payload_torques(q, payload_kg, model.p_FP, with_dq=True)[1][:, j]
        if pay
        else np.zeros(dY.shape[:2])
    )
    return f, np.concatenate([dY, dtp[:, :, None]], axis=2)


def basis_compliance(effect, model: TrackerModel) -> dict:
    """The fitted basis deflection against the model file's torques (see the module docstring).

    Returns:
        ``compliance`` c_j [rad/(N m)] (least squares of ``Y theta`` on ``Y beta_file`` over the
        reference poses), ``moment_ratio`` ``|theta| / |c_j beta_file|`` (1 = the file's moments up
        to scale), ``payload_compliance`` (the payload parameter, if any) and ``rank`` r_j.
    """
    robot = model.robot
    jb = joint_basis(robot, effect.joint)
    v = effect.value_array()
    theta = v[: jb.rank]
    Y = jb.regressor(robot, reference_poses(robot, _N_REF))
    ref = Y @ jb.beta_file
    fit = Y @ theta
    denom = float(ref @ ref)
    c = float(fit @ ref) / denom if denom > 0 else float("nan")
    nb = float(np.linalg.norm(c * jb.beta_file))
    out = {
        "compliance": c,
        "moment_ratio": float(np.linalg.norm(theta)) / nb if nb > 0 else float("nan"),
        "rank": jb.rank,
    }
    if v.size > jb.rank:
        out["payload_compliance"] = float(v[jb.rank])
    return out


def torque_std(robot: Robot, q: np.ndarray, joint: int, *, spread: float = MASS_PRIOR_SPREAD) -> np.ndarray:
    """(n,) prior standard deviation of joint ``joint``'s gravity torque [N m] when the file's link
    masses and centres of mass are uncertain by ``spread`` (:data:`MASS_PRIOR_SPREAD`): first-order
    propagation of the independent uniform errors ``a, d`` (variance ``spread^2 / 3``) through
    :func:`link_regressor`. A recorded payload is known and adds nothing."""
    Y = link_regressor(robot, q, joint)
    v = spread**2 / 3.0
    u2 = np.zeros(Y.shape[0])
    scales = com_scales(robot.coms)
    for col, k in zip(range(0, Y.shape[1], 4), subtree_links(robot, joint), strict=True):
        m, c, r = robot.masses[k], robot.coms[k], float(scales[k])
        p = np.concatenate([[m], m * c])  # d pi / d a
        S = v * np.outer(p, p) + v * (m * r) ** 2 * np.diag([0.0, 1.0, 1.0, 1.0])
        Yk = Y[:, col : col + 4]
        u2 += np.einsum("na,ab,nb->n", Yk, S, Yk)
    return np.sqrt(u2)


def expected_side(tau: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Expected sign of a torque known as ``tau`` +- ``std`` (Gaussian): ``erf(tau / (sqrt 2 std))``
    (the sign itself where ``std`` is 0)."""
    tau, std = np.asarray(tau, dtype=float), np.asarray(std, dtype=float)
    z = np.divide(tau, np.sqrt(2.0) * std, out=np.sign(tau) * 1e300, where=std > 0)
    return scipy.special.erf(z)
