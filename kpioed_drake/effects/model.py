"""Non-geometric effects: the :class:`Effect` type, its text syntax and SPEC's realistic sizes
(the families, conventions and measurement model: :mod:`kpioed_drake.effects`)."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Sequence

import numpy as np

from kpioed_drake.effects import compliance as cp
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.gravity import elastic_lever
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.effects.gravity_basis import resolve_basis
from kpioed_drake.errors import InputError
from kpioed_drake.tracker.data import per_pose
from kpioed_drake.tracker.measurement import TrackerModel

FAMILIES = ("joint_elasticity", "gear_cyclic", "thermal_expansion", "tracker_drift")
"""Effect names as in SPEC (and ``none`` for a model that explains the data): diagnosis's candidates."""
EXTRA_FAMILIES = ("joint_scale", "joint_coupling", "tracker_scale", "backlash", BASIS_FAMILY, lb.FAMILY)
"""Further families for simulation and ``--extend``; the first four are diagnosis candidates too, the
gravity bases enter the diagnosis through :mod:`kpioed_drake.diagnosis.elastic_basis`."""
BASIS_FAMILIES = (BASIS_FAMILY, lb.FAMILY)
"""The mass-free bases: a robot- and data-dependent parameter count (``Effect.n_basis``)."""
ROTATION_FAMILIES = cp.FAMILIES + (lb.FAMILY,)
"""Families that turn what they carry rigidly (:class:`~.compliance.Rotation`), not a joint angle."""
COMPLIANCE_FAMILIES = cp.FAMILIES
"""A column, the base or a joint's bearing that yields under the robot's weight (:mod:`.compliance`):
simulation, ``--extend``, and diagnosis candidates for robots on a lift (or with ``compliant_base:
true``); ``lateral_compliance`` only where a diagnosis is given it as a candidate."""
ALL_FAMILIES = FAMILIES + EXTRA_FAMILIES + COMPLIANCE_FAMILIES
JOINT_FAMILIES = (
    "joint_elasticity",
    "gear_cyclic",
    "joint_scale",
    "joint_coupling",
    "backlash",
    BASIS_FAMILY,
)
"""Families that act as a joint-angle error ``delta_i(q)`` (no per-pose temperature or time needed)."""

N_PARAMS = {
    "joint_elasticity": 1,
    "gear_cyclic": 2,
    "thermal_expansion": 1,
    "tracker_drift": 3,
    "joint_scale": 1,
    "joint_coupling": 1,
    "tracker_scale": 1,
    "backlash": 1,
    cp.COLUMN: 1,
    cp.BASE: 1,
    cp.LATERAL: 1,
    BASIS_FAMILY: None,  # robot-dependent: Effect.n_basis (gravity_basis.resolve_basis)
    lb.FAMILY: None,  # robot-dependent: Effect.n_basis (lateral_basis.resolve)
}
UNITS = {
    "joint_elasticity": "rad/(N m)",
    "gear_cyclic": "deg",
    "thermal_expansion": "1/K",
    "tracker_drift": "mm/min",
    "joint_scale": "ppm",
    "joint_coupling": "ppm",
    "tracker_scale": "ppm/K",
    "backlash": "deg",
    BASIS_FAMILY: "rad",
    lb.FAMILY: "rad",
    **cp.UNITS,
}
"""Units of the *displayed* values (text syntax, reports); inside the code see :class:`Effect`."""

T_REF_C = 20.0
"""Reference temperature [C]: the geometric parameters describe the robot at this temperature."""
STEEL_K = 11.7e-6
"""Linear expansion coefficient of steel [1/K] (SPEC)."""
ELASTIC_TOOL_MM = (0.1, 1.0)
GEAR_DEG = (0.003, 0.02)
DRIFT_MM_PER_MIN = (0.005, 0.05)
SCALE_PPM = (100.0, 1000.0)
"""Range of a drawn gear-ratio error (joint_scale) or coupling (joint_coupling) [ppm], random sign."""
AIR_PPM_PER_K = -0.93
"""Tracker scale per kelvin of uncompensated air refraction [ppm/K] (dn/dT of air at 20 C, 1 atm)."""
BACKLASH_DEG = (0.003, 0.02)
"""Range of a drawn backlash [deg] (positive: the joint settles where gravity pushes it)."""
_DISPLAY = {"joint_elasticity": 1.0, "gear_cyclic": np.pi / 180.0, "thermal_expansion": 1.0}
_DISPLAY["tracker_drift"] = 1.0 / 60.0  # mm/min -> mm/s
_DISPLAY.update(joint_scale=1e-6, joint_coupling=1e-6, tracker_scale=1e-6, backlash=np.pi / 180.0)
_DISPLAY[BASIS_FAMILY] = _DISPLAY[lb.FAMILY] = 1.0
_DISPLAY.update({cp.COLUMN: 1.0, cp.BASE: 1.0, cp.LATERAL: 1.0})
COMPLIANCE_TOOL_MM = (0.1, 1.0)
"""Largest reflector displacement [mm] over the joint box of a drawn column or base compliance."""
_DRAW = {
    "joint_scale": lambda rng: rng.uniform(*SCALE_PPM) * rng.choice([-1.0, 1.0]) * 1e-6,
    "joint_coupling": lambda rng: rng.uniform(*SCALE_PPM) * rng.choice([-1.0, 1.0]) * 1e-6,
    "tracker_scale": lambda rng: AIR_PPM_PER_K * 1e-6,
    "backlash": lambda rng: np.deg2rad(rng.uniform(*BACKLASH_DEG)),
}
"""Realistic value of the further families, internal units (tracker_scale: air, not random)."""


@dataclasses.dataclass(frozen=True)
class Effect:
    """One non-geometric effect.

    Attributes:
        family: one of :data:`ALL_FAMILIES`.
        joint: 1-based joint (elasticity, gear, scale, coupling: the joint that errs, backlash) or None.
        harmonic: n of ``gear_cyclic`` or None.
        values: the parameters in internal units, or None if unknown (to be estimated):
            elasticity ``(c,)`` [rad/(N m)]; gear ``(a, b)`` [rad]; thermal ``(k,)`` [1/K];
            drift ``(vx, vy, vz)`` [mm/s] in W; joint scale ``(eps,)`` [1]; coupling ``(c,)`` [1];
            tracker scale ``(k,)`` [1/K]; backlash ``(b,)`` [rad].
        tool_mm: for an elasticity drawn by size: the largest tool displacement [mm] over the joint
            box; :func:`resolve` turns it into c for a robot.
        coupled: 1-based joint j whose angle drives ``joint_coupling:i:j``, else None.
        n_basis: parameter count of ``joint_elasticity_basis`` (robot- and data-dependent, set by
            :func:`resolve` / :func:`~kpioed_drake.effects.gravity_basis.resolve_basis`), else None.
    """

    family: str
    joint: int | None = None
    harmonic: int | None = None
    values: tuple[float, ...] | None = None
    tool_mm: float | None = None
    coupled: int | None = None
    n_basis: int | None = None

    @property
    def n_params(self) -> int:
        if self.family in BASIS_FAMILIES:
            if self.n_basis is None:
                raise InputError(f"effect {self.name}: its size depends on the robot; resolve it first")
            return self.n_basis
        return N_PARAMS[self.family]

    @property
    def key(self) -> tuple:
        """(family, joint, harmonic or coupled joint): what a diagnosis has to name."""
        return (self.family, self.joint, self.harmonic if self.coupled is None else self.coupled)

    @property
    def name(self) -> str:
        """Text form without values, e.g. ``gear_cyclic:4:2``."""
        parts = [self.family]
        if self.joint is not None:
            parts.append(str(self.joint))
        if self.harmonic is not None:
            parts.append(str(self.harmonic))
        if self.coupled is not None:
            parts.append(str(self.coupled))
        return ":".join(parts)

    @property
    def param_names(self) -> list[str]:
        if self.family in BASIS_FAMILIES:
            return [f"{self.name}.t{k}" for k in range(self.n_params)]
        sub = {
            "joint_elasticity": ["c"],
            "gear_cyclic": ["a", "b"],
            "thermal_expansion": ["k"],
            "tracker_drift": ["vx", "vy", "vz"],
            "joint_scale": ["eps"],
            "joint_coupling": ["c"],
            "tracker_scale": ["k"],
            "backlash": ["b"],
            cp.COLUMN: ["c"],
            cp.BASE: ["c"],
            cp.LATERAL: ["c"],
        }[self.family]
        return [f"{self.name}.{s}" for s in sub]

    def value_array(self) -> np.ndarray:
        """(n_params,) internal values; zeros when unknown."""
        if self.values is None:
            return np.zeros(self.n_params)
        return np.asarray(self.values, dtype=float)

    def with_values(self, values: np.ndarray | Sequence[float]) -> Effect:
        """This effect with ``values`` (internal units)."""
        return dataclasses.replace(self, values=tuple(float(v) for v in np.ravel(values)))

    def display_values(self, values: np.ndarray | None = None) -> list[float]:
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
        if self.coupled is not None:
            out["coupled_joint"] = self.coupled
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
    "tracker_drift[=vx,vy,vz mm/min], joint_scale:JOINT[=eps ppm], joint_coupling:JOINT:JOINT[=c ppm], "
    "tracker_scale[=k ppm/K], backlash:JOINT[=b deg], column_compliance:JOINT[=c 1/(N m^2)], "
    "base_compliance[=c rad/(N m)], lateral_compliance:JOINT[=c rad/(N m)], "
    "joint_elasticity_basis:JOINT[=t1,... rad], lateral_compliance_basis:JOINT[=t1,... rad]"
)


def _numbers(text: str, count: int, spec: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != count or not all(np.isfinite(vals)):
        raise InputError(f"effect {spec!r}: expected {count} comma-separated number(s) after '='")
    return vals


def _joint(token: str, spec: str, n_joints: int = 6) -> int:
    if not (re.fullmatch(r"[1-9][0-9]*", token.strip()) and int(token) <= n_joints):
        raise InputError(f"effect {spec!r}: joint must be 1..{n_joints} (1-based), got {token!r}")
    return int(token)


def parse_effect(
    text: str,
    rng: np.random.Generator | None = None,
    *,
    model: TrackerModel | None = None,
    n_joints: int | None = None,
) -> Effect:
    """Parse an effect from its text form.

    Syntax: ``joint_elasticity:2`` / ``joint_elasticity:2=2e-6`` (c in rad per N m);
    ``gear_cyclic:4:2`` / ``gear_cyclic:4:2=0.01,-0.005`` (joint 4, harmonic 2, a and b in deg);
    ``thermal_expansion`` / ``thermal_expansion=11.7e-6`` (k in 1/K, default steel);
    ``tracker_drift`` / ``tracker_drift=0.01,0,-0.02`` (velocity in W, mm/min);
    ``joint_scale:2=300`` (eps in ppm); ``joint_coupling:5:4=-200`` (joint 5 errs by c q_4, c in ppm);
    ``tracker_scale=-0.93`` (k in ppm/K); ``backlash:3=0.01`` (b in deg).

    Without a value: with ``rng`` a value of SPEC's realistic size is drawn (an elasticity as a tool
    displacement ``tool_mm``, turned into c by :func:`resolve` once the robot is known; pass
    ``model`` to resolve at once); without ``rng`` the values stay unknown (``values=None``: an
    extension to estimate). ``n_joints``: the robot's joint count when no ``model`` is given
    (default six, a column seven). ``thermal_expansion`` drawn with ``rng`` is steel
    (``STEEL_K``), not random;
    ``tracker_scale`` is air (``AIR_PPM_PER_K``); the other further families see ``_DRAW``.

    Raises:
        InputError: unknown family, bad joint or harmonic, wrong number of values.
    """
    nj = model.robot.n_joints if model is not None else n_joints or 6  # joints of the robot
    spec = str(text).strip()
    lhs, eq, rhs = spec.partition("=")
    parts = [p.strip() for p in lhs.split(":")]
    family = parts[0]
    if family not in ALL_FAMILIES:
        raise InputError(f"unknown effect {family!r} in {spec!r}; expected one of: {_SYNTAX}")
    given = rhs.strip() if eq else None
    if eq and not given:
        raise InputError(f"effect {spec!r}: nothing after '='")
    if family == "joint_elasticity":
        eff = _parse_elasticity(parts, given, rng, spec, nj)
        return resolve(eff, model) if model is not None and eff.tool_mm is not None else eff
    if family == "gear_cyclic":
        return _parse_gear(parts, given, rng, spec, nj)
    if family in COMPLIANCE_FAMILIES:
        eff = _parse_compliance(family, parts, given, rng, spec, model, n_joints)
        return resolve(eff, model) if model is not None else eff
    if family in EXTRA_FAMILIES:
        eff = _parse_extra(family, parts, given, rng, spec, nj)
        return resolve(eff, model) if model is not None and family in BASIS_FAMILIES else eff
    if len(parts) != 1:
        raise InputError(f"effect {spec!r}: {family} takes no joint")
    return _parse_tracker_thermal(family, given, rng, spec)


def _joint_part(parts: list[str], n_parts: int, usage: str, spec: str, nj: int) -> int:
    """The joint of an effect text of ``n_parts`` colon-separated parts (``usage``: its syntax)."""
    if len(parts) != n_parts:
        raise InputError(f"effect {spec!r}: expected {usage}")
    return _joint(parts[1], spec, nj)


def _parse_elasticity(
    parts: list[str], given: str | None, rng: np.random.Generator | None, spec: str, nj: int
) -> Effect:
    """``joint_elasticity:JOINT[=c]``: with a value, unknown, or drawn as a tool displacement."""
    family = "joint_elasticity"
    joint = _joint_part(parts, 2, "joint_elasticity:JOINT[=c], e.g. joint_elasticity:2", spec, nj)
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
    return Effect(family, joint, tool_mm=float(rng.uniform(*ELASTIC_TOOL_MM)))


def _parse_gear(
    parts: list[str], given: str | None, rng: np.random.Generator | None, spec: str, nj: int
) -> Effect:
    """``gear_cyclic:JOINT:N[=a,b]`` (a, b in deg): with values, unknown, or drawn."""
    family = "gear_cyclic"
    joint = _joint_part(parts, 3, "gear_cyclic:JOINT:N[=a,b], e.g. gear_cyclic:4:2", spec, nj)
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


def _parse_tracker_thermal(
    family: str, given: str | None, rng: np.random.Generator | None, spec: str
) -> Effect:
    """``thermal_expansion[=k]`` (drawn: steel) or ``tracker_drift[=vx,vy,vz]`` (mm/min)."""
    if family == "thermal_expansion":
        if given is None and rng is None:
            return Effect(family)
        k = _numbers(given, 1, spec)[0] if given is not None else STEEL_K
        return Effect(family, values=(float(k),))
    if given is not None:  # tracker_drift
        v = np.asarray(_numbers(given, 3, spec)) / 60.0
        return Effect(family, values=tuple(float(x) for x in v))
    if rng is None:
        return Effect(family)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    v = d * rng.uniform(*DRIFT_MM_PER_MIN) / 60.0
    return Effect(family, values=tuple(float(x) for x in v))


def _parse_extra(family: str, parts: list[str], given, rng, spec: str, nj: int = 6) -> Effect:
    """The further families (:data:`EXTRA_FAMILIES`): ``parts`` = the ':'-separated left side."""
    if family in BASIS_FAMILIES:
        if len(parts) != 2:
            raise InputError(f"effect {spec!r}: expected {family}:JOINT[=t1,t2,... rad]")
        joint = _joint(parts[1], spec, nj)
        if given is None and rng is not None:
            physical = "joint_elasticity" if family == BASIS_FAMILY else cp.LATERAL
            raise InputError(f"effect {spec!r}: no size to draw; simulate {physical}:{joint} instead")
        vals = None if given is None else _numbers(given, len(given.split(",")), spec)
        return Effect(family, joint, values=vals, n_basis=None if vals is None else len(vals))
    form = {
        "joint_scale": "joint_scale:JOINT[=eps ppm]",
        "joint_coupling": "joint_coupling:JOINT:JOINT[=c ppm]",
        "tracker_scale": "tracker_scale[=k ppm/K]",
        "backlash": "backlash:JOINT[=b deg]",
    }[family]
    n_idx = form.count(":JOINT")
    if len(parts) != 1 + n_idx:
        raise InputError(f"effect {spec!r}: expected {form}")
    idx = [_joint(p, spec, nj) for p in parts[1:]]
    if family == "backlash" and idx[0] == 1:
        raise InputError(
            f"effect {spec!r}: joint 1 turns about the vertical axis; gravity exerts no torque on it, "
            "so the side its backlash settles on is undefined (use joints 2..6)"
        )
    if family == "joint_coupling" and idx[0] == idx[1]:
        raise InputError(f"effect {spec!r}: a joint coupled to itself is joint_scale:{idx[0]}")
    kw = {"joint": idx[0] if idx else None, "coupled": idx[1] if n_idx == 2 else None}
    if given is not None:
        (v,) = _numbers(given, 1, spec)
        return Effect(family, values=(float(v * _DISPLAY[family]),), **kw)
    if rng is None:
        return Effect(family, **kw)
    return Effect(family, values=(float(_DRAW[family](rng)),), **kw)


def _parse_compliance(family: str, parts: list[str], given, rng, spec: str, model, n_joints=None) -> Effect:
    """``column_compliance:JOINT[=c]`` (c = 1/EI [1/(N m^2)]), ``base_compliance[=c]`` or
    ``lateral_compliance:JOINT[=c]`` (c [rad/(N m)]); with a model the joint is checked (a column:
    prismatic, only prismatic joints below it; a lateral compliance: revolute)."""
    nj = model.robot.n_joints if model is not None else n_joints or 7  # a lift: one joint more than six
    if family in (cp.COLUMN, cp.LATERAL):
        if len(parts) != 2:
            unit, ex = ("1/(N m^2)", 1) if family == cp.COLUMN else ("rad/(N m)", 2)
            raise InputError(f"effect {spec!r}: expected {family}:JOINT[=c {unit}], e.g. {family}:{ex}")
        joint = _joint(parts[1], spec, nj)
        if model is not None:
            (cp.check_column if family == cp.COLUMN else cp.check_lateral)(model.robot, joint, spec)
    elif len(parts) != 1:
        raise InputError(f"effect {spec!r}: {family} takes no joint (expected {family}[=c rad/(N m)])")
    else:
        joint = None
    if given is not None:
        (c,) = _numbers(given, 1, spec)
        return Effect(family, joint, values=(float(c),))
    if rng is None:
        return Effect(family, joint)
    return Effect(family, joint, tool_mm=float(rng.uniform(*COMPLIANCE_TOOL_MM)))


def _per_pose(x, n: int, what: str, effect: str) -> np.ndarray:
    if x is None:
        raise InputError(f"effect {effect} needs {what} for every pose (column {what!r} in the data)")
    return per_pose(x, n, f"effect {effect}: {what}")


def scale_and_drift(
    effects: Sequence[Effect],
    n: int,
    temperature_C: float | np.ndarray | None,
    time_s: float | np.ndarray | None,
) -> tuple:
    """Of the thermal and tracker effects at n poses: the length scale s (n,), the tracker shift
    ``v t`` (n, 3) [mm], ``T - T_REF_C`` and t (each (n,) or None), and the tracker's distance scale
    s_T (n,).

    Raises:
        InputError: an effect that needs ``temperature_C`` or ``time_s`` without them.
    """
    s = np.ones(n)
    s_T = np.ones(n)
    temp = None
    drift = np.zeros((n, 3))
    tvec = None
    for e in effects:
        if e.family in ("thermal_expansion", "tracker_scale"):
            temp = _per_pose(temperature_C, n, "temperature_C", e.name) - T_REF_C
            if e.family == "thermal_expansion":
                s = s + e.value_array()[0] * temp
            else:
                s_T = s_T + e.value_array()[0] * temp
        elif e.family == "tracker_drift":
            tvec = _per_pose(time_s, n, "time_s", e.name)
            drift = drift + tvec[:, None] * e.value_array()[None, :]
    return s, drift, temp, tvec, s_T


def parse_effects(
    texts: Iterable[str],
    rng: np.random.Generator | None = None,
    *,
    model: TrackerModel | None = None,
    n_joints: int | None = None,
) -> list[Effect]:
    """Parse several effects (a list, or one comma-free text per effect); duplicates are an error."""
    effects = [parse_effect(t, rng, model=model, n_joints=n_joints) for t in texts]
    keys = [e.key for e in effects]
    for k in keys:
        if keys.count(k) > 1:
            raise InputError(f"effect {effects[keys.index(k)].name!r} given more than once")
    return effects


def resolve(effect: Effect, model: TrackerModel) -> Effect:
    """An effect with concrete values: an elasticity or a compliance drawn by ``tool_mm`` gets its c
    for this robot (a column's joint is checked); a ``joint_elasticity_basis`` without ``n_basis``
    gets its parameter count (no payload column)."""
    if effect.family == BASIS_FAMILY:
        return resolve_basis(effect, model, n_given=effect.n_basis)
    if effect.family == lb.FAMILY:
        return lb.resolve(effect, model.robot, n_given=effect.n_basis)
    if effect.family == cp.COLUMN:
        cp.check_column(model.robot, effect.joint)
    if effect.family == cp.LATERAL:
        cp.check_lateral(model.robot, effect.joint)
    if effect.values is not None or effect.tool_mm is None:
        return effect
    if effect.family in COMPLIANCE_FAMILIES:
        size = cp.lever(model.robot, effect.family, effect.joint, model.p_FQ)
        if size <= 0:
            raise InputError(f"effect {effect.name}: gravity does not bend it on this robot (zero moment)")
        return dataclasses.replace(effect, values=(effect.tool_mm / size,))
    if effect.family != "joint_elasticity":
        return effect
    lever = elastic_lever(model, effect.joint)
    if lever <= 0:
        raise InputError(
            f"effect {effect.name}: gravity exerts no torque on joint {effect.joint} of this robot"
        )
    return dataclasses.replace(effect, values=(effect.tool_mm / lever,))
