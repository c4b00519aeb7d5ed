"""Compensation: joint values with which a calibrated model reaches what the nominal one promised.

A controller commands joint values computed with the nominal kinematics. :func:`compensate_program`
finds, for each such program pose ``q_nom``, the joint values ``q`` with which the calibrated model
(geometry and estimated non-geometric effects) puts the target point where the nominal model puts
it, with the flange orientation the nominal model gives:

    p_WQ(q) = p_WQ_nom(q_nom),   R_WF(q) = R_WF_nom(q_nom)       (6 equations)

:func:`reach_targets` finds joint values that put the target point at given points in W (3
equations) with the least joint motion from a start pose, then keeps the start's flange orientation
as a second objective where the robot can (a second solve of all 6 equations from there, kept for
the rows where it converges), so position always takes precedence. The solution is the one near
the start: a point the start's configuration (elbow, wrist) cannot reach continuously is reported
unreachable (give start joints near the goal).

The forward map is one function, :func:`model_pose`: the geometric model at the joint values plus
the effects' joint deltas (elasticity, gear, scale, coupling, backlash, gravity basis), rotated by
the compliances and scaled by thermal expansion, at each row's conditions, as the measurement model
of :mod:`kpioed_drake.effects.response` (the tracker's own effects do not move the robot).

Solver: damped Gauss-Newton (Levenberg-Marquardt) over all rows at once with closed-form Jacobians:
``dp/dq_j = w_j x (p - o_j)`` and angular velocity ``w_j`` for a revolute joint, ``w_j`` and 0 for
a prismatic one, through ``d q_actual / d q = I + d delta/dq`` of the joint effects, times the
thermal scale, turned by the compliance rotation ``omega`` plus its own derivative
(``d omega/dq x (p - o) - omega x do/dq``; the orientation rows to first order in ``omega`` ~ 1e-4
rad). Residual: position [mm] and ``ORIENTATION_LENGTH_MM`` times the rotation vector [rad] (1 mrad
weighs as 0.1 mm; a row with a solution has both at zero, the weight shapes only the path and the
best pose of an unreachable row). Each step is the minimum-norm damped step
``J^T (J J^T + lambda I)^-1 e`` (a redundant robot moves least), at most ``MAX_STEP``; joints at a
limit whose step points outward are held there and the others take the step (projected LM); steps
are clamped to the limits.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from kpioed_drake.effects.model import ROTATION_FAMILIES, T_REF_C, Effect
from kpioed_drake.effects.response import effect_rotations, joint_deltas
from kpioed_drake.errors import InputError
from kpioed_drake.robot.jointmap import commandable_motions
from kpioed_drake.robot.kinematics import cross
from kpioed_drake.tracker.measurement import TrackerModel

ORIENTATION_LENGTH_MM = 100.0
"""Length that weighs the orientation residual [mm per rad]: 1 mrad counts as 0.1 mm."""
TOL_MM = 1e-3
"""A row is reached when the model's point is within this distance of the goal [mm]."""
TOL_RAD = 1e-6
"""... and its flange orientation within this angle (program rows) [rad]."""
MAX_ITERATIONS = 60
_STOP_MM, _STOP_RAD = 1e-9, 1e-12  # a row stops iterating below these errors
_LAM0, _LAM_MAX = 1e-9, 1e6  # damping, relative to the mean diagonal of J^T J
MAX_STEP = (0.2, 50.0)
"""Largest change of a revolute [rad] and a prismatic [mm] joint in one iteration (the step is
shortened to it): far from the start the linearisation does not hold, near a singularity the
undamped step is long."""


@dataclasses.dataclass(frozen=True)
class Compensation:
    """Solved joint values of n rows.

    Attributes:
        q: (n, nj) joint values [rad; prismatic mm], within the limits.
        q_start: (n, nj) where the iteration started (the program pose, or the target's start).
        residual_mm: (n,) distance of the model's target point from the goal at ``q`` [mm].
        residual_rad: (n,) angle between the model's flange orientation and the goal's (program
            rows), or the start's (target rows) [rad].
        reachable: (n,) within ``TOL_MM`` (and, for program rows, ``TOL_RAD``).
        reasons: (n,) why a row is not reachable ('' if it is).
        iterations: iterations of the slowest row (targets: of both solves).
    """

    q: np.ndarray
    q_start: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    reachable: np.ndarray
    reasons: tuple[str, ...]
    iterations: int


def _condition(conditions: dict, name: str, n: int, effect: Effect) -> np.ndarray:
    value = conditions.get(name)
    if value is None:
        raise InputError(f"effect {effect.name} needs column {name!r} (one value per row)")
    return np.broadcast_to(np.asarray(value, dtype=float), (n,))


def model_pose(
    model: TrackerModel,
    q: np.ndarray,
    effects: Sequence[Effect] = (),
    conditions: Mapping[str, np.ndarray] | None = None,
    *,
    target: int = 0,
    jacobian: bool = False,
) -> tuple[np.ndarray, ...]:
    """Target point and flange orientation of a model with effects, at the commanded joint values.

    Args:
        model: the geometric model (joint rows, target offsets).
        q: (n, nj) commanded joint values [rad; prismatic mm].
        effects: :class:`~kpioed_drake.effects.model.Effect` with values (unknown values count as 0).
        conditions: ``{"temperature_C": (n,), "payload_kg": (n,)}`` as the effects need them.
        target: 0-based target whose point is returned.
        jacobian: also return the Jacobian.

    Returns:
        p_WQ (n, 3) [mm], R_WF (n, 3, 3); with ``jacobian`` also J (n, 6, nj): rows 0-2
        ``dp_WQ/dq`` [mm/rad, mm/mm], rows 3-5 the angular velocity ``dw/dq`` [rad/rad, rad/mm].
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, nj = q.shape
    effects, conditions = list(effects), conditions or {}
    A = np.broadcast_to(np.eye(nj), (n, nj, nj))
    q_act = q
    if any(e.family not in ROTATION_FAMILIES for e in effects):
        jd = joint_deltas(model, q, effects, payload_kg=conditions.get("payload_kg"), with_dq=jacobian)
        q_act = q + jd[0]
        A = A + jd[2] if jacobian else A
    frames = model.frames(q_act)
    rows = np.full(n, target)
    link = model.target_links(rows)  # the target's link (a tree robot's arm), None: the flange
    R_F, o_F = frames.at_link(link)
    p = o_F + R_F @ model.target_offsets[target]
    w, shift = np.zeros((n, 3)), np.zeros((n, 3))  # compliance: rotation vector, point shift
    dw, dshift = np.zeros((n, nj, 3)), np.zeros((n, nj, 3))  # their d/dq through m(q) and o(q)
    s = np.ones(n)  # thermal length scale
    pay = conditions.get("payload_kg")
    rots = effect_rotations(model, q, effects, pay, with_dq=jacobian, target=rows)
    for i, e in enumerate(effects):
        if i in rots:
            for c, r in zip(e.value_array(), rots[i], strict=True):
                w, shift = w + c * r.m, shift + c * r.displacement(p)
                if jacobian:
                    dw += c * r.dm
                    dshift += c * (cross(r.dm, (p - r.pivot)[:, None, :]) - cross(r.m[:, None, :], r.dpivot))
        elif e.family == "thermal_expansion":
            c = e.value_array()[0]
            s = s + c * (_condition(conditions, "temperature_C", n, e) - T_REF_C)
    p_out = s[:, None] * (p + shift)
    R_out = Rotation.from_rotvec(w).as_matrix() @ R_F if np.any(w) else R_F
    if not jacobian:
        return p_out, R_out
    At = A.transpose(0, 2, 1)
    on = frames.point_path(link)  # the joints moving the target (None: all)
    on = 1.0 if on is None else on[:, :, None]
    Jp = At @ (frames.joint_motion(p) * on)  # (n, nj, 3): dp/dq_j through q_act
    Jw = At @ np.where(frames.prismatic[None, :, None], 0.0, frames.joint_axes * on)
    Jp = Jp + cross(w[:, None, :], Jp) + dshift
    Jw = np.einsum("nab,njb->nja", _exp(w), Jw) + np.einsum("nab,njb->nja", _left_jacobian(w), dw)
    J = np.concatenate([s[:, None, None] * Jp, Jw], axis=2).transpose(0, 2, 1)
    return p_out, R_out, J


def _exp(w: np.ndarray) -> np.ndarray:
    """(n, 3, 3) the rotation of rotation vectors ``w`` (n, 3) [rad]."""
    return Rotation.from_rotvec(w).as_matrix()


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    """(n, 3, 3) SO(3)'s left Jacobian at ``w`` (n, 3): the angular velocity of ``exp(w)`` per
    ``dw``, ``I + (1 - cos t)/t^2 [w] + (t - sin t)/t^3 [w]^2`` (series below 1e-4 rad)."""
    t = np.linalg.norm(w, axis=1)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t**2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6.0 - t**2 / 120.0, (ts - np.sin(ts)) / ts**3)
    W = np.zeros((len(w), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    W = W - W.transpose(0, 2, 1)
    return np.eye(3) + a[:, None, None] * W + b[:, None, None] * (W @ W)


def rotation_error(R_goal: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vector in W that turns ``R`` (n, 3, 3) into ``R_goal`` [rad]."""
    return Rotation.from_matrix(R_goal @ R.transpose(0, 2, 1)).as_rotvec()


def _damped_solve(J: np.ndarray, e: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """(n, nj) minimum-norm damped step ``J^T (J J^T + lam s I)^-1 e`` (``s``: mean diagonal of J J^T)."""
    m = J.shape[1]
    JJ = J @ J.transpose(0, 2, 1)
    scale = np.maximum(np.trace(JJ, axis1=1, axis2=2) / m, 1e-6)  # a zero J: a zero step
    JJ = JJ + (lam * scale)[:, None, None] * np.eye(m)
    return np.einsum("nmj,nm->nj", J, np.linalg.solve(JJ, e[..., None])[..., 0])


@dataclasses.dataclass(frozen=True)
class _Goal:
    """What the rows must reach: points (n, 3) [mm] and flange orientations (n, 3, 3); ``rows``
    of the residual solved for (6: both; 3: the point only, the orientation's rows only reported)."""

    p: np.ndarray
    R: np.ndarray
    rows: int


def _residual(model, effects, conditions, target, goal: _Goal, rows, q, *, jacobian: bool):
    """Residual (m, 6) [mm, mm] of ``rows`` at q (m, nj), its merit (m,) and Jacobian (m, 6, nj)."""
    cond = {
        k: None if v is None else np.broadcast_to(v, goal.p.shape[:1])[rows] for k, v in conditions.items()
    }
    out = model_pose(model, q, effects, cond, target=target, jacobian=jacobian)
    e = np.concatenate(
        [goal.p[rows] - out[0], ORIENTATION_LENGTH_MM * rotation_error(goal.R[rows], out[1])], 1
    )
    merit = np.sum(e[:, : goal.rows] ** 2, axis=1)
    J = None
    if jacobian:
        J = out[2] * np.where(np.arange(6) < 3, 1.0, ORIENTATION_LENGTH_MM)[None, :, None]
    return e, merit, J


def _held(q, dq, lo, up):
    """(n, nj) joints at a limit whose step points outward."""
    tol = 1e-12 * np.maximum(1.0, np.abs(q))
    return ((q <= lo + tol) & (dq < 0)) | ((q >= up - tol) & (dq > 0))


def _solve(model, q0, goal: _Goal, effects=(), conditions=None, *, target=0) -> tuple[np.ndarray, int]:
    """Projected Levenberg-Marquardt over all rows; (q (n, nj), iterations of the slowest row).

    A row stops when its point is within ``_STOP_MM`` (and, solving for the orientation too, its
    orientation within ``_STOP_RAD``), or when its damping exceeds ``_LAM_MAX`` (no step decreases
    its residual: the best pose within the limits, or a singular one).
    """
    lo, up = model.robot.lower, model.robot.upper
    q = np.clip(np.asarray(q0, dtype=float), lo, up)
    cond = conditions or {}
    lam = np.full(q.shape[0], _LAM0)
    active = np.ones(q.shape[0], dtype=bool)
    on_map = commandable_motions(model.robot)  # steps along the joint map's couplings only
    it = 0
    while active.any() and it < MAX_ITERATIONS:
        it += 1
        rows = np.flatnonzero(active)
        e, merit, J = _residual(model, effects, cond, target, goal, rows, q[rows], jacobian=True)
        J, e_solved = J[:, : goal.rows] @ on_map, e[:, : goal.rows]
        dq = _damped_solve(J, e_solved, lam[rows])
        held = _held(q[rows], dq, lo, up)
        if held.any():
            dq = _damped_solve((J * ~held[:, None, :]) @ on_map, e_solved, lam[rows])
        cap = np.where(model.robot.prismatic, MAX_STEP[1], MAX_STEP[0])
        dq = dq / np.maximum(1.0, np.max(np.abs(dq) / cap, axis=1))[:, None]
        q_new = np.clip(q[rows] + dq, lo, up)
        e_new, merit_new, _ = _residual(model, effects, cond, target, goal, rows, q_new, jacobian=False)
        better = merit_new < merit
        q[rows[better]] = q_new[better]
        e = np.where(better[:, None], e_new, e)
        lam[rows] = np.where(better, np.maximum(0.1 * lam[rows], 1e-15), 10.0 * lam[rows])
        done = np.linalg.norm(e[:, :3], axis=1) < _STOP_MM
        if goal.rows == 6:
            done &= np.linalg.norm(e[:, 3:], axis=1) < _STOP_RAD * ORIENTATION_LENGTH_MM
        active[rows] = ~(done | (lam[rows] > _LAM_MAX))
    return q, it


def _finish(model, q, q_start, goal: _Goal, effects, conditions, target, iterations) -> Compensation:
    """The :class:`Compensation` of solved rows: residuals, reachability and the reasons."""
    rows = np.arange(q.shape[0])
    e, _, _ = _residual(model, effects, conditions or {}, target, goal, rows, q, jacobian=False)
    res_mm = np.linalg.norm(e[:, :3], axis=1)
    res_rad = np.linalg.norm(e[:, 3:], axis=1) / ORIENTATION_LENGTH_MM
    ok = res_mm <= TOL_MM
    if goal.rows == 6:
        ok &= res_rad <= TOL_RAD
    lo, up = model.robot.lower, model.robot.upper
    at_limit = (q <= lo + 1e-9) | (q >= up - 1e-9)
    reasons = []
    for k in range(q.shape[0]):
        if ok[k]:
            reasons.append("")
            continue
        left = f"{res_mm[k]:.4g} mm" + (f" and {np.rad2deg(res_rad[k]):.3g} deg" if goal.rows == 6 else "")
        joints = ", ".join(str(j + 1) for j in np.flatnonzero(at_limit[k]))
        why = f"joint {joints} at its limit" if joints else "out of reach or at a singularity"
        reasons.append(f"not reachable: {left} left ({why})")
    return Compensation(q, q_start, res_mm, res_rad, ok, tuple(reasons), iterations)


def compensate_program(
    model: TrackerModel,
    nominal: TrackerModel,
    q_program: np.ndarray,
    *,
    effects: Sequence[Effect] = (),
    conditions: Mapping[str, np.ndarray] | None = None,
    target: int = 0,
) -> Compensation:
    """Joint values with which ``model`` (and ``effects``) reach the program's nominal poses.

    Args:
        model: the calibrated model; nominal: the controller's (nominal) model of the same robot.
        q_program: (n, nj) joint values the nominal controller commands [rad; prismatic mm].
        effects: estimated effects (values in internal units) of the calibrated model.
        conditions: per-row ``temperature_C``, ``payload_kg`` as the effects need them.
        target: 0-based target of both models (its point and the flange orientation are matched).

    Returns:
        :class:`Compensation`, started from the program's joint values.
    """
    q0 = np.atleast_2d(np.asarray(q_program, dtype=float))
    p, R = model_pose(nominal, q0, target=target)
    goal = _Goal(p, R, 6)
    q, it = _solve(model, q0, goal, effects, conditions, target=target)
    return _finish(model, q, q0, goal, effects, conditions, target, it)


def reach_targets(
    model: TrackerModel,
    points: np.ndarray,
    q_start: np.ndarray,
    *,
    effects: Sequence[Effect] = (),
    conditions: Mapping[str, np.ndarray] | None = None,
    target: int = 0,
) -> Compensation:
    """Joint values that put the model's target point at ``points`` (n, 3) in W [mm].

    Position only (3 equations), from ``q_start`` (n, nj), in two passes: the point with the least
    joint motion from the start (minimum-norm steps); then, from there, the point together with
    the start's flange orientation (6 equations), kept for the rows where it converges (a six-joint
    robot: the one such pose near the start; a redundant one: the least motion). Rows where it does
    not (the orientation out of reach within the limits, a robot of fewer joints) keep the first
    pass. ``residual_rad`` of the result is the orientation's change from the start.
    """
    q0 = np.atleast_2d(np.asarray(q_start, dtype=float))
    _, R = model_pose(model, q0, effects, conditions, target=target)
    points = np.atleast_2d(np.asarray(points, dtype=float))
    goal = _Goal(points, R, 3)
    q1, it1 = _solve(model, q0, goal, effects, conditions, target=target)
    both = _Goal(points, R, 6)
    q2, it2 = _solve(model, q1, both, effects, conditions, target=target)
    held = _finish(model, q2, q0, both, effects, conditions, target, it2).reachable
    q = np.where(held[:, None], q2, q1)
    return _finish(model, q, q0, goal, effects, conditions, target, it1 + it2)
