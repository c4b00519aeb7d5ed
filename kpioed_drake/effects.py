"""Non-geometric effects: what the kinematic model leaves out (SPEC "Measured data and model discrepancy").

Four effect families, each a few parameters on top of the 33-vector of
:mod:`kpioed_drake.measurement` (joint numbers are 1-based, as in SPEC and on the command line):

============================  ============================================  ====================
family (``parse_effect``)     model                                         parameters (inside)
============================  ============================================  ====================
``joint_elasticity:i[=c]``    joint i deflects by ``c * tau_i(q)``          c [rad/(N m)]
``gear_cyclic:i:n[=a,b]``     joint i angle error ``a sin(n q_i) + b cos``  a, b [rad] (text: deg)
``thermal_expansion[=k]``     robot lengths scale by ``1 + k (T - T_ref)``  k [1/K]
``tracker_drift[=vx,vy,vz]``  tracker origin moves by ``v t`` (v in W)      v [mm/s] (text: mm/min)
============================  ============================================  ====================

Conventions (the choices SPEC leaves open, kept here in one place):

- Joint angles ``q`` in the data are the *commanded* (encoder) angles. Joint-angle effects act as
  ``q_actual = q_cmd + delta(q_cmd)``; the deflection and the gear error are evaluated at the
  commanded angles (the difference to evaluating them at ``q_actual`` is second order, below
  1e-7 rad at SPEC sizes).
- Gravity torque ``tau(q)`` [N m] is Drake's ``MultibodyPlant.CalcGravityGeneralizedForces`` on the
  plant of :func:`kpioed_drake.plant.build_scene` built from the robot's *nominal* geometry, link
  masses and centres of mass (metres inside Drake). Drake returns the generalized force that
  gravity exerts on each joint (the term on the right of ``M v' + C v = tau_g + tau``), so a joint
  held by a spring of compliance c at the commanded angle settles at
  ``q_actual = q_cmd + c * tau_g``: a positive c means the joint yields in the direction gravity
  pushes it. Joint 1 of every shipped robot turns about the vertical axis: gravity has no torque
  there and elasticity of joint 1 cannot be seen (``parse_effect`` refuses it).
- Payload: a point mass ``payload_kg`` at the reflector/TCP point ``p_FQ`` of the model; its torque
  is ``J_v^T (m g)`` with ``J_v`` the translational Jacobian of that point from the numpy kinematics
  (same nominal geometry). Its joint-angle derivative is closed form (see ``_payload_torque``).
- Thermal expansion scales *every* length of the robot side by ``s = 1 + k (T - T_REF_C)``: all
  ``a`` and ``d`` of the kinematic table and the reflector offset ``p_FQ`` (the reflector holder is
  steel too). Because the reflector position is homogeneous of degree one in those lengths, this
  is exactly ``p_WQ -> s p_WQ`` (a scaling about the base origin W). The tracker position does not
  scale. ``T_REF_C`` = 20 C: the geometric parameters describe the robot at 20 C. A temperature that
  is constant over the data only rescales the geometry (absorbed by the length parameters); only its
  variation over the data identifies k.
- Tracker drift: the tracker origin moves in W as ``p_WT(t) = p_WT + v t`` (``t`` = ``time_s``).
  A constant offset is the tracker position itself; only the linear part is an effect.

Measurement model with effects (everything in the tracker frame, mm)::

    h = R_TW (s * p_WQ(p, q_cmd + delta) - p_WT - v t)

:func:`true_measurements` evaluates it (noise-free) for simulation; :func:`augmented_jacobian`
returns its Jacobian w.r.t. the 33 geometric parameters and the effect parameters (closed form,
finite-difference checked in ``tests/test_effects.py``); :func:`extension_columns` returns just the
effect columns (and their joint-angle derivative) so that calibration and design can append them to
``F1``.

Realistic sizes (SPEC), used when ``parse_effect`` draws a value with a random generator:

- elasticity: the largest tool displacement it causes over the joint box is drawn uniformly in
  0.1-1 mm (``tool_mm``); c follows from the robot (:func:`resolve`: max over 2000 seeded poses
  within the joint limits of ``|tau_i| * |dp_WQ/dq_i|``, no payload);
- gear: a and b each uniform in 0.003-0.02 deg with a random sign;
- thermal: k = 11.7e-6 /K (steel), not drawn (without ``rng``: unknown, like the others);
- drift: speed uniform in 0.005-0.05 mm/min, direction uniform on the sphere.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.kinematics import cross, forward_kinematics, point_jacobian
from kpioed_drake.measurement import N_FULL, TrackerModel, small_rotation
from kpioed_drake.models import N_JOINTS, Robot

FAMILIES = ("joint_elasticity", "gear_cyclic", "thermal_expansion", "tracker_drift")
"""Effect names as in SPEC (and ``none`` for a model that explains the data)."""

N_PARAMS = {"joint_elasticity": 1, "gear_cyclic": 2, "thermal_expansion": 1, "tracker_drift": 3}
UNITS = {
    "joint_elasticity": "rad/(N m)",
    "gear_cyclic": "deg",
    "thermal_expansion": "1/K",
    "tracker_drift": "mm/min",
}
"""Units of the *displayed* values (text syntax, reports); inside the code see :class:`Effect`."""

T_REF_C = 20.0
"""Reference temperature [C]: the geometric parameters describe the robot at this temperature."""
STEEL_K = 11.7e-6
"""Linear expansion coefficient of steel [1/K] (SPEC)."""
ELASTIC_TOOL_MM = (0.1, 1.0)
GEAR_DEG = (0.003, 0.02)
DRIFT_MM_PER_MIN = (0.005, 0.05)
_DISPLAY = {"joint_elasticity": 1.0, "gear_cyclic": np.pi / 180.0, "thermal_expansion": 1.0}
_DISPLAY["tracker_drift"] = 1.0 / 60.0  # mm/min -> mm/s
_N_REFERENCE = 2000
_REFERENCE_SEED = 20170710


@dataclasses.dataclass(frozen=True)
class Effect:
    """One non-geometric effect.

    Attributes:
        family: one of :data:`FAMILIES`.
        joint: 1-based joint (elasticity, gear) or None.
        harmonic: n of ``gear_cyclic`` or None.
        values: the parameters in internal units, or None if unknown (to be estimated):
            elasticity ``(c,)`` [rad/(N m)]; gear ``(a, b)`` [rad]; thermal ``(k,)`` [1/K];
            drift ``(vx, vy, vz)`` [mm/s] in W.
        tool_mm: for an elasticity drawn by size: the largest tool displacement [mm] over the joint
            box; :func:`resolve` turns it into c for a robot.
    """

    family: str
    joint: int | None = None
    harmonic: int | None = None
    values: tuple[float, ...] | None = None
    tool_mm: float | None = None

    @property
    def n_params(self) -> int:
        return N_PARAMS[self.family]

    @property
    def key(self) -> tuple:
        """(family, joint, harmonic): what a diagnosis has to name."""
        return (self.family, self.joint, self.harmonic)

    @property
    def name(self) -> str:
        """Text form without values, e.g. ``gear_cyclic:4:2``."""
        parts = [self.family]
        if self.joint is not None:
            parts.append(str(self.joint))
        if self.harmonic is not None:
            parts.append(str(self.harmonic))
        return ":".join(parts)

    @property
    def param_names(self) -> list[str]:
        sub = {
            "joint_elasticity": ["c"],
            "gear_cyclic": ["a", "b"],
            "thermal_expansion": ["k"],
            "tracker_drift": ["vx", "vy", "vz"],
        }[self.family]
        return [f"{self.name}.{s}" for s in sub]

    def value_array(self) -> np.ndarray:
        """(n_params,) internal values; zeros when unknown."""
        if self.values is None:
            return np.zeros(self.n_params)
        return np.asarray(self.values, dtype=float)

    def with_values(self, values) -> Effect:
        return dataclasses.replace(self, values=tuple(float(v) for v in np.ravel(values)))

    def display_values(self, values=None) -> list[float]:
        """Values (or any same-shaped array, e.g. standard deviations) in display units."""
        v = self.value_array() if values is None else np.asarray(values, dtype=float)
        return [float(x) for x in np.ravel(v) / _DISPLAY[self.family]]

    def text(self) -> str:
        """Parseable text with the values, e.g. ``gear_cyclic:4:2=0.01,-0.005`` (display units)."""
        if self.values is None:
            return self.name
        return self.name + "=" + ",".join(f"{x:.6g}" for x in self.display_values())

    def to_dict(self) -> dict:
        """JSON-ready description (SPEC names, 1-based joints, display units)."""
        out: dict = {"effect": self.family}
        if self.joint is not None:
            out["joint"] = self.joint
        if self.harmonic is not None:
            out["harmonic"] = self.harmonic
        if self.values is not None:
            dv = self.display_values()
            out["value"] = dv[0] if len(dv) == 1 else dv
        out["unit"] = UNITS[self.family]
        if self.tool_mm is not None:
            out["tool_mm"] = self.tool_mm
        return out


# ----------------------------------------------------------------------------------------------
# Parsing
# ----------------------------------------------------------------------------------------------
_SYNTAX = (
    "joint_elasticity:JOINT[=c rad/(N m)], gear_cyclic:JOINT:N[=a,b deg], thermal_expansion[=k 1/K], "
    "tracker_drift[=vx,vy,vz mm/min]"
)


def _numbers(text: str, count: int, spec: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != count or not all(np.isfinite(vals)):
        raise InputError(f"effect {spec!r}: expected {count} comma-separated number(s) after '='")
    return vals


def _joint(token: str, spec: str) -> int:
    if not re.fullmatch(r"[1-6]", token.strip()):
        raise InputError(f"effect {spec!r}: joint must be 1..6 (1-based), got {token!r}")
    return int(token)


def parse_effect(
    text: str, rng: np.random.Generator | None = None, *, model: TrackerModel | None = None
) -> Effect:
    """Parse an effect from its text form.

    Syntax: ``joint_elasticity:2`` / ``joint_elasticity:2=2e-6`` (c in rad per N m);
    ``gear_cyclic:4:2`` / ``gear_cyclic:4:2=0.01,-0.005`` (joint 4, harmonic 2, a and b in deg);
    ``thermal_expansion`` / ``thermal_expansion=11.7e-6`` (k in 1/K, default steel);
    ``tracker_drift`` / ``tracker_drift=0.01,0,-0.02`` (velocity in W, mm/min).

    Without a value: with ``rng`` a value of SPEC's realistic size is drawn (an elasticity as a tool
    displacement ``tool_mm``, turned into c by :func:`resolve` once the robot is known; pass
    ``model`` to resolve at once); without ``rng`` the values stay unknown (``values=None``: an
    extension to estimate). ``thermal_expansion`` drawn with ``rng`` is steel (``STEEL_K``), not random.

    Raises:
        InputError: unknown family, bad joint or harmonic, wrong number of values.
    """
    spec = str(text).strip()
    lhs, eq, rhs = spec.partition("=")
    parts = [p.strip() for p in lhs.split(":")]
    family = parts[0]
    if family not in FAMILIES:
        raise InputError(f"unknown effect {family!r} in {spec!r}; expected one of: {_SYNTAX}")
    given = rhs.strip() if eq else None
    if eq and not given:
        raise InputError(f"effect {spec!r}: nothing after '='")
    if family == "joint_elasticity":
        if len(parts) != 2:
            raise InputError(f"effect {spec!r}: expected joint_elasticity:JOINT[=c], e.g. joint_elasticity:2")
        joint = _joint(parts[1], spec)
        if joint == 1:
            raise InputError(
                f"effect {spec!r}: joint 1 turns about the vertical axis; gravity exerts no torque on it, "
                "so its elasticity has no effect (use joints 2..6)"
            )
        if given is not None:
            (c,) = _numbers(given, 1, spec)
            return Effect(family, joint, None, (c,))
        if rng is None:
            return Effect(family, joint)
        eff = Effect(family, joint, tool_mm=float(rng.uniform(*ELASTIC_TOOL_MM)))
        return resolve(eff, model) if model is not None else eff
    if family == "gear_cyclic":
        if len(parts) != 3:
            raise InputError(f"effect {spec!r}: expected gear_cyclic:JOINT:N[=a,b], e.g. gear_cyclic:4:2")
        joint = _joint(parts[1], spec)
        if not re.fullmatch(r"[1-9]\d*", parts[2]):
            raise InputError(f"effect {spec!r}: harmonic N must be a positive integer (SPEC: 1 or 2)")
        n = int(parts[2])
        if given is not None:
            ab = np.deg2rad(_numbers(given, 2, spec))
            return Effect(family, joint, n, tuple(float(x) for x in ab))
        if rng is None:
            return Effect(family, joint, n)
        ab = rng.uniform(*GEAR_DEG, size=2) * rng.choice([-1.0, 1.0], size=2)
        return Effect(family, joint, n, tuple(float(x) for x in np.deg2rad(ab)))
    if len(parts) != 1:
        raise InputError(f"effect {spec!r}: {family} takes no joint")
    if family == "thermal_expansion":
        if given is None and rng is None:
            return Effect(family)
        k = _numbers(given, 1, spec)[0] if given is not None else STEEL_K
        return Effect(family, values=(float(k),))
    # tracker_drift
    if given is not None:
        v = np.asarray(_numbers(given, 3, spec)) / 60.0
        return Effect(family, values=tuple(float(x) for x in v))
    if rng is None:
        return Effect(family)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    v = d * rng.uniform(*DRIFT_MM_PER_MIN) / 60.0
    return Effect(family, values=tuple(float(x) for x in v))


def parse_effects(texts, rng: np.random.Generator | None = None, *, model: TrackerModel | None = None):
    """Parse several effects (a list, or one comma-free text per effect); duplicates are an error."""
    effects = [parse_effect(t, rng, model=model) for t in texts]
    keys = [e.key for e in effects]
    for k in keys:
        if keys.count(k) > 1:
            raise InputError(f"effect {effects[keys.index(k)].name!r} given more than once")
    return effects


# ----------------------------------------------------------------------------------------------
# Gravity torques (Drake)
# ----------------------------------------------------------------------------------------------
class GravityModel:
    """Gravity torques of a robot's links from its Drake plant (nominal geometry, model masses).

    Built once per robot and cached (:func:`gravity_model`).
    """

    def __init__(self, robot: Robot):
        from kpioed_drake.plant import build_scene

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
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

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
        lever = np.linalg.norm(J[:, :, 4 * (joint - 1)], axis=1)
        _GRAVITY_CACHE[key] = float(np.max(np.abs(tau) * lever))
    return _GRAVITY_CACHE[key]


def resolve(effect: Effect, model: TrackerModel) -> Effect:
    """An effect with concrete values: an elasticity drawn by ``tool_mm`` gets its c for this robot."""
    if effect.values is not None or effect.family != "joint_elasticity" or effect.tool_mm is None:
        return effect
    lever = elastic_lever(model, effect.joint)
    if lever <= 0:
        raise InputError(
            f"effect {effect.name}: gravity exerts no torque on joint {effect.joint} of this robot"
        )
    return dataclasses.replace(effect, values=(effect.tool_mm / lever,))


# ----------------------------------------------------------------------------------------------
# The measurement model with effects and its Jacobian
# ----------------------------------------------------------------------------------------------
def _per_pose(x, n: int, what: str, effect: str):
    if x is None:
        raise InputError(f"effect {effect} needs {what} for every pose (column {what!r} in the data)")
    arr = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(arr)):
        raise InputError(f"effect {effect}: {what} has a non-finite value")
    return arr


def _rotation_columns(model: TrackerModel, x: np.ndarray) -> np.ndarray:
    """(n, 3, 3) d h / d r_k of ``h = R_TW x`` with ``R_WT = R_ref Rx(r0) Ry(r1) Rz(r2)``."""
    r = model.p[27:30]
    Rx, Ry, Rz = (small_rotation(np.eye(3)[k] * r[k]) for k in range(3))
    G = [
        np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], float),
        np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], float),
        np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], float),
    ]
    dR = [Rx @ G[0] @ Ry @ Rz, Rx @ Ry @ G[1] @ Rz, Rx @ Ry @ Rz @ G[2]]  # d(R_r)/dr_k
    u = x @ model.R_WT_ref  # R_ref^T x
    return np.stack([u @ d for d in dR], axis=-1)  # (d R_r)^T u, as rows


def joint_deltas(model: TrackerModel, q_cmd, effects, *, payload_kg=None, with_dq: bool = False, tau=None):
    """Joint-angle errors of the joint effects at their values [rad], and what their columns need.

    Returns:
        delta: (n, 6) angle errors; factors: list over effects of (n, n_params) or None (the
        derivative of delta_joint w.r.t. the effect's parameters); with ``with_dq`` also
        ddelta (n, 6, 6) ``d delta_i / d q_j`` and dfactors (list of (n, 6, n_params) or None).
    """
    q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
    n = q.shape[0]
    need_tau = any(e.family == "joint_elasticity" for e in effects)
    dtau = None
    if need_tau and tau is None:
        out = gravity_torques(model.robot, q, payload_kg=payload_kg, p_FP=model.p_FQ, with_dq=with_dq)
        tau, dtau = (out, None) if not with_dq else out
    elif need_tau and with_dq:
        _, dtau = gravity_torques(model.robot, q, payload_kg=payload_kg, p_FP=model.p_FQ, with_dq=True)
    delta = np.zeros((n, N_JOINTS))
    ddelta = np.zeros((n, N_JOINTS, N_JOINTS))
    factors, dfactors = [], []
    for e in effects:
        if e.family == "joint_elasticity":
            i = e.joint - 1
            f = tau[:, i : i + 1]
            df = dtau[:, i, :, None] if with_dq else None
        elif e.family == "gear_cyclic":
            i = e.joint - 1
            nq = e.harmonic * q[:, i]
            f = np.stack([np.sin(nq), np.cos(nq)], axis=1)
            if with_dq:
                df = np.zeros((n, N_JOINTS, 2))
                df[:, i, 0] = e.harmonic * np.cos(nq)
                df[:, i, 1] = -e.harmonic * np.sin(nq)
            else:
                df = None
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


def augmented_jacobian(
    model: TrackerModel,
    q_cmd,
    effects=(),
    *,
    temperature_C=None,
    time_s=None,
    payload_kg=None,
    with_dq: bool = False,
    tau=None,
):
    """Response of the measurement model with effects and its Jacobian.

    ``h = R_TW (s p_WQ(p, q_cmd + delta) - p_WT - v t)`` with the effects at their values (unknown
    values count as zero).

    Args:
        model: the geometric model (33-vector).
        q_cmd: (n, 6) commanded joint angles [rad].
        effects: list of :class:`Effect`.
        temperature_C, time_s, payload_kg: (n,) or scalars, as the effects need them.
        with_dq: also the derivative of the effect columns w.r.t. the commanded joint angles.
        tau: (n, 6) precomputed gravity torques (payload included) to skip Drake.

    Returns:
        h (n, 3) [mm]; H (n, 3, 33) dh/dp; E (n, 3, k) dh/d(effect parameters), effects in order,
        internal units; with ``with_dq`` also dE (n, 6, 3, k) ``dE / dq_cmd_j``.
    """
    q = np.atleast_2d(np.asarray(q_cmd, dtype=float))
    n = q.shape[0]
    effects = list(effects)
    jd = joint_deltas(model, q, effects, payload_kg=payload_kg, with_dq=with_dq, tau=tau)
    delta, factors = jd[0], jd[1]
    q_act = q + delta
    frames = model.frames(q_act)
    out = point_jacobian(frames, model.p_FQ, with_dq=with_dq)
    p_WQ, JW = out[0], out[1]
    s = np.ones(n)
    temp = None
    drift = np.zeros((n, 3))
    tvec = None
    for e in effects:
        if e.family == "thermal_expansion":
            temp = _per_pose(temperature_C, n, "temperature_C", e.name) - T_REF_C
            s = s + e.value_array()[0] * temp
        elif e.family == "tracker_drift":
            tvec = _per_pose(time_s, n, "time_s", e.name)
            drift = drift + tvec[:, None] * e.value_array()[None, :]
    R_TW = model.R_WT.T
    x = s[:, None] * p_WQ - model.p_WT - drift
    h = x @ R_TW.T
    H = np.zeros((n, 3, N_FULL))
    H[:, :, :24] = s[:, None, None] * np.einsum("ab,nbc->nac", R_TW, JW[:, :, :24])
    H[:, :, 24:27] = -R_TW
    H[:, :, 27:30] = _rotation_columns(model, x)
    H[:, :, 30:33] = s[:, None, None] * np.einsum("ab,nbc->nac", R_TW, JW[:, :, 24:27])
    if payload_kg is not None and np.any(np.asarray(payload_kg) != 0):
        # the payload sits at p_FQ: its torque, hence an elastic deflection, depends on p_FQ
        c_el = np.zeros(N_JOINTS)
        for e in effects:
            if e.family == "joint_elasticity":
                c_el[e.joint - 1] += e.value_array()[0]
        if np.any(c_el):
            dtau_dp = gravity_model(model.robot).payload_torques_dp(q, payload_kg)  # (n,6,3)
            dq_dp = c_el[None, :, None] * dtau_dp  # (n,6,3) d q_act / d p_FQ
            dh_dq = s[:, None, None] * np.einsum("ab,nbj->naj", R_TW, JW[:, :, 0:24:4])  # (n,3,6)
            H[:, :, 30:33] += np.einsum("naj,njd->nad", dh_dq, dq_dp)
    k = sum(e.n_params for e in effects)
    E = np.zeros((n, 3, k))
    if with_dq:
        dJW = out[2]
        A = np.eye(N_JOINTS)[None] + jd[2]  # d q_act / d q_cmd
        dE = np.zeros((n, N_JOINTS, 3, k))
        G_all = JW[:, :, 0:24:4]  # (n,3,6) dp/dq_act (theta columns)
        dp_dq = np.einsum("nal,nlj->nja", G_all, A)  # (n,6,3)
    col = 0
    for e, f, *rest in zip(effects, factors, *(jd[3:4] if with_dq else ()), strict=True):
        m = e.n_params
        if e.family in ("joint_elasticity", "gear_cyclic"):
            c = 4 * (e.joint - 1)
            G = s[:, None] * (JW[:, :, c] @ R_TW.T)  # (n,3) s R_TW dp/dq_i
            E[:, :, col : col + m] = G[:, :, None] * f[:, None, :]
            if with_dq:
                df = rest[0]
                dG = np.einsum("nlb,nlj->njb", dJW[:, :, :, c], A) @ R_TW.T * s[:, None, None]  # (n,6,3)
                dE[:, :, :, col : col + m] = (
                    dG[..., None] * f[:, None, None, :] + G[:, None, :, None] * df[:, :, None, :]
                )
        elif e.family == "thermal_expansion":
            E[:, :, col] = (p_WQ @ R_TW.T) * temp[:, None]
            if with_dq:
                dE[:, :, :, col] = (dp_dq @ R_TW.T) * temp[:, None, None]
        else:
            E[:, :, col : col + 3] = -R_TW[None] * tvec[:, None, None]
        col += m
    if with_dq:
        return h, H, E, dE
    return h, H, E


def true_measurements(
    model_true: TrackerModel,
    q_cmd,
    effects=(),
    *,
    temperature_C=None,
    time_s=None,
    payload_kg=None,
) -> np.ndarray:
    """Noise-free reflector positions in the tracker frame [mm] of a robot with these effects.

    Args:
        model_true: the true geometry, tracker pose and reflector offset.
        q_cmd: (n, 6) commanded joint angles [rad] (what the data file records).
        effects: list of :class:`Effect` (or texts for :func:`parse_effect` with given values);
            each must have values (an elasticity drawn by ``tool_mm`` is resolved for this robot).
        temperature_C, time_s, payload_kg: (n,) or scalars; required by thermal expansion and
            drift; payload adds to the gravity torques of joint elasticity.

    Returns:
        (n, 3) positions [mm].
    """
    effs = []
    for e in effects:
        e = parse_effect(e) if isinstance(e, str) else e
        e = resolve(e, model_true)
        if e.values is None:
            raise InputError(
                f"effect {e.name} has no value: give one ('{e.name}=...') or draw one with a random generator"
            )
        effs.append(e)
    h, _, _ = augmented_jacobian(
        model_true, q_cmd, effs, temperature_C=temperature_C, time_s=time_s, payload_kg=payload_kg
    )
    return h


def extension_columns(
    model: TrackerModel,
    q,
    extensions,
    *,
    temperature_C=None,
    time_s=None,
    payload_kg=None,
    with_dq: bool = False,
):
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

    Returns:
        E (n, 3, k); with ``with_dq`` also dE (n, 6, 3, k) ``dE[i, j] = dE[i] / dq_j``.
    """
    effs = [parse_effect(e) if isinstance(e, str) else e for e in extensions]
    out = augmented_jacobian(
        model,
        q,
        effs,
        temperature_C=temperature_C,
        time_s=time_s,
        payload_kg=payload_kg,
        with_dq=with_dq,
    )
    if with_dq:
        return out[2], out[3]
    return out[2]


def extension_param_names(extensions) -> list[str]:
    """Names of the extension parameters in column order, e.g. ``gear_cyclic:4:2.a``."""
    effs = [parse_effect(e) if isinstance(e, str) else e for e in extensions]
    return [nm for e in effs for nm in e.param_names]


def effect_kpi_columns(model: TrackerModel, q_work, effects, *, tool_offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(3, k) derivative of the TCP in W at ``q_work`` w.r.t. the effect parameters.

    KPI conditions: no payload, temperature ``T_REF_C`` (thermal column 0), tracker irrelevant
    (drift columns 0). Joint effects move the TCP by ``dp/dq_i * factor(q_work)``.
    """
    q = np.asarray(q_work, dtype=float)[None, :]
    effects = list(effects)
    _, factors = joint_deltas(model, q, effects)
    frames = model.frames(q)
    _, J = point_jacobian(frames, model.p_FQ + np.asarray(tool_offset, dtype=float))
    cols = []
    for e, f in zip(effects, factors, strict=True):
        if f is None:
            cols.append(np.zeros((3, e.n_params)))
        else:
            cols.append(J[0, :, 4 * (e.joint - 1)][:, None] * f[0][None, :])
    return np.concatenate(cols, axis=1) if cols else np.zeros((3, 0))


def effect_tcp_shift(model: TrackerModel, q_work, effects, *, tool_offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(3,) TCP displacement in W at ``q_work`` caused by the effects at their values (KPI conditions)."""
    q = np.asarray(q_work, dtype=float)[None, :]
    delta, _ = joint_deltas(model, q, list(effects))
    off = model.p_FQ + np.asarray(tool_offset, dtype=float)
    from kpioed_drake.kinematics import flange_point

    return flange_point(model.frames(q + delta), off)[0] - flange_point(model.frames(q), off)[0]
