"""The measurement model with effects, its Jacobian, and the effects' columns for design and KPI.

``h = s_T R_TW (s * p_WQ(p, q_cmd + delta) - p_WT - v t)``; see :mod:`kpioed_drake.effects`. A column
or base compliance (:mod:`.compliance`) turns the reflector point about its pivot first:
``p_WQ -> p_WQ + sum_e c_e m_e(q_cmd) x (p_WQ - o_e(q_cmd))``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypedDict, Unpack

import numpy as np

from kpioed_drake.effects import compliance as cp
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.gravity import gravity_model, gravity_torques
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.effects.gravity_basis import basis_factors
from kpioed_drake.effects.model import Effect, parse_effect, resolve, scale_and_drift
from kpioed_drake.errors import InputError
from kpioed_drake.robot.kinematics import cross, flange_point, point_jacobian
from kpioed_drake.tracker.measurement import TrackerModel, tracker_jacobian


# ----------------------------------------------------------------------------------------------
# The measurement model with effects and its Jacobian
# ----------------------------------------------------------------------------------------------
def joint_deltas(
    model: TrackerModel,
    q_cmd: np.ndarray,
    effects: Sequence[Effect],
    *,
    payload_kg: float | np.ndarray | None = None,
    with_dq: bool = False,
    tau: np.ndarray | None = None,
    side: np.ndarray | None = None,
) -> tuple:
    """Joint-angle errors of the joint effects at their values [rad], and what their columns need.

    The joint effects (:data:`~kpioed_drake.effects.model.JOINT_FAMILIES`) add ``factor(q) @ values``
    to joint i: elasticity ``tau_i``, gear ``(sin n q_i, cos n q_i)``, scale ``q_i``, coupling
    ``q_j``, backlash ``sign(tau_i)`` (``tau``: gravity torques at the commanded angles; ``side``
    (n, 6): the backlash's side per pose instead, e.g. its expectation when the masses are uncertain).

    Returns:
        delta: (n, 6) angle errors; factors: list over effects of (n, n_params) or None (the
        derivative of delta_joint w.r.t. the effect's parameters); with ``with_dq`` also
        ddelta (n, 6, 6) ``d delta_i / d q_j`` and dfactors (list of (n, 6, n_params) or None).
    """
    q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
    n = q.shape[0]
    need_dtau = with_dq and any(e.family == "joint_elasticity" for e in effects)
    fams = {e.family for e in effects}
    need_tau = "joint_elasticity" in fams or ("backlash" in fams and side is None)
    dtau = None
    if (need_tau and tau is None) or need_dtau:
        out = gravity_torques(model.robot, q, payload_kg=payload_kg, p_FP=model.p_FP, with_dq=need_dtau)
        tau_g, dtau = out if need_dtau else (out, None)
        tau = tau_g if tau is None else tau
    nj = model.robot.n_joints
    delta = np.zeros((n, nj))
    ddelta = np.zeros((n, nj, nj))
    factors, dfactors = [], []
    for e in effects:
        if e.family == "joint_elasticity":
            i = e.joint - 1
            f = tau[:, i : i + 1]
            df = dtau[:, i, :, None] if with_dq else None
        elif e.family == BASIS_FAMILY:  # gravity basis: f = Y_j(q) (+ the payload torque)
            i = e.joint - 1
            fb = basis_factors(model, q, e, tau=tau, payload_kg=payload_kg, with_dq=with_dq)
            f, df = fb if with_dq else (fb, None)
        elif e.family == "gear_cyclic":
            i = e.joint - 1
            nq = e.harmonic * q[:, i]
            f = np.stack([np.sin(nq), np.cos(nq)], axis=1)
            if with_dq:
                df = np.zeros((n, nj, 2))
                df[:, i, 0] = e.harmonic * np.cos(nq)
                df[:, i, 1] = -e.harmonic * np.sin(nq)
            else:
                df = None
        elif e.family in ("joint_scale", "joint_coupling", "backlash"):
            i = e.joint - 1
            j = e.coupled - 1 if e.family == "joint_coupling" else i
            if e.family == "backlash":
                f = np.sign(tau[:, i : i + 1]) if side is None else side[:, i : i + 1]
            else:
                f = q[:, j : j + 1]
            df = np.zeros((n, nj, 1)) if with_dq else None
            if with_dq and e.family != "backlash":  # d sign(tau)/dq = 0 almost everywhere
                df[:, j, 0] = 1.0
        else:
            factors.append(None)
            dfactors.append(None)
            continue
        v = e.value_array()
        delta[:, i] += f @ v
        if with_dq:
            ddelta[:, i, :] += df @ v
        factors.append(f)
        dfactors.append(df)
    if with_dq:
        return delta, factors, ddelta, dfactors
    return delta, factors


def effect_rotations(
    model: TrackerModel,
    q: np.ndarray,
    effects: Sequence[Effect],
    payload_kg: float | np.ndarray | None,
    *,
    with_dq: bool = False,
    target: np.ndarray | None = None,
) -> dict:
    """{index in effects: [:class:`~.compliance.Rotation` per parameter]} of the effects that turn
    what they carry: the compliances (payload at ``model.p_FP``) and the lateral basis. On a tree robot a
    row's point turns only if the joint carries its target's link (``target`` (n,); None: the
    flange)."""
    out = {}
    for i, e in enumerate(effects):
        if e.family in cp.FAMILIES:
            rot = cp.rotation(
                model.robot, e.family, e.joint, q, p_FP=model.p_FP, payload_kg=payload_kg, with_dq=with_dq
            )
            out[i] = [rot]
        elif e.family == lb.FAMILY:
            on = cp.carried_rows(model, e.joint, target, q.shape[0])
            out[i] = lb.lateral_basis(model.robot, e.joint).rotations(model.robot, q, with_dq=with_dq, on=on)
        on = cp.carried_rows(model, e.joint, target, len(q)) if i in out and e.family != lb.FAMILY else None
        if on is not None:
            out[i] = [cp.on_carried_rows(r, on) for r in out[i]]
    return out


def _turned(effects, rots: dict, p_W: np.ndarray):
    """``p_W`` (n, 3) turned by the rotation effects at their values, and their rotation vector (n, 3)
    (an effect's parameters about one pivot summed first: one cross product an effect)."""
    w = np.zeros_like(p_W)
    shift = np.zeros_like(p_W)
    for i, parts in rots.items():
        vals = effects[i].value_array()
        if not parts:
            continue
        w_i = sum(v * r.m for v, r in zip(vals, parts, strict=True))
        w += w_i
        if all(r.pivot is parts[0].pivot for r in parts):
            shift += cross(w_i, p_W - parts[0].pivot)
        else:
            shift += sum(v * r.displacement(p_W) for v, r in zip(vals, parts, strict=True))
    return p_W + shift, w


class Conditions(TypedDict, total=False):
    """The per-row conditions of :func:`augmented_response` (those of :func:`augmented_jacobian`,
    whose docstring details each)."""

    temperature_C: float | np.ndarray | None
    time_s: float | np.ndarray | None
    payload_kg: float | np.ndarray | None
    tau: np.ndarray | None
    target: np.ndarray | None
    side: np.ndarray | None
    compliance_payload_kg: float | np.ndarray | None


def augmented_response(
    model: TrackerModel, q_cmd: np.ndarray, effects: Sequence[Effect] = (), **conditions: Unpack[Conditions]
) -> np.ndarray:
    """(n, 3) response of the measurement model with effects [mm], without the Jacobian.

    The same ``h`` as :func:`augmented_jacobian` (same arguments), at a fraction of the cost.
    """
    c = conditions
    q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
    effects = list(effects)
    payload_kg, target = c.get("payload_kg"), c.get("target")
    delta, _ = joint_deltas(model, q, effects, payload_kg=payload_kg, tau=c.get("tau"), side=c.get("side"))
    p_WQ = flange_point(model.frames(q + delta), model.target_points(target), model.target_links(target))
    pay_c = payload_kg if payload_kg is not None else c.get("compliance_payload_kg")
    p_WQ, _ = _turned(effects, effect_rotations(model, q, effects, pay_c, target=target), p_WQ)
    s, drift, _, _, s_T = scale_and_drift(effects, q.shape[0], c.get("temperature_C"), c.get("time_s"))
    return s_T[:, None] * ((s[:, None] * p_WQ - model.p_WT - drift) @ model.R_WT)


def augmented_jacobian(
    model: TrackerModel,
    q_cmd: np.ndarray,
    effects: Sequence[Effect] = (),
    *,
    temperature_C: float | np.ndarray | None = None,
    time_s: float | np.ndarray | None = None,
    payload_kg: float | np.ndarray | None = None,
    with_dq: bool = False,
    tau: np.ndarray | None = None,
    target: np.ndarray | None = None,
    side: np.ndarray | None = None,
    compliance_payload_kg: float | np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    """Response of the measurement model with effects and its Jacobian.

    ``h = s_T R_TW (s p_WQ(p, q_cmd + delta) - p_WT - v t)`` with the effects at their values (unknown
    values count as zero).

    Args:
        model: the geometric model.
        q_cmd: (n, 6) commanded joint angles [rad].
        effects: list of :class:`Effect`.
        temperature_C, time_s, payload_kg: (n,) or scalars, as the effects need them.
        with_dq: also the derivative of the effect columns w.r.t. the commanded joint angles.
        tau: (n, 6) precomputed gravity torques (payload included) to skip Drake.
        target: (n,) 0-based target of each row (None: target 0); a payload sits at target 0.
        side: (n, 6) a backlash's side per pose (None: ``sign(tau)``, :func:`joint_deltas`).
        compliance_payload_kg: the payload of the compliances' moments when ``payload_kg`` is None
            (a fit's conditions: its joint torques ``tau`` hold the payload already).

    Compliances (:mod:`.compliance`): ``H`` is exact for their rotation at its value (the rotated
    geometric columns and the payload point's moment); the other effects' columns and ``dE`` take
    the rotation to first order (exact at c = 0, a design's linearisation point).

    Returns:
        h (n, 3) [mm]; H (n, 3, n_full) dh/dp; E (n, 3, k) dh/d(effect parameters), effects in order,
        internal units; with ``with_dq`` also dE (n, 6, 3, k) ``dE / dq_cmd_j``.
    """
    q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
    n = q.shape[0]
    effects = list(effects)
    jd = joint_deltas(model, q, effects, payload_kg=payload_kg, with_dq=with_dq, tau=tau, side=side)
    delta = jd[0]
    q_act = q + delta
    frames = model.frames(q_act)
    out = point_jacobian(
        frames, model.target_points(target), link=model.target_links(target), with_dq=with_dq
    )
    lay = model.layout
    pay_c = payload_kg if payload_kg is not None else compliance_payload_kg
    rots = effect_rotations(model, q, effects, pay_c, with_dq=with_dq, target=target)
    p_raw, theta_raw = out[0], out[1][:, :, lay.joint_angles]
    out = _compliance_turned(effects, rots, out, with_dq)
    p_WQ, JW = out[0], out[1]
    s, drift, temp, tvec, s_T = scale_and_drift(effects, n, temperature_C, time_s)
    R_TW = model.R_WT.T
    h, H = tracker_jacobian(model, p_WQ, JW, scale=s, offset=drift, target=target)
    theta = JW[:, :, lay.joint_angles]  # (n, 3, 6) dp_WQ/dq_act: the theta columns
    _add_payload_point_columns(
        H, model, q, effects, rots, payload_kg, s=s, R_TW=R_TW, theta=theta, p_raw=p_raw
    )
    E, dE, dp_dq = _effect_columns(
        model, effects, jd, rots, out, p_raw, theta_raw, s=s, R_TW=R_TW, temp=temp, tvec=tvec, with_dq=with_dq
    )
    h, H, E, dE = _tracker_scaled(effects, h, H, E, dE, dp_dq, s=s, s_T=s_T, temp=temp, R_TW=R_TW)
    if with_dq:
        return h, H, E, dE
    return h, H, E


def _compliance_turned(effects, rots: dict, out: tuple, with_dq: bool) -> tuple:
    """``out`` of :func:`point_jacobian` (the reflector point (n, 3), its Jacobian (n, 3, n_full) and
    with ``with_dq`` its derivative) turned by the compliances at their values, ``(I + [w]x)``."""
    if not rots:
        return out
    p_WQ, w = _turned(effects, rots, out[0])
    JW = out[1]
    JW = JW + cross(w[:, None, :], JW.transpose(0, 2, 1)).transpose(0, 2, 1)
    if not with_dq:
        return p_WQ, JW
    dJW = out[2]
    return p_WQ, JW, dJW + cross(w[:, None, None, :], dJW.transpose(0, 1, 3, 2)).transpose(0, 1, 3, 2)


def _add_payload_point_columns(H, model, q, effects, rots: dict, payload_kg, *, s, R_TW, theta, p_raw):
    """Add to ``H``'s reflector columns (target 0, in place) what a payload there changes with them:
    its torque on the elastic joints and its moment on the compliances."""
    lay = model.layout
    if payload_kg is not None and np.any(np.asarray(payload_kg) != 0):
        # the payload sits at p_FQ: its torque, hence an elastic deflection, depends on p_FQ
        c_el = np.zeros(model.robot.n_joints)
        for e in effects:
            if e.family == "joint_elasticity":
                c_el[e.joint - 1] += e.value_array()[0]
        if np.any(c_el):
            dtau_dp = gravity_model(model.robot).payload_torques_dp(q, payload_kg)  # (n,6,3)
            dq_dp = c_el[None, :, None] * dtau_dp  # (n,6,3) d q_act / d p_FQ
            dh_dq = s[:, None, None] * np.einsum("ab,nbj->naj", R_TW, theta)  # (n,3,6)
            H[:, :, lay.target(0)] += np.einsum("naj,njd->nad", dh_dq, dq_dp)
    for i, (r, *_) in rots.items():  # a payload's moment moves with the reflector point p_FQ
        if r.dm_dp is not None:
            v = effects[i].value_array()[0]
            dp = v * cross(r.dm_dp.transpose(0, 2, 1), (p_raw - r.pivot)[:, None, :])  # (n, 3 d, 3)
            H[:, :, lay.target(0)] += s[:, None, None] * np.einsum("ab,ndb->nad", R_TW, dp)


def _effect_columns(model, effects, jd, rots: dict, out, p_raw, theta_raw, *, s, R_TW, temp, tvec, with_dq):
    """The effects' columns E (n, 3, k) before the tracker scale, with ``with_dq`` also dE
    (n, 6, 3, k) and the reflector's derivative dp_dq (n, 6, 3) w.r.t. the commanded angles (else
    None, None)."""
    lay = model.layout
    p_WQ, JW = out[0], out[1]
    n = p_WQ.shape[0]
    theta = JW[:, :, lay.joint_angles]  # (n, 3, 6) dp_WQ/dq_act
    factors = jd[1]
    k = sum(e.n_params for e in effects)
    E = np.zeros((n, 3, k))
    dE = dp_dq = None
    if with_dq:
        dJW = out[2]
        A = np.eye(model.robot.n_joints)[None] + jd[2]  # d q_act / d q_cmd
        dE = np.zeros((n, model.robot.n_joints, 3, k))
        dp_dq = np.einsum("nal,nlj->nja", theta, A)  # (n,6,3)
        dp_raw = np.einsum("nal,nlj->nja", theta_raw, A)
    col = 0
    for idx, (e, f, *rest) in enumerate(zip(effects, factors, *(jd[3:4] if with_dq else ()), strict=True)):
        m = e.n_params
        if f is not None:  # a joint-angle error of joint e.joint
            c = lay.joint_angle(e.joint)
            G = s[:, None] * (JW[:, :, c] @ R_TW.T)  # (n,3) s R_TW dp/dq_i
            E[:, :, col : col + m] = G[:, :, None] * f[:, None, :]
            if with_dq:
                df = rest[0]
                dG = np.einsum("nlb,nlj->njb", dJW[:, :, :, c], A) @ R_TW.T * s[:, None, None]  # (n,6,3)
                dE[:, :, :, col : col + m] = (
                    dG[..., None] * f[:, None, None, :] + G[:, None, :, None] * df[:, :, None, :]
                )
        elif idx in rots:
            E[:, :, col : col + m] = cp.rotation_columns(rots[idx], p_raw, s, R_TW)
            for c, r in enumerate(rots[idx] if with_dq else (), start=col):
                if with_dq:
                    d = cross(r.dm, (p_raw - r.pivot)[:, None, :]) + cross(r.m[:, None, :], dp_raw - r.dpivot)
                    dE[:, :, :, c] = s[:, None, None] * (d @ R_TW.T)
        elif e.family == "thermal_expansion":
            E[:, :, col] = (p_WQ @ R_TW.T) * temp[:, None]
            if with_dq:
                dE[:, :, :, col] = (dp_dq @ R_TW.T) * temp[:, None, None]
        elif e.family == "tracker_drift":
            E[:, :, col : col + 3] = -R_TW[None] * tvec[:, None, None]
        col += m
    return E, dE, dp_dq


def _tracker_scaled(effects, h, H, E, dE, dp_dq, *, s, s_T, temp, R_TW):
    """``h``, ``H``, ``E`` and ``dE`` times the tracker's distance scale ``s_T`` (it multiplies
    everything: ``h = s_T h_0``) and the tracker scale's own column; unchanged without one."""
    ts = [k for k, e in enumerate(effects) if e.family == "tracker_scale"]
    if ts:
        k = E.shape[2]
        col = sum(e.n_params for e in effects[: ts[0]])
        E[:, :, col] = h * temp[:, None]
        if dE is not None:
            dE *= s_T[:, None, None, None]
            dE[:, :, :, col] = (dp_dq @ R_TW.T) * (s * temp)[:, None, None]
        h, H = s_T[:, None] * h, s_T[:, None, None] * H
        E[:, :, np.arange(k) != col] *= s_T[:, None, None]
    return h, H, E, dE


def true_measurements(
    model_true: TrackerModel,
    q_cmd: np.ndarray,
    effects: Sequence[Effect | str] = (),
    *,
    temperature_C: float | np.ndarray | None = None,
    time_s: float | np.ndarray | None = None,
    payload_kg: float | np.ndarray | None = None,
    target: np.ndarray | None = None,
) -> np.ndarray:
    """Noise-free reflector positions in the tracker frame [mm] of a robot with these effects.

    Args:
        model_true: the true geometry, tracker pose and reflector offset.
        q_cmd: (n, 6) commanded joint angles [rad] (what the data file records).
        effects: list of :class:`Effect` (or texts for :func:`parse_effect` with given values);
            each must have values (an elasticity drawn by ``tool_mm`` is resolved for this robot).
        temperature_C, time_s, payload_kg: (n,) or scalars; required by thermal expansion and
            drift; payload adds to the gravity torques of joint elasticity.
        target: (n,) 0-based target of each row (None: target 0).

    Returns:
        (n, 3) positions [mm].
    """
    effs = []
    for e in effects:
        e = parse_effect(e, model=model_true) if isinstance(e, str) else e
        e = resolve(e, model_true)
        if e.values is None:
            raise InputError(
                f"effect {e.name} has no value: give one ('{e.name}=...') or draw one with a random generator"
            )
        effs.append(e)
    h, _, _ = augmented_jacobian(
        model_true,
        q_cmd,
        effs,
        temperature_C=temperature_C,
        time_s=time_s,
        payload_kg=payload_kg,
        target=target,
    )
    return h


def extension_columns(
    model: TrackerModel,
    q: np.ndarray,
    extensions: Sequence[Effect | str],
    *,
    temperature_C: float | np.ndarray | None = None,
    time_s: float | np.ndarray | None = None,
    payload_kg: float | np.ndarray | None = None,
    with_dq: bool = False,
    target: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Jacobian columns of the measurement w.r.t. the parameters of model extensions.

    To extend calibration or design by effects, append these columns to the geometric ones:
    ``H_aug = concat(H[:, :, free], E)`` (and ``dH_aug`` likewise with ``dE``). Evaluated at the
    extensions' values (unknown values = 0, the usual linearisation point of a design), in
    internal units (see :class:`Effect`); scale them like the other columns (divide by sigma).

    Args:
        model: the geometric model.
        q: (n, 6) joint angles [rad].
        extensions: effects or texts (``"joint_elasticity:2"``, ``"gear_cyclic:4:2"``, ...).
        temperature_C, time_s: (n,) per-pose values, required by thermal expansion and drift.
        payload_kg: scalar or (n,), adds to the gravity torques.
        with_dq: also return the derivative w.r.t. the joint angles.
        target: (n,) 0-based target of each row (None: target 0).

    Returns:
        E (n, 3, k); with ``with_dq`` also dE (n, 6, 3, k) ``dE[i, j] = dE[i] / dq_j``.
    """
    effs = [parse_effect(e, model=model) if isinstance(e, str) else e for e in extensions]
    out = augmented_jacobian(
        model,
        q,
        effs,
        temperature_C=temperature_C,
        time_s=time_s,
        payload_kg=payload_kg,
        with_dq=with_dq,
        target=target,
    )
    if with_dq:
        return out[2], out[3]
    return out[2]


def extension_param_names(extensions: Sequence[Effect | str]) -> list[str]:
    """Names of the extension parameters in column order, e.g. ``gear_cyclic:4:2.a``."""
    effs = [parse_effect(e) if isinstance(e, str) else e for e in extensions]
    return [nm for e in effs for nm in e.param_names]


def effect_kpi_columns(
    model: TrackerModel,
    q_work: np.ndarray,
    effects: Sequence[Effect],
    *,
    tool_offset: Sequence[float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """(3, k) derivative of the TCP in W at ``q_work`` w.r.t. the effect parameters.

    KPI conditions: no payload, temperature ``T_REF_C`` (thermal column 0), tracker irrelevant
    (drift columns 0). Joint effects move the TCP by ``dp/dq_i * factor(q_work)``, a compliance by
    ``m(q_work) x (p_TCP - pivot)`` (the robot's own weight).
    """
    q = np.asarray(q_work, dtype=float)[None, :]
    effects = list(effects)
    _, factors = joint_deltas(model, q, effects)
    frames = model.frames(q)
    p, J = point_jacobian(frames, model.p_FQ + np.asarray(tool_offset, dtype=float))
    rots = effect_rotations(model, q, effects, None)
    cols = []
    for i, (e, f) in enumerate(zip(effects, factors, strict=True)):
        if i in rots:
            cols.append(np.stack([r.displacement(p)[0] for r in rots[i]], axis=1))
        elif f is None:
            cols.append(np.zeros((3, e.n_params)))
        else:
            cols.append(J[0, :, model.layout.joint_angle(e.joint)][:, None] * f[0][None, :])
    return np.concatenate(cols, axis=1) if cols else np.zeros((3, 0))


def effect_tcp_shift(
    model: TrackerModel,
    q_work: np.ndarray,
    effects: Sequence[Effect],
    *,
    tool_offset: Sequence[float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """(3,) TCP displacement in W at ``q_work`` caused by the effects at their values (KPI conditions)."""
    q = np.asarray(q_work, dtype=float)[None, :]
    effects = list(effects)
    delta, _ = joint_deltas(model, q, effects)
    off = model.p_FQ + np.asarray(tool_offset, dtype=float)
    p, _ = _turned(
        effects, effect_rotations(model, q, effects, None), flange_point(model.frames(q + delta), off)
    )
    return p[0] - flange_point(model.frames(q), off)[0]
