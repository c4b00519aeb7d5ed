"""Gravity torques of a robot's links (Drake) and of a payload, and the elastic lever of a joint.

See :mod:`kpioed_drake.effects` for the sign and unit conventions.
"""

from __future__ import annotations

import dataclasses
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np
from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

from kpioed_drake.robot.kinematics import Frames, cross, forward_kinematics, point_jacobian
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.plant import build_scene
from kpioed_drake.tracker.measurement import TrackerModel

_N_REFERENCE = 2000
_REFERENCE_SEED = 20170710


# ----------------------------------------------------------------------------------------------
# Gravity torques (Drake)
# ----------------------------------------------------------------------------------------------
class GravityModel:
    """Gravity torques of a robot's links from its Drake plant (nominal geometry, model masses).

    Built once per robot and cached (:func:`gravity_model`).
    """

    def __init__(self, robot: Robot):
        self.robot = robot
        self.scene = build_scene(robot)
        self.g = np.asarray(self.scene.plant.gravity_field().gravity_vector(), dtype=float)  # m/s^2
        self._ad = None

    def link_torques(
        self, q: np.ndarray, *, with_dq: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """(n, nj) generalized gravity forces [N m; N for prismatic joints] at q (n, nj) [rad, mm].

        With ``with_dq`` also (n, nj, nj) ``d tau_i / d q_j`` (Drake AutoDiffXd) [per rad, per mm].
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        plant, ctx = self.scene.plant, self.scene.plant_context
        nj, scale, idx = self.robot.n_joints, self.scene.q_scale, self.scene.q_index
        tau = np.empty((q.shape[0], nj))
        for k, qk in enumerate(q):
            plant.SetPositions(ctx, self.scene.positions(qk))
            tau[k] = plant.CalcGravityGeneralizedForces(ctx)[idx]
        if not with_dq:
            return tau
        if self._ad is None:
            diagram = self.scene.diagram.ToAutoDiffXd()
            plant_ad = diagram.GetSubsystemByName(plant.get_name())
            context = diagram.CreateDefaultContext()
            self._ad = (plant_ad, plant_ad.GetMyContextFromRoot(context), context)
        plant_ad, ctx_ad, _ = self._ad
        dtau = np.empty((q.shape[0], nj, nj))
        for k, qk in enumerate(q):
            plant_ad.SetPositions(ctx_ad, InitializeAutoDiff(self.scene.positions(qk)).ravel())
            dtau[k] = ExtractGradient(plant_ad.CalcGravityGeneralizedForces(ctx_ad))[np.ix_(idx, idx)] * scale
        return tau, dtau

    def payload_torques(
        self, q: np.ndarray, payload_kg: float | np.ndarray, p_FP: np.ndarray, *, with_dq: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """(n, nj) torques [N m] of point masses ``payload_kg`` (scalar or (n,)) at ``p_FP`` [mm].

        ``tau_i = F . m_i`` with ``F = m g`` [N] and ``m_i = w_i x r_i`` (``w_i`` the axis of joint
        i and ``r_i`` the point relative to that axis [m]), or ``m_i = w_i`` for a prismatic joint
        (a force [N]). Derivative: for ``j <= i`` the whole term turns about ``w_j``:
        ``F . (w_j x m_i)`` (0 for a prismatic j); for ``j > i`` only the point moves:
        ``F . (w_i x dr_j)`` with ``dr_j = w_j x r_j`` (prismatic j: ``w_j`` 1e-3 m/mm; 0 for a
        prismatic i).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = np.broadcast_to(np.asarray(payload_kg, dtype=float), (q.shape[0],))
        fr = nominal_frames(self.robot, q)
        pris = fr.prismatic[:, None]  # (nj, 1)
        R_F, o_F = fr.at_link()
        p = o_F + np.einsum("nij,j->ni", R_F, np.asarray(p_FP, float))
        w = fr.joint_axes  # (n,nj,3)
        r = (p[:, None, :] - fr.joint_points) * 1e-3  # (n,nj,3) [m]
        F = m[:, None] * self.g[None, :]  # (n,3) [N]
        wxr = cross(w, r)
        mi = np.where(pris, w, wxr)
        carries = fr.path[fr.tip]  # (nj,): the joints that carry the flange (all of a serial robot)
        mi = mi * carries[None, :, None]
        tau = np.einsum("nc,nic->ni", F, mi)
        if not with_dq:
            return tau
        full = cross(w[:, :, None, :], mi[:, None, :, :])  # [n, j, i]: w_j x m_i
        full = np.where(pris[None, :, :, None], 0.0, full)
        dr = np.where(pris, 1e-3 * w, wxr)
        part = cross(w[:, None, :, :], dr[:, :, None, :])  # [n, j, i]: w_i x dr_j
        part = np.where(pris.T[None, :, :, None], 0.0, part)
        part = part * (carries[:, None] & carries[None, :])[None, :, :, None]
        turns = fr.path[1:].T  # [j, i]: joint j moves joint i's axis (or is joint i)
        d = np.where(turns[None, :, :, None], full, part)
        dtau = np.einsum("nc,njic->nij", F, d)
        return tau, dtau

    def payload_torques_dp(self, q: np.ndarray, payload_kg: float | np.ndarray) -> np.ndarray:
        """(n, nj, 3) derivative of :meth:`payload_torques` w.r.t. ``p_FP`` [N m / mm].

        ``F . (w_i x R_WF dp) = (F x w_i) . R_WF dp``, times 1e-3 (mm -> m); 0 for a prismatic joint.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = np.broadcast_to(np.asarray(payload_kg, dtype=float), (q.shape[0],))
        fr = nominal_frames(self.robot, q)
        F = m[:, None] * self.g[None, :]
        Fxw = np.where(fr.prismatic[:, None], 0.0, cross(F[:, None, :], fr.joint_axes))  # (n,nj,3)
        Fxw = Fxw * fr.path[fr.tip][None, :, None]  # only the joints carrying the flange
        return 1e-3 * np.einsum("nic,ncd->nid", Fxw, fr.at_link()[0])

    def torques(
        self,
        q: np.ndarray,
        *,
        payload_kg: float | np.ndarray | None = None,
        p_FP: np.ndarray | None = None,
        with_dq: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Link torques plus the payload's (if ``payload_kg`` is given) [N m]."""
        out = self.link_torques(q, with_dq=with_dq)
        if payload_kg is None or np.all(np.asarray(payload_kg) == 0):
            return out
        pay = self.payload_torques(q, payload_kg, p_FP, with_dq=with_dq)
        if not with_dq:
            return out + pay
        return out[0] + pay[0], out[1] + pay[1]


_GRAVITY_CACHE: dict = {}


_REGRESSORS: OrderedDict = OrderedDict()
_REGRESSORS_LOCK = threading.Lock()
MAX_REGRESSORS = 256
"""Most regressors kept by :func:`memoized` (the latest; a fit evaluates the same poses every
iteration, a diagnosis the same poses for every candidate and fold) ..."""
MAX_REGRESSOR_BYTES = 1 << 30
"""... and the most bytes they may hold together."""
_REGRESSOR_BYTES = [0]


def memoized(kind: str, robot: Robot, q: np.ndarray, extra: tuple, compute: Callable[[], Any]) -> Any:
    """``compute()`` for the regressor ``kind`` of ``robot`` at poses ``q`` with ``extra`` arguments,
    kept for the latest :data:`MAX_REGRESSORS` calls. The regressors of the gravity bases depend on
    the commanded poses and the nominal geometry only, not on the parameters a fit moves, so its
    iterations find them here. The arrays returned are read-only (shared by every caller)."""
    q = np.ascontiguousarray(q, dtype=float)
    key = (kind, robot_key(robot), q.shape, hashlib.sha1(q.tobytes()).digest(), extra)
    with _REGRESSORS_LOCK:
        hit = _REGRESSORS.get(key)
        if hit is not None:
            _REGRESSORS.move_to_end(key)
            return hit[0]
    out = compute()
    arrays = [a for a in _arrays(out) if isinstance(a, np.ndarray)]
    for a in arrays:
        a.flags.writeable = False
    size = sum(a.nbytes for a in arrays)
    with _REGRESSORS_LOCK:
        if key not in _REGRESSORS:
            _REGRESSORS[key] = (out, size)
            _REGRESSOR_BYTES[0] += size
        while len(_REGRESSORS) > 1 and (
            len(_REGRESSORS) > MAX_REGRESSORS or _REGRESSOR_BYTES[0] > MAX_REGRESSOR_BYTES
        ):
            _REGRESSOR_BYTES[0] -= _REGRESSORS.popitem(last=False)[1][1]
    return out


def _arrays(out) -> tuple:
    """The arrays of a memoized value: a tuple's items, a :class:`Frames`' fields, or the value."""
    if isinstance(out, tuple):
        return out
    if dataclasses.is_dataclass(out):
        return tuple(getattr(out, f.name) for f in dataclasses.fields(out))
    return (out,)


def nominal_frames(robot: Robot, q: np.ndarray) -> Frames:
    """:func:`~kpioed_drake.robot.kinematics.forward_kinematics` at the nominal geometry, memoized
    (:func:`memoized`; read-only arrays): the regressors of every gravity basis and moment start
    from the same frames of the same poses."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return memoized("frames", robot, q, (), lambda: forward_kinematics(robot, q))


def robot_key(robot: Robot) -> tuple:
    """What the caches of a robot's gravity quantities are keyed by: its name, file, joint types,
    nominal geometry (a chain's joint placements too), masses and centres of mass."""
    chain = robot.chain
    return (
        robot.name,
        robot.conventions,
        robot.source,
        robot.geometry.tobytes(),
        robot.masses.tobytes(),
        robot.coms.tobytes(),
        b"" if chain is None else chain.R_PJ.tobytes() + chain.p_PJ.tobytes(),
    )


def gravity_model(robot: Robot) -> GravityModel:
    """The cached :class:`GravityModel` of ``robot``."""
    key = robot_key(robot)
    if key not in _GRAVITY_CACHE:
        if len(_GRAVITY_CACHE) > 16:
            _GRAVITY_CACHE.clear()
        _GRAVITY_CACHE[key] = GravityModel(robot)
    return _GRAVITY_CACHE[key]


def gravity_torques(
    robot: Robot,
    q: np.ndarray,
    *,
    payload_kg: float | np.ndarray | None = None,
    p_FP: np.ndarray | None = None,
    with_dq: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """(n, nj) gravity generalized forces [N m] (Drake sign: the torque gravity exerts on the joint)."""
    return gravity_model(robot).torques(q, payload_kg=payload_kg, p_FP=p_FP, with_dq=with_dq)


# ----------------------------------------------------------------------------------------------
# Resolving sizes
# ----------------------------------------------------------------------------------------------
def reference_poses(robot: Robot, n: int = _N_REFERENCE) -> np.ndarray:
    """(n, nj) seeded poses uniform within the joint limits [rad] (the 'joint box' of SPEC's sizes)."""
    rng = np.random.default_rng(_REFERENCE_SEED)
    return rng.uniform(robot.lower, robot.upper, size=(n, robot.n_joints))


def elastic_lever(model: TrackerModel, joint: int) -> float:
    """Largest tool displacement per unit compliance [mm per rad/(N m)] over the joint box.

    ``max_q |tau_i(q)| * |d p_WQ / d q_i|`` over :func:`reference_poses` (no payload).
    """
    robot = model.robot
    key = ("lever", robot_key(robot), model.p_FQ.tobytes(), joint)
    if key not in _GRAVITY_CACHE:
        q = reference_poses(robot)
        tau = gravity_torques(robot, q)[:, joint - 1]
        _, J = point_jacobian(forward_kinematics(robot, q, model.geometry), model.p_FQ)
        lever = np.linalg.norm(J[:, :, model.layout.joint_angle(joint)], axis=1)
        _GRAVITY_CACHE[key] = float(np.max(np.abs(tau) * lever))
    return _GRAVITY_CACHE[key]
