"""Laser-tracker measurement model (paper eq. 3 and 4) and the parameter vector.

The full parameter vector ``p`` (33 entries) is, in this order:

- 24 joint parameters, joint-major, each joint in its own convention's order
  (DH ``theta, d, a, alpha``; Hayati ``theta, a, alpha, beta``) [rad, mm];
- 6 tracker pose parameters: position ``p_WT`` in W [mm] and three small rotations ``r`` [rad]
  about the tracker axes, ``R_WT = R_WT_ref @ Rx(rx) @ Ry(ry) @ Rz(rz)``;
- 3 reflector coordinates ``p_FQ`` in the flange frame F [mm].

Six of them trade exactly against others and are held at their nominal values (SPEC, the gauge):
theta1, d1 (against the tracker pose) and theta6, d6, a6, alpha6 (against the reflector offset).
The other 27 are estimated.

Model response (eq. 3): ``h(p, q) = R_WT^T (p_WQ(p, q) - p_WT)``, the reflector in the tracker
frame. Incidence (eq. 4): ``cos(beta) = z_F . (p_WT - p_WQ)/|p_WT - p_WQ| >= cos(30 deg)``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.kinematics import (
    Frames,
    flange_point,
    forward_kinematics,
    point_jacobian,
    point_velocity_jacobian,
)
from kpioed_drake.models import N_JOINTS, Cell, Robot

N_FULL = 33
FIXED_NAMES = ("theta1", "d1", "theta6", "d6", "a6", "alpha6")
TRACKER_NAMES = ("tracker_x", "tracker_y", "tracker_z", "tracker_rx", "tracker_ry", "tracker_rz")
REFLECTOR_NAMES = ("reflector_x", "reflector_y", "reflector_z")
ANGLE_PREFIXES = ("theta", "alpha", "beta", "tracker_r")


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def small_rotation(r) -> np.ndarray:
    """``Rx(r0) @ Ry(r1) @ Rz(r2)`` (3, 3)."""
    return _rot(0, r[0]) @ _rot(1, r[1]) @ _rot(2, r[2])


@dataclasses.dataclass(frozen=True)
class ParameterLayout:
    """Names, units and the estimated subset of the 33-vector.

    Attributes:
        names: (33,) parameter names.
        is_angle: (33,) True for angles [rad], False for lengths [mm].
        free: (27,) indices of the estimated parameters into the 33-vector.
    """

    names: tuple[str, ...]
    is_angle: np.ndarray
    free: np.ndarray

    @property
    def free_names(self) -> list[str]:
        return [self.names[i] for i in self.free]

    @property
    def n_free(self) -> int:
        return int(self.free.size)

    def scale(self, reach: float) -> np.ndarray:
        """(27,) SPEC's scaling to millimetres at the tool: lengths 1, angles times the reach."""
        return np.where(self.is_angle[self.free], reach, 1.0)


def parameter_layout(robot: Robot, *, fixed: tuple[str, ...] = FIXED_NAMES) -> ParameterLayout:
    """The 33 parameter names of ``robot`` and the indices of the estimated ones."""
    names = tuple(robot.param_names()) + TRACKER_NAMES + REFLECTOR_NAMES
    is_angle = np.array([n.startswith(ANGLE_PREFIXES) for n in names])
    unknown = set(fixed) - set(names)
    if unknown:
        raise ValueError(f"fixed parameters not in the model: {sorted(unknown)}")
    free = np.array([i for i, n in enumerate(names) if n not in fixed])
    return ParameterLayout(names=names, is_angle=is_angle, free=free)


@dataclasses.dataclass(frozen=True)
class TrackerModel:
    """Robot + tracker + reflector: everything the measurement model needs.

    Attributes:
        robot: the robot (conventions, limits).
        p: (33,) parameter values [rad, mm].
        R_WT_ref: (3, 3) reference tracker orientation the small rotations refer to.
        layout: which parameters are estimated.
    """

    robot: Robot
    p: np.ndarray
    R_WT_ref: np.ndarray
    layout: ParameterLayout

    @property
    def geometry(self) -> np.ndarray:
        return self.p[:24].reshape(N_JOINTS, 4)

    @property
    def p_WT(self) -> np.ndarray:
        return self.p[24:27]

    @property
    def R_WT(self) -> np.ndarray:
        return self.R_WT_ref @ small_rotation(self.p[27:30])

    @property
    def p_FQ(self) -> np.ndarray:
        return self.p[30:33]

    def with_params(self, p: np.ndarray) -> TrackerModel:
        return dataclasses.replace(self, p=np.asarray(p, dtype=float))

    def rebased(self) -> TrackerModel:
        """Same model with the tracker's small rotations folded into ``R_WT_ref``."""
        p = self.p.copy()
        p[27:30] = 0.0
        return dataclasses.replace(self, p=p, R_WT_ref=self.R_WT)

    def frames(self, q) -> Frames:
        return forward_kinematics(self.robot, q, self.geometry)


def nominal_model(robot: Robot, cell: Cell) -> TrackerModel:
    """The nominal model: the robot's table, the cell's tracker pose and reflector offset."""
    p = np.concatenate([robot.geometry.ravel(), cell.p_WT, np.zeros(3), cell.p_FQ])
    return TrackerModel(robot=robot, p=p, R_WT_ref=cell.R_WT, layout=parameter_layout(robot))


def reflector_world(model: TrackerModel, q) -> np.ndarray:
    """(n, 3) reflector position in W [mm]."""
    return flange_point(model.frames(q), model.p_FQ)


def measure(model: TrackerModel, q) -> np.ndarray:
    """Model response h(p, q) (eq. 3): (n, 3) reflector positions in the tracker frame [mm]."""
    p_WQ = reflector_world(model, q)
    return (p_WQ - model.p_WT) @ model.R_WT


def measurement_jacobian(model: TrackerModel, q, *, with_dq: bool = False, frames: Frames | None = None):
    """Jacobian of :func:`measure` w.r.t. the 33 parameters.

    ``frames`` is ``model.frames(q)`` if the caller has it already.

    Returns:
        h: (n, 3) [mm].
        H: (n, 3, 33) dh/dp.
        dH (with ``with_dq``): (n, 6, 3, 33), derivative of H w.r.t. the joint angles.
    """
    frames = model.frames(q) if frames is None else frames
    out = point_jacobian(frames, model.p_FQ, with_dq=with_dq)
    p_WQ, JW = out[0], out[1]
    R_TW = model.R_WT.T
    h = (p_WQ - model.p_WT) @ R_TW.T
    n = h.shape[0]
    H = np.zeros((n, 3, N_FULL))
    H[:, :, :24] = np.einsum("ab,nbc->nac", R_TW, JW[:, :, :24])
    H[:, :, 24:27] = -R_TW
    # h = Rr^T v with v = R_ref^T (p_WQ - p_WT) = Rr h, so dh/dr_k = G_k v, G_k = d(Rr^T)/dr_k.
    Rr = small_rotation(model.p[27:30])
    G = _drot_transposed(model.p[27:30])
    v = h @ Rr.T
    for k in range(3):
        H[:, :, 27 + k] = v @ G[k].T
    H[:, :, 30:33] = np.einsum("ab,nbc->nac", R_TW, JW[:, :, 24:27])
    if not with_dq:
        return h, H
    dJW = out[2]
    dH = np.zeros((n, N_JOINTS, 3, N_FULL))
    dH[..., :24] = np.einsum("ab,njbc->njac", R_TW, dJW[..., :24])
    dH[..., 30:33] = np.einsum("ab,njbc->njac", R_TW, dJW[..., 24:27])
    dh_dq = point_velocity_jacobian(frames, p_WQ[:, None, :], np.array([N_JOINTS]))[:, 0] @ R_TW.T
    dv = dh_dq @ Rr.T
    for k in range(3):
        dH[:, :, :, 27 + k] = dv @ G[k].T
    return h, H, dH


def _drot_transposed(r) -> list[np.ndarray]:
    """``d(Rr^T)/dr_k`` for ``Rr = Rx(r0) Ry(r1) Rz(r2)``, k = 0, 1, 2."""
    Rx, Ry, Rz = _rot(0, r[0]), _rot(1, r[1]), _rot(2, r[2])
    Gx = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float)
    Gy = np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], dtype=float)
    Gz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=float)
    return [(Rx @ Gx @ Ry @ Rz).T, (Rx @ Ry @ Gy @ Rz).T, (Rx @ Ry @ Rz @ Gz).T]


def incidence_cosine(model: TrackerModel, q, *, frames: Frames | None = None) -> np.ndarray:
    """(n,) cosine of the incidence angle between the reflector axis z_F and the line of sight."""
    frames = model.frames(q) if frames is None else frames
    p = flange_point(frames, model.p_FQ)
    g = model.p_WT - p
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    return np.einsum("ni,ni->n", frames.R[:, N_JOINTS, :, 2], g)


def kpi_jacobian(model: TrackerModel, q_work, tool_offset=(0.0, 0.0, 0.0)):
    """The KPI: TCP position in W at ``q_work`` and its Jacobian w.r.t. the 33 parameters.

    The TCP is the reflector point plus ``tool_offset`` (flange axes, [mm]); the tracker parameters
    do not move it (their columns are zero).

    Returns:
        s: (3,) [mm]; Js: (3, 33).
    """
    frames = model.frames(np.asarray(q_work, dtype=float)[None, :])
    p, J = point_jacobian(frames, model.p_FQ + np.asarray(tool_offset, dtype=float))
    Js = np.zeros((3, N_FULL))
    Js[:, :24] = J[0, :, :24]
    Js[:, 30:33] = J[0, :, 24:27]
    return p[0], Js
