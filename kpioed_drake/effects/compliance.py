"""Compliance of a lifting column or of the robot's base: the robot above turns under its own weight.

Effect families for robots on a lift or a soft floor and for joint bearings, each one parameter
``c`` and each a
small rigid rotation ``omega(q) = c m(q)`` [rad] of
everything the compliant part carries about a pivot ``o(q)``: a point ``p`` it carries moves by
``omega x (p - o)`` (first order in omega: ``omega`` is 1e-4 rad at realistic sizes, the second
order term is below 1e-8 of the lever).

``column_compliance:k`` (k a prismatic joint, the lift): the column is a cantilever fixed at its foot
and loaded at the carriage ``C`` (the origin of link frame k, the child of joint k) by the gravity
moment of everything above it, links k..n and the payload,
``M = sum_l m_l (p_l - C) x g`` [N m] (``p_l`` the centre of mass of link l, ``g`` Drake's gravity
in W), only its part perpendicular to the column axis ``a`` (the joint axis in W):
``M_perp = (I - a a^T) M``. ``h = (C - o_{k-1}) . a`` [m] is the carriage height above the foot
(the origin offset of joint k along its axis plus ``q_k``; the foot is ``C - h a``). A cantilever of
bending stiffness EI with an end moment M turns at its top by ``theta = M h / EI`` and its top moves
by ``M h^2 / (2 EI)``: both follow exactly from a rigid rotation

    omega = c h M_perp,    pivot o = C - a h / 2,    c = 1 / EI  [1/(N m^2)]

(``omega x (C - o) = c M_perp x a h^2 / 2``). Sign: the rotation turns about the moment, so the
top leans towards the load (an arm reaching along +x with gravity -z: ``M`` along +y, the carriage
moves to +x and the arm tips down), the sense of a real column under its robot. A positive c is a
column that yields; a negative c is not physical.

``base_compliance``: a soft floor or mount: the whole robot turns about the base origin ``O``
(the root link's origin in W: 0 for the table robots, the URDF's base pose for a URDF robot) by
``omega = c M_B``, ``M_B = sum_l m_l (p_l - O) x g`` over all moving links 1..n and the payload
(perpendicular to g by construction), ``c`` [rad/(N m)] as a joint compliance.

``lateral_compliance:j`` (j a revolute joint): the bearing of joint j yields about the axes across
its axis ``a = w_j``: everything joint j carries (links j..n and the payload) turns about the point
``C = a_j`` on the axis by ``omega = c (I - a a^T) M_j``, ``M_j = sum_l m_l (p_l - C) x g`` [N m],
``c`` [rad/(N m)] (the joint's own torque ``a . M_j`` is ``joint_elasticity``'s). A positive c
yields towards the load, as the column does.

Masses and centres of mass are the model file's (``robot.masses``, ``robot.coms`` in the link
frames), the kinematics the nominal geometry at the commanded joint values (as the gravity torques
of joint elasticity); the payload is a point mass at the reflector point ``p_FP``. The joint-value
derivatives are closed form: a joint j moves a point ``p`` it carries by
``v_j(p) = w_j x (p - a_j)`` (revolute) or ``w_j`` (prismatic), so
``dM/dq_j = sum_{l >= j} m_l (v_j(p_l) - v_j(C)[j <= k]) x g`` (1e-3 m per mm), ``dh/dq_k = 1``
and ``d o/dq_j = v_j(C) - a [j = k] / 2`` for ``j <= k``. Only prismatic joints may precede the
column (a rail): a revolute joint below it would turn the column axis itself.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.effects.gravity import gravity_model, nominal_frames, reference_poses, robot_key
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import (
    Frames,
    cross,
    flange_point,
    forward_kinematics,
    link_paths,
    subtree_links,
)
from kpioed_drake.robot.models import Robot

COLUMN = "column_compliance"
BASE = "base_compliance"
LATERAL = "lateral_compliance"
FAMILIES = (COLUMN, BASE, LATERAL)
"""The compliance families: a rigid rotation of the carried robot, not a joint-angle error."""
UNITS = {COLUMN: "1/(N m^2)", BASE: "rad/(N m)", LATERAL: "rad/(N m)"}
VERTICAL_DEG = 30.0
"""A prismatic joint whose axis is within this angle of gravity is a lifting column (diagnosis)."""
MIN_RANGE_MM = 20.0
"""Smallest spread of a column's joint values in the data for a column-compliance candidate [mm]."""
_CACHE: dict = {}


@dataclasses.dataclass(frozen=True)
class Rotation:
    """The rotation of one compliance effect per unit of its parameter, at n poses.

    Attributes:
        m: (n, 3) rotation vector per unit c [rad per 1/(N m^2) or per rad/(N m)].
        pivot: (n, 3) the point it turns about, in W [mm].
        dm: (n, nj, 3) ``dm/dq_j`` [per rad, per mm] or None.
        dpivot: (n, nj, 3) ``d pivot/dq_j`` [mm/rad, mm/mm] or None.
        dm_dp: (n, 3, 3) ``dm/dp_FP`` of the payload's moment (column d: component d of ``p_FP``)
            [per mm], or None without a payload (computed with or without ``with_dq``).
    """

    m: np.ndarray
    pivot: np.ndarray
    dm: np.ndarray | None = None
    dpivot: np.ndarray | None = None
    dm_dp: np.ndarray | None = None

    def displacement(self, p_W: np.ndarray) -> np.ndarray:
        """(n, 3) ``m x (p - pivot)``: displacement of the points p_W (n, 3) [mm] per unit c."""
        return cross(self.m, p_W - self.pivot)


def carried_rows(model, joint: int | None, target, n: int) -> np.ndarray | None:
    """(n,) 1 on the rows whose target link joint ``joint`` carries, 0 on the others (another arm);
    None when it carries every row's."""
    if joint is None or model.robot.target_links is None:
        return None
    links = model.target_links(target)
    on = link_paths(model.robot)[model.robot.tip if links is None else links, joint - 1].astype(float)
    return None if np.all(on == 1.0) else np.ascontiguousarray(np.broadcast_to(on, (n,)))


def on_carried_rows(rot, on: np.ndarray):
    """``rot`` zero on the rows where ``on`` (:func:`carried_rows`) is 0."""
    parts = {k: v for k in ("dm", "dm_dp") if (v := getattr(rot, k)) is not None}
    scaled = {k: v * on.reshape((-1,) + (1,) * (v.ndim - 1)) for k, v in parts.items()}
    return dataclasses.replace(rot, m=rot.m * on[:, None], **scaled)


def rotation_columns(parts: list[Rotation], p_W: np.ndarray, s: np.ndarray, R_TW: np.ndarray) -> np.ndarray:
    """(n, 3, k) the displacements of the points p_W (n, 3) [mm] per unit of each of the k
    rotations ``parts``, in the tracker frame (rotation ``R_TW``) and scaled by ``s`` (n,)."""
    if not parts:
        return np.zeros((p_W.shape[0], 3, 0))
    M = np.stack([r.m for r in parts])  # (k, n, 3)
    if all(r.pivot is parts[0].pivot for r in parts):
        d = (p_W - parts[0].pivot)[None]
    else:
        d = np.stack([p_W - r.pivot for r in parts])
    return s[:, None, None] * np.einsum("kna,ba->nbk", cross(M, d), R_TW)


def check_column(robot: Robot, joint: int, spec: str = "") -> None:
    """Raise InputError unless ``joint`` (1-based) is prismatic with only prismatic joints before it."""
    what = f"effect {spec!r}" if spec else f"{COLUMN}:{joint}"
    pris = robot.conventions
    if not 1 <= joint <= robot.n_joints:
        raise InputError(f"{what}: joint must be 1..{robot.n_joints} (1-based), got {joint}")
    if pris[joint - 1] != "prismatic":
        raise InputError(
            f"{what}: joint {joint} of {robot.name} is {pris[joint - 1]}; a column compliance needs the "
            "prismatic joint of a lifting column (a URDF robot with a lift)"
        )
    before = [i + 1 for i in range(joint - 1) if pris[i] != "prismatic"]
    if before:
        raise InputError(
            f"{what}: joint(s) {before} below the column are revolute; the column must stand on the base or "
            "on prismatic joints (rails) only"
        )


def check_lateral(robot: Robot, joint: int, spec: str = "") -> None:
    """Raise InputError unless ``joint`` (1-based) is a revolute joint of ``robot``."""
    what = f"effect {spec!r}" if spec else f"{LATERAL}:{joint}"
    if not 1 <= joint <= robot.n_joints:
        raise InputError(f"{what}: joint must be 1..{robot.n_joints} (1-based), got {joint}")
    if robot.prismatic[joint - 1]:
        raise InputError(
            f"{what}: joint {joint} of {robot.name} is prismatic; a lateral compliance is that of a "
            "revolute joint's bearing (a lift's bending is column_compliance)"
        )


def base_origin(robot: Robot) -> np.ndarray:
    """(3,) the base origin in W [mm]: the root link's origin (0 for a table robot)."""
    key = ("origin", robot_key(robot))
    if key not in _CACHE:
        o = np.zeros(3)
        if robot.urdf is not None:
            scene = gravity_model(robot).scene
            body = scene.plant.GetBodyByName(robot.urdf.root)
            o = 1e3 * np.asarray(body.EvalPoseInWorld(scene.plant_context).translation(), dtype=float)
        _CACHE[key] = o
    return _CACHE[key]


def vertical_columns(robot: Robot, max_deg: float = VERTICAL_DEG) -> list[int]:
    """1-based prismatic joints that can be a column (:func:`check_column`) with an axis within
    ``max_deg`` of gravity (the axis is constant: only prismatic joints precede such a joint)."""
    out = []
    g = gravity_model(robot).g
    gn = g / max(np.linalg.norm(g), 1e-300)
    fr = forward_kinematics(robot, 0.5 * (robot.lower + robot.upper))
    for j in range(1, robot.n_joints + 1):
        if any(c != "prismatic" for c in robot.conventions[:j]):
            continue
        cosang = abs(float(fr.joint_axes[0, j - 1] @ gn))
        if cosang >= np.cos(np.deg2rad(max_deg)):
            out.append(j)
    return out


def _carriage_motion(fr, C: np.ndarray, k: int) -> np.ndarray:
    """(n, nj, 3) ``v_j(C)`` of the carriage point C (n, 3) for the joints below the column (j <= k),
    0 for the others: what a column's moment arm loses when those joints move the carriage."""
    return np.where((np.arange(fr.n_joints) < k)[None, :, None], fr.joint_motion(C), 0.0)


def rotation(
    robot: Robot,
    family: str,
    joint: int | None,
    q: np.ndarray,
    *,
    p_FP: np.ndarray,
    payload_kg: float | np.ndarray | None = None,
    with_dq: bool = False,
) -> Rotation:
    """The :class:`Rotation` of a compliance effect at poses q (n, nj) [rad, mm].

    Args:
        robot: the robot (nominal geometry, model file's masses).
        family: :data:`COLUMN` or :data:`BASE`; joint: the column's 1-based joint (None for the base).
        q: (n, nj) commanded joint values.
        p_FP: (3,) payload point in the flange frame [mm] (the reflector).
        payload_kg: None, scalar or (n,) payload [kg].
        with_dq: also ``dm``, ``dpivot`` (and ``dm_dp`` with a payload).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, nj = q.shape
    fr = nominal_frames(robot, q)
    g = gravity_model(robot).g
    k, C, a, h, pivot = _pivot(robot, fr, family, joint)
    links = np.arange(1, nj + 1) if k == 0 else subtree_links(robot, k)  # the links it carries
    p_l = fr.o[:, links] + np.einsum("nlab,lb->nla", fr.R[:, links], robot.coms[links])  # (n, L, 3)
    w_l = robot.masses[links]
    M = 1e-3 * np.einsum("l,nla->na", w_l, cross(p_l - C[:, None, :], g[None, None, :]))  # [N m]
    pay = None
    carries_tip = k == 0 or bool(fr.path[fr.tip, k - 1])  # the payload sits on the flange
    if payload_kg is not None and np.any(np.asarray(payload_kg) != 0) and carries_tip:
        pay = np.broadcast_to(np.asarray(payload_kg, dtype=float), (n,))
        p_pay = flange_point(fr, np.asarray(p_FP, dtype=float))
        M = M + 1e-3 * pay[:, None] * cross(p_pay - C, g[None, :])
    if family in (COLUMN, LATERAL):
        P = np.eye(3)[None] - a[:, :, None] * a[:, None, :]  # (n, 3, 3)
        scale = 1e-3 * h if family == COLUMN else np.ones(n)  # [m] or 1
        m = scale[:, None] * np.einsum("nab,nb->na", P, M)
    else:
        P, scale = np.broadcast_to(np.eye(3), (n, 3, 3)), np.ones(n)
        m = M
    dm_dp = None
    if pay is not None:
        RF = fr.at_link()[0]  # (n, 3, 3): d p_pay / d p_FP
        dM_dp = 1e-3 * pay[:, None, None] * cross(RF.transpose(0, 2, 1), g[None, None, :]).transpose(0, 2, 1)
        dm_dp = scale[:, None, None] * np.einsum("nab,nbd->nad", P, dM_dp)
    if not with_dq:
        return Rotation(m, pivot, dm_dp=dm_dp)
    dM = _moment_dq(fr, p_l, w_l, links, C, k, g)
    if pay is not None:
        v = fr.joint_motion(p_pay)  # every joint on its path moves the payload
        on = fr.point_path()
        v = v if on is None else v * on[:, :, None]
        if k:
            v = v - _carriage_motion(fr, C, k)
        dM = dM + 1e-3 * pay[:, None, None] * cross(v, g[None, None, :])
    dm = scale[:, None, None] * np.einsum("nab,njb->nja", P, dM)
    dpivot = np.zeros((n, nj, 3))
    if family == COLUMN:
        dm[:, k - 1] += 1e-3 * np.einsum("nab,nb->na", P, M)  # dh/dq_k = 1 mm/mm
        dpivot[:, :k] = fr.joint_motion(C)[:, :k]
        dpivot[:, k - 1] -= 0.5 * a
    elif family == LATERAL:
        dm += _projector_dq(fr, a, M, k)
        dpivot[:, :k] = fr.joint_motion(C)[:, :k]  # joint k turns about C: 0 there
    return Rotation(m, pivot, dm, dpivot, dm_dp)


def _pivot(robot: Robot, fr: Frames, family: str, joint: int | None) -> tuple:
    """``(k, C, a, h, pivot)`` of a compliance at the frames ``fr`` of n poses: the joint k (0: the
    base), the point C (n, 3) the carried links' moment is taken about, joint k's axis a (n, 3) and a
    column's height h (n,) [mm] (None where they do not apply), and the pivot (n, 3) [mm]."""
    a = h = None
    if family == COLUMN:
        check_column(robot, joint)
        k = int(joint)
        C = fr.o[:, k]
        a = fr.joint_axes[:, k - 1]
        h = np.einsum("ni,ni->n", C - fr.o[:, k - 1], a)  # [mm]
        pivot = C - 0.5 * h[:, None] * a
    elif family == BASE:
        k = 0
        C = np.broadcast_to(base_origin(robot), (fr.R.shape[0], 3))
        pivot = np.array(C)
    elif family == LATERAL:
        check_lateral(robot, joint)
        k = int(joint)
        C = fr.joint_points[:, k - 1]
        a = fr.joint_axes[:, k - 1]
        pivot = np.array(C)
    else:
        raise ValueError(f"not a compliance family: {family}")
    return k, C, a, h, pivot


def _projector_dq(fr, a: np.ndarray, M: np.ndarray, k: int) -> np.ndarray:
    """(n, nj, 3) ``d(I - a a^T)/dq_i M`` of joint k's axis ``a`` (n, 3): the revolute joints before
    k turn it, ``da = w_i x a``; the others leave it."""
    n, nj = a.shape[0], fr.n_joints
    out = np.zeros((n, nj, 3))
    for i in range(k - 1):
        if fr.prismatic[i]:
            continue
        da = cross(fr.joint_axes[:, i], a)
        out[:, i] = -(da * np.einsum("na,na->n", a, M)[:, None] + a * np.einsum("na,na->n", da, M)[:, None])
    return out


def _moment_dq(fr, p_l, w_l, links, C, k: int, g) -> np.ndarray:
    """(n, nj, 3) ``dM/dq_j`` of the links' moment about C [N m per rad or mm] (module docstring)."""
    v = fr.joint_motion(p_l)  # (n, L, nj, 3)
    moved = fr.path[links]  # (L, nj): joint j moves link l
    v = np.where(moved[None, :, :, None], v, 0.0)
    if k:
        v = v - _carriage_motion(fr, C, k)[:, None]
    return 1e-3 * np.einsum("l,nlja->nja", w_l, cross(v, g[None, None, None, :]))


def lever(robot: Robot, family: str, joint: int | None, p_FQ: np.ndarray) -> float:
    """Largest reflector displacement per unit c over the joint box [mm per unit c]:
    ``max_q |m(q) x (p_WQ - pivot)|`` over :func:`~kpioed_drake.effects.gravity.reference_poses`
    (no payload); a drawn ``tool_mm`` divided by it is the drawn c."""
    key = ("lever", robot_key(robot), np.asarray(p_FQ, float).tobytes(), family, joint)
    if key not in _CACHE:
        q = reference_poses(robot)
        rot = rotation(robot, family, joint, q, p_FP=p_FQ)
        p = flange_point(forward_kinematics(robot, q), np.asarray(p_FQ, dtype=float))
        _CACHE[key] = float(np.max(np.linalg.norm(rot.displacement(p), axis=1)))
    return _CACHE[key]


def candidates(robot: Robot, q: np.ndarray) -> tuple[list[tuple[str, int | None]], list[str]]:
    """The compliance candidates of a diagnosis: ``(family, joint)`` pairs and notes on those left out.

    ``column_compliance:k`` for every column (:func:`vertical_columns`) whose joint spans more than
    :data:`MIN_RANGE_MM` in the data ``q`` (n, nj); ``base_compliance`` for a robot with a column
    (a lift stands on a floor) or whose model file says ``compliant_base: true``. A robot with
    neither gets no candidate and no note (the six-joint robot files).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    cols = vertical_columns(robot)
    out: list[tuple[str, int | None]] = []
    notes = []
    for j in cols:
        span = float(np.ptp(q[:, j - 1]))
        if span > MIN_RANGE_MM:
            out.append((COLUMN, j))
        else:
            notes.append(
                f"{COLUMN}:{j} is not a candidate: joint {j} (the column) spans {span:.3g} mm in the data "
                f"(at least {MIN_RANGE_MM:g} mm needed; with a fixed carriage height it is {BASE})"
            )
    if cols or robot.compliant_base:
        out.append((BASE, None))
    return out, notes
