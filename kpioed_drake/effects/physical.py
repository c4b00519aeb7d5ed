"""Physical plausibility of an estimated effect: is the value one a real robot and tracker can have?

A named cause whose value lies outside the bounds below is flagged ``plausible: false`` with a
``plausible_reason``: the data then point at *something* with that signature, but not at the
physical effect of that name (a stand-in for column bending, a bumped tracker, a wrong mass, ...).
A bound counts as violated only when it lies more than ``N_STD`` standard deviations from the
estimate (a value the data do not pin down is not called implausible). Bounds (docs/diagnosis.md,
"Plausibility"):

- ``joint_elasticity``: compliance c >= 0 (a negative c moves the joint against gravity); at most
  ``ELASTIC_MAX_DEG`` of deflection at the largest gravity torque of the joint in the data (the
  model files hold no rated torques; the rated torque is larger, so this bound is lenient), and
  c <= ``ELASTIC_MAX_C`` (a torsional stiffness below 1000 N m/rad is softer than any gear train of
  an industrial arm or cobot; harmonic drives of small arms are about 1e4 N m/rad);
- ``gear_cyclic``: amplitude ``sqrt(a^2 + b^2)`` <= ``GEAR_MAX_DEG``;
- ``joint_scale``, ``joint_coupling``: |eps|, |c| <= ``SCALE_MAX_PPM`` (1 %);
- ``thermal_expansion``: k within ``THERMAL_K`` (0-50 ppm/K: steel 11.7, aluminium 23, cast iron
  10; a negative k shrinks the robot when it warms);
- ``tracker_drift``: speed <= ``DRIFT_MAX_MM_PER_MIN`` and total movement over the data
  <= ``DRIFT_MAX_MM`` (a tracker that moved more was bumped or its stand sank: re-reference it);
- ``tracker_scale``: |k| <= ``TRACKER_SCALE_MAX_PPM_PER_K`` (uncompensated air refraction is
  -0.93 ppm/K);
- ``backlash``: |b| <= ``BACKLASH_MAX_DEG``;
- ``column_compliance``, ``base_compliance``, ``lateral_compliance``: c >= 0 (a negative c bends
  against gravity).
"""

from __future__ import annotations

import numpy as np

from kpioed_drake import effects as fx

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


def _beyond(value: float, std: float, lo: float, hi: float) -> bool:
    """Whether ``value`` lies outside [lo, hi] by more than ``N_STD`` standard deviations."""
    return bool(value - N_STD * std > hi or value + N_STD * std < lo)


def plausibility(
    effect: fx.Effect, std: np.ndarray, *, tau: np.ndarray, time_s: np.ndarray | None
) -> tuple[bool, str | None]:
    """Whether an estimated effect's value is physically plausible, and why not.

    Args:
        effect: the effect with its estimated values (internal units, :class:`~kpioed_drake.effects.Effect`).
        std: (n_params,) standard deviations of the values [internal units].
        tau: (n, 6) gravity torques of the data's poses [N m] (payload included).
        time_s: (n,) time of each pose [s] or None.

    Returns:
        ``(plausible, reason)``; ``reason`` is None when plausible.
    """
    v, s = effect.value_array(), np.asarray(std, dtype=float)
    fam, name = effect.family, effect.name
    if fam == "joint_elasticity":
        c, sc = float(v[0]), float(s[0])
        if _beyond(c, sc, 0.0, np.inf):
            return False, (
                f"{name}: negative compliance {c:.3g} +- {sc:.2g} rad/(N m): the joint would move against "
                "gravity; the signature is something else that follows the gravity torque (wrong masses, a "
                "column or base that bends, a payload not in the data)"
            )
        t_max = float(np.max(np.abs(tau[:, effect.joint - 1])))
        if _beyond(c * t_max, sc * t_max, -np.inf, np.deg2rad(ELASTIC_MAX_DEG)) or _beyond(
            c, sc, -np.inf, ELASTIC_MAX_C
        ):
            return False, (
                f"{name}: compliance {c:.3g} rad/(N m) means {np.rad2deg(c * t_max):.3g} deg at the largest "
                f"gravity torque in the data ({t_max:.3g} N m) (bounds: {ELASTIC_MAX_DEG:g} deg, "
                f"{ELASTIC_MAX_C:g} rad/(N m)): softer than any gear train"
            )
    elif fam == "gear_cyclic":
        amp, sa = np.rad2deg(np.hypot(*v)), np.rad2deg(float(np.max(s)))
        if _beyond(amp, sa, 0.0, GEAR_MAX_DEG):
            return False, f"{name}: amplitude {amp:.3g} deg, above {GEAR_MAX_DEG:g} deg (a failing gear)"
    elif fam in ("joint_scale", "joint_coupling"):
        ppm, sp = 1e6 * float(v[0]), 1e6 * float(s[0])
        if _beyond(abs(ppm), sp, 0.0, SCALE_MAX_PPM):
            return False, f"{name}: {ppm:.4g} ppm, above {SCALE_MAX_PPM:g} ppm (1 %)"
    elif fam == "thermal_expansion":
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
    elif fam == "backlash":
        b, sb = np.rad2deg(float(v[0])), np.rad2deg(float(s[0]))
        if _beyond(abs(b), sb, 0.0, BACKLASH_MAX_DEG):
            return False, f"{name}: {b:.3g} deg above {BACKLASH_MAX_DEG:g} deg"
    elif fam in fx.COMPLIANCE_FAMILIES and _beyond(float(v[0]), float(s[0]), 0.0, np.inf):
        return False, (
            f"{name}: negative compliance {v[0]:.3g} +- {s[0]:.2g} {fx.UNITS[fam]}: the column or base would "
            "lean against its load; the signature is something else that follows the gravity moment"
        )
    return True, None
