"""Gravity torques of a robot's links (Drake) and of a payload, and the elastic lever of a joint.

See :mod:`kpioed_drake.effects` for the sign and unit conventions.
"""

from __future__ import annotations

import numpy as np
from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

from kpioed_drake.kinematics import cross, forward_kinematics, point_jacobian
from kpioed_drake.measurement import TrackerModel
from kpioed_drake.models import N_JOINTS, Robot
from kpioed_drake.plant import build_scene

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

    def link_torques(self, q, *, with_dq: bool = False):
        """(n, 6) generalized gravity forces [N m] at joint angles q (n, 6) [rad].

        With ``with_dq`` also (n, 6, 6) ``d tau_i / d q_j`` (Drake AutoDiffXd).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        plant, ctx = self.scene.plant, self.scene.plant_context
        tau = np.empty((q.shape[0], N_JOINTS))
        for k, qk in enumerate(q):
            plant.SetPositions(ctx, qk)
            tau[k] = plant.CalcGravityGeneralizedForces(ctx)
        if not with_dq:
            return tau
        if self._ad is None:
            diagram = self.scene.diagram.ToAutoDiffXd()
            plant_ad = diagram.GetSubsystemByName(plant.get_name())
            context = diagram.CreateDefaultContext()
            self._ad = (plant_ad, plant_ad.GetMyContextFromRoot(context), context)
        plant_ad, ctx_ad, _ = self._ad
        dtau = np.empty((q.shape[0], N_JOINTS, N_JOINTS))
        for k, qk in enumerate(q):
            plant_ad.SetPositions(ctx_ad, InitializeAutoDiff(qk).ravel())
            dtau[k] = ExtractGradient(plant_ad.CalcGravityGeneralizedForces(ctx_ad))
        return tau, dtau

    def payload_torques(self, q, payload_kg, p_FP, *, with_dq: bool = False):
        """(n, 6) torques [N m] of point masses ``payload_kg`` (scalar or (n,)) at ``p_FP`` [mm].

        ``tau_i = F . (w_i x r_i)`` with ``F = m g`` [N], ``w_i`` the axis of joint i and ``r_i`` the
        point relative to that axis [m]. Derivative: for ``j <= i`` the whole term turns about
        ``w_j``: ``F . (w_j x (w_i x r_i))``; for ``j > i`` only the point moves:
        ``F . (w_i x (w_j x r_j))``.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = np.broadcast_to(np.asarray(payload_kg, dtype=float), (q.shape[0],))
        fr = forward_kinematics(self.robot, q)
        p = fr.o[:, N_JOINTS] + np.einsum("nij,j->ni", fr.R[:, N_JOINTS], np.asarray(p_FP, float))
        w = fr.joint_axes  # (n,6,3)
        r = (p[:, None, :] - fr.joint_points) * 1e-3  # (n,6,3) [m]
        F = m[:, None] * self.g[None, :]  # (n,3) [N]
        wxr = cross(w, r)
        tau = np.einsum("nc,nic->ni", F, wxr)
        if not with_dq:
            return tau
        full = cross(w[:, :, None, :], wxr[:, None, :, :])  # [n, j, i]: w_j x (w_i x r_i)
        part = cross(w[:, None, :, :], wxr[:, :, None, :])  # [n, j, i]: w_i x (w_j x r_j)
        jj, ii = np.arange(N_JOINTS)[:, None], np.arange(N_JOINTS)[None, :]
        d = np.where((jj <= ii)[None, :, :, None], full, part)
        dtau = np.einsum("nc,njic->nij", F, d)
        return tau, dtau

    def payload_torques_dp(self, q, payload_kg) -> np.ndarray:
        """(n, 6, 3) derivative of :meth:`payload_torques` w.r.t. ``p_FP`` [N m / mm].

        ``F . (w_i x R_WF dp) = (F x w_i) . R_WF dp``, times 1e-3 (mm -> m).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        m = np.broadcast_to(np.asarray(payload_kg, dtype=float), (q.shape[0],))
        fr = forward_kinematics(self.robot, q)
        F = m[:, None] * self.g[None, :]
        Fxw = cross(F[:, None, :], fr.joint_axes)  # (n,6,3)
        return 1e-3 * np.einsum("nic,ncd->nid", Fxw, fr.R[:, N_JOINTS])

    def torques(self, q, *, payload_kg=None, p_FP=None, with_dq: bool = False):
        """Link torques plus the payload's (if ``payload_kg`` is given) [N m]."""
        out = self.link_torques(q, with_dq=with_dq)
        if payload_kg is None or np.all(np.asarray(payload_kg) == 0):
            return out
        pay = self.payload_torques(q, payload_kg, p_FP, with_dq=with_dq)
        if not with_dq:
            return out + pay
        return out[0] + pay[0], out[1] + pay[1]


_GRAVITY_CACHE: dict = {}


def _robot_key(robot: Robot) -> tuple:
    return (
        robot.name,
        robot.conventions,
        robot.geometry.tobytes(),
        robot.masses.tobytes(),
        robot.coms.tobytes(),
    )


def gravity_model(robot: Robot) -> GravityModel:
    """The cached :class:`GravityModel` of ``robot``."""
    key = _robot_key(robot)
    if key not in _GRAVITY_CACHE:
        if len(_GRAVITY_CACHE) > 16:
            _GRAVITY_CACHE.clear()
        _GRAVITY_CACHE[key] = GravityModel(robot)
    return _GRAVITY_CACHE[key]


def gravity_torques(robot: Robot, q, *, payload_kg=None, p_FP=None, with_dq: bool = False):
    """(n, 6) gravity generalized forces [N m] (Drake sign: the torque gravity exerts on the joint)."""
    return gravity_model(robot).torques(q, payload_kg=payload_kg, p_FP=p_FP, with_dq=with_dq)


# ----------------------------------------------------------------------------------------------
# Resolving sizes
# ----------------------------------------------------------------------------------------------
def reference_poses(robot: Robot, n: int = _N_REFERENCE) -> np.ndarray:
    """(n, 6) seeded poses uniform within the joint limits [rad] (the 'joint box' of SPEC's sizes)."""
    rng = np.random.default_rng(_REFERENCE_SEED)
    return rng.uniform(robot.lower, robot.upper, size=(n, N_JOINTS))


def elastic_lever(model: TrackerModel, joint: int) -> float:
    """Largest tool displacement per unit compliance [mm per rad/(N m)] over the joint box.

    ``max_q |tau_i(q)| * |d p_WQ / d q_i|`` over :func:`reference_poses` (no payload).
    """
    robot = model.robot
    key = ("lever", _robot_key(robot), model.p_FQ.tobytes(), joint)
    if key not in _GRAVITY_CACHE:
        q = reference_poses(robot)
        tau = gravity_torques(robot, q)[:, joint - 1]
        _, J = point_jacobian(forward_kinematics(robot, q, model.geometry), model.p_FQ)
        lever = np.linalg.norm(J[:, :, model.layout.joint_angle(joint)], axis=1)
        _GRAVITY_CACHE[key] = float(np.max(np.abs(tau) * lever))
    return _GRAVITY_CACHE[key]
