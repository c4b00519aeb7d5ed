"""Physical plausibility of an estimated effect: is the value one a real robot and tracker can have?

A named cause whose value lies outside the bounds below is flagged ``plausible: false`` with a
``plausible_reason``: the data then point at *something* with that signature, but not at the
physical effect of that name (a stand-in for column bending, a bumped tracker, a wrong mass, ...).
A bound counts as violated only when it lies more than ``N_STD`` standard deviations from the
estimate (a value the data do not pin down is not called implausible). The bounds of a joint's
effects follow its drive (the robot file's ``drive``/``drives``,
:mod:`kpioed_drake.robot.drivetrain`; :data:`DRIVE_BOUNDS`, gear when the file names none).
Bounds (docs/diagnosis.md, "Plausibility"):

- ``joint_elasticity``: compliance c >= 0 (a negative c moves the joint against gravity); at most
  the drive's ``elastic_deg`` of deflection at the largest gravity torque of the joint in the data
  (the model files hold no rated torques; the rated torque is larger, so this bound is lenient),
  and c <= the drive's ``elastic_c`` (a gear train's torsional stiffness is above 1000 N m/rad;
  harmonic drives of small arms are about 1e4 N m/rad, cables and belts softer);
- ``gear_cyclic``: amplitude ``sqrt(a^2 + b^2)`` <= the drive's ``gear_deg``;
- ``joint_scale``, ``joint_coupling``: |eps|, |c| <= the drive's ``scale_ppm`` (a gear's ratio is
  exact: 1 %; a cable's or belt's pulley ratio a few %); the coupling of a joint-map follower to
  its leader, and a follower's scale, <= ``FOLLOWER_SHARE`` of the map's factor (the mechanism
  behind a coupled joint has that ratio only nominally);
- ``thermal_expansion``: k within ``THERMAL_K`` (0-50 ppm/K: steel 11.7, aluminium 23, cast iron
  10; a negative k shrinks the robot when it warms);
- ``tracker_drift``: speed <= ``DRIFT_MAX_MM_PER_MIN`` and total movement over the data
  <= ``DRIFT_MAX_MM`` (a tracker that moved more was bumped or its stand sank: re-reference it);
- ``tracker_scale``: |k| <= ``TRACKER_SCALE_MAX_PPM_PER_K`` (uncompensated air refraction is
  -0.93 ppm/K);
- ``backlash``: |b| <= the drive's ``backlash_deg``;
- ``column_compliance``, ``base_compliance``, ``lateral_compliance``: c >= 0 (a negative c bends
  against gravity);
- the mass-free bases ``joint_elasticity_basis``, ``lateral_compliance_basis`` (their values are
  moments times a compliance, with no bound of their own): the rotation they cause
  (:class:`BasisSize`: the largest displacement at the reflector that no geometric parameter takes,
  over its distance from the joint, a lower bound of the angle) at most the drive's ``elastic_deg``
  (a twist about the axis) or ``lateral_deg`` (a bearing's tilt).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.robot.drivetrain import follower_factor, joint_drive
from kpioed_drake.robot.models import Robot

N_STD = 2.0
"""A bound is violated when the estimate is beyond it by more than this many standard deviations."""
ELASTIC_MAX_DEG = 1.0
"""Largest plausible elastic deflection of a joint at its largest gravity torque [deg]."""
ELASTIC_MAX_C = 1e-3
"""Largest plausible joint compliance [rad/(N m)] (stiffness 1000 N m/rad)."""
GEAR_MAX_DEG = 0.1
SCALE_MAX_PPM = 1e4
THERMAL_K = (0.0, 50e-6)
"""Plausible range of a linear expansion coefficient [1/K]."""
DRIFT_MAX_MM_PER_MIN = 0.1
DRIFT_MAX_MM = 5.0
TRACKER_SCALE_MAX_PPM_PER_K = 5.0
BACKLASH_MAX_DEG = 0.1
LATERAL_MAX_DEG = 0.5
"""Largest plausible tilt of a gear-driven joint's bearing under the load it carries [deg]."""
FOLLOWER_SHARE = 0.05
"""Largest plausible deviation of a joint-map follower's ratio from the map's factor (its share)."""


@dataclasses.dataclass(frozen=True)
class DriveBounds:
    """The plausibility bounds of one drive type's joint effects."""

    gear_deg: float
    """Cyclic error amplitude [deg]."""
    scale_ppm: float
    """Ratio (scale) error and a drive-train coupling [ppm]."""
    backlash_deg: float
    """Backlash (half the play) [deg]."""
    elastic_deg: float
    """Elastic twist at the largest gravity torque of the data [deg]."""
    elastic_c: float
    """Torsional compliance [rad/(N m)]."""
    lateral_deg: float
    """Tilt of the joint's bearing [deg]."""


DRIVE_BOUNDS = {
    "gear": DriveBounds(GEAR_MAX_DEG, SCALE_MAX_PPM, BACKLASH_MAX_DEG, ELASTIC_MAX_DEG, ELASTIC_MAX_C, 0.5),
    "harmonic": DriveBounds(0.25, SCALE_MAX_PPM, BACKLASH_MAX_DEG, ELASTIC_MAX_DEG, 3e-3, 0.5),
    "belt": DriveBounds(0.25, 3e4, 0.2, 2.0, 1e-2, 1.0),
    "cable": DriveBounds(0.25, 5e4, BACKLASH_MAX_DEG, 3.0, 1e-2, 1.0),
}
"""Bounds per drive type (:data:`kpioed_drake.robot.drivetrain.DRIVES`): a strain-wave gear has
larger cyclic (flexspline) errors and is softer than a gear train; a belt's or cable's ratio is a
pulley ratio known to a few per cent (3 %, 5 %), cables and belts are softer still, and a belt
drive's teeth have more play."""


@dataclasses.dataclass(frozen=True)
class BasisSize:
    """How far a mass-free basis turns what the joint carries, over the data's poses.

    Attributes:
        angle: the largest displacement at the reflector that the geometric parameters cannot take,
            over its distance from the joint's axis point: a lower bound of the rotation [rad].
        relative_std: the standard deviation of the effect's size along its fitted values, relative
            to the size (``sqrt(v^T C v) / |v|^2``).
        max_mm: the largest displacement at the reflector [mm]; lever_mm: the reflector's distance
            from the joint at that pose [mm]; reach_mm: the robot's reach [mm].
    """

    angle: float
    relative_std: float
    max_mm: float
    lever_mm: float
    reach_mm: float


def bounds_for(robot: Robot | None, joint: int | None) -> tuple[DriveBounds, str]:
    """The bounds of a joint's effects and the joint's drive type (gear without a robot)."""
    drive = "gear" if robot is None or joint is None else joint_drive(robot, joint)
    return DRIVE_BOUNDS[drive], drive


def _beyond(value: float, std: float, lo: float, hi: float) -> bool:
    """Whether ``value`` lies outside [lo, hi] by more than ``N_STD`` standard deviations."""
    return bool(value - N_STD * std > hi or value + N_STD * std < lo)


def plausibility(
    effect: fx.Effect,
    std: np.ndarray,
    *,
    tau: np.ndarray,
    time_s: np.ndarray | None,
    robot: Robot | None = None,
    size: BasisSize | None = None,
) -> tuple[bool, str | None]:
    """Whether an estimated effect's value is physically plausible, and why not.

    Args:
        effect: the effect with its estimated values (internal units, :class:`~kpioed_drake.effects.Effect`).
        std: (n_params,) standard deviations of the values [internal units].
        tau: (n, 6) gravity torques of the data's poses [N m] (payload included).
        time_s: (n,) time of each pose [s] or None.
        robot: the robot (its joints' drives and joint map set the bounds); None: gear drives.
        size: a mass-free basis's rotation over the data (:class:`BasisSize`); None: not checked.

    Returns:
        ``(plausible, reason)``; ``reason`` is None when plausible.
    """
    if effect.family in fx.JOINT_FAMILIES or effect.family in (gb.FAMILY, lb.FAMILY):
        return _joint_effect(effect, np.asarray(std, dtype=float), tau, robot, size)
    v, s = effect.value_array(), np.asarray(std, dtype=float)
    fam, name = effect.family, effect.name
    if fam == "thermal_expansion":
        k, sk = float(v[0]), float(s[0])
        if _beyond(k, sk, *THERMAL_K):
            return False, (
                f"{name}: k = {1e6 * k:.3g} +- {1e6 * sk:.2g} ppm/K outside {1e6 * THERMAL_K[0]:g}-"
                f"{1e6 * THERMAL_K[1]:g} ppm/K (steel 11.7, aluminium 23)"
            )
    elif fam == "tracker_drift":
        speed, ss = 60.0 * float(np.linalg.norm(v)), 60.0 * float(np.max(s))
        minutes = np.ptp(time_s) / 60.0 if time_s is not None else 0.0
        total = speed * minutes
        if _beyond(speed, ss, 0.0, DRIFT_MAX_MM_PER_MIN) or _beyond(total, ss * minutes, 0.0, DRIFT_MAX_MM):
            return False, (
                f"{name}: {speed:.3g} mm/min, {total:.3g} mm over the data (bounds {DRIFT_MAX_MM_PER_MIN:g} "
                f"mm/min, {DRIFT_MAX_MM:g} mm): a tracker that moves this much was bumped; re-reference it"
            )
    elif fam == "tracker_scale":
        k, sk = 1e6 * float(v[0]), 1e6 * float(s[0])
        if _beyond(abs(k), sk, 0.0, TRACKER_SCALE_MAX_PPM_PER_K):
            return False, (
                f"{name}: {k:.3g} ppm/K, above {TRACKER_SCALE_MAX_PPM_PER_K:g} ppm/K (air: -0.93 ppm/K)"
            )
    elif fam in fx.COMPLIANCE_FAMILIES and _beyond(float(v[0]), float(s[0]), 0.0, np.inf):
        return False, (
            f"{name}: negative compliance {v[0]:.3g} +- {s[0]:.2g} {fx.UNITS[fam]}: the column or base would "
            "lean against its load; the signature is something else that follows the gravity moment"
        )
    return True, None


def _joint_effect(effect, s: np.ndarray, tau, robot, size: BasisSize | None) -> tuple[bool, str | None]:
    """:func:`plausibility` of a joint's effect, with the bounds of its drive (:func:`bounds_for`)."""
    v, fam, name = effect.value_array(), effect.family, effect.name
    b, drive = bounds_for(robot, effect.joint)
    kind = f"a {drive} drive" if robot is not None and drive != "gear" else "a gear"
    if fam == "joint_elasticity":
        c, sc = float(v[0]), float(s[0])
        if _beyond(c, sc, 0.0, np.inf):
            return False, (
                f"{name}: negative compliance {c:.3g} +- {sc:.2g} rad/(N m): the joint would move against "
                "gravity; the signature is something else that follows the gravity torque (wrong masses, a "
                "column or base that bends, a payload not in the data)"
            )
        t_max = float(np.max(np.abs(tau[:, effect.joint - 1])))
        if _beyond(c * t_max, sc * t_max, -np.inf, np.deg2rad(b.elastic_deg)) or _beyond(
            c, sc, -np.inf, b.elastic_c
        ):
            return False, (
                f"{name}: compliance {c:.3g} rad/(N m) means {np.rad2deg(c * t_max):.3g} deg at the largest "
                f"gravity torque in the data ({t_max:.3g} N m) (bounds for {kind}: {b.elastic_deg:g} deg, "
                f"{b.elastic_c:g} rad/(N m)): softer than any such drive"
            )
    elif fam == "gear_cyclic":
        amp, sa = np.rad2deg(np.hypot(*v)), np.rad2deg(float(np.max(s)))
        if _beyond(amp, sa, 0.0, b.gear_deg):
            return False, f"{name}: amplitude {amp:.3g} deg, above {b.gear_deg:g} deg (a failing {drive})"
    elif fam in ("joint_scale", "joint_coupling"):
        ppm, sp = 1e6 * float(v[0]), 1e6 * float(s[0])
        factor = None if robot is None else follower_factor(robot, effect.joint, effect.coupled)
        top = b.scale_ppm if factor is None else max(b.scale_ppm, 1e6 * FOLLOWER_SHARE * factor)
        why = f"{kind}'s ratio" if factor is None else f"the joint map's factor {factor:g} of a coupled joint"
        if _beyond(abs(ppm), sp, 0.0, top):
            return False, f"{name}: {ppm:.4g} ppm, above {top:g} ppm ({100 * top / 1e6:g} %, {why})"
    elif fam == "backlash":
        deg, sb = np.rad2deg(float(v[0])), np.rad2deg(float(s[0]))
        if _beyond(abs(deg), sb, 0.0, b.backlash_deg):
            return False, f"{name}: {deg:.3g} deg above {b.backlash_deg:g} deg ({kind})"
    elif fam in (gb.FAMILY, lb.FAMILY) and size is not None:
        top = b.elastic_deg if fam == gb.FAMILY else b.lateral_deg
        what = "twist" if fam == gb.FAMILY else "bearing tilt"
        deg = float(np.rad2deg(size.angle))
        if _beyond(deg, deg * size.relative_std, 0.0, top):
            return False, (
                f"{name}: {size.max_mm:.3g} mm at the reflector {size.lever_mm:.0f} mm from joint "
                f"{effect.joint} (reach {size.reach_mm:.0f} mm): a {what} of {deg:.3g} deg or more, above "
                f"{top:g} deg for {kind}: it stands in for something else with that signature"
            )
    return True, None
