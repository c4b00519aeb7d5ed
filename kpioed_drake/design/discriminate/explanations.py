"""Two competing explanations of a discrepancy and the tests between them.

The text ``"A|B"`` of ``kpioed design --discriminate`` (:func:`parse_pair`: effects of
:mod:`kpioed_drake.effects` with given or assumed sizes), the non-centrality of each test
(:func:`noncentralities`: A true, the likelihood-ratio test of A on top of the geometry and B),
its power (:func:`power`) and, for effects that need per-pose temperature or time, the span of the
condition the data needs (:func:`condition_spread`). The design is :mod:`.discriminate`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.optimize
import scipy.stats

from kpioed_drake.effects import (
    COMPLIANCE_FAMILIES,
    EXTRA_FAMILIES,
    T_REF_C,
    Effect,
    augmented_jacobian,
    parse_effect,
    resolve,
)
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.tracker.measurement import TrackerModel

OPTION = "discriminate"
"""The API parameter the messages name (their ``fields``; the command line shows ``--discriminate``)."""


def discriminate_error(text: str, *fields: str) -> InputError:
    """InputError ``"discriminate: {text}"``, naming ``discriminate`` and ``fields``."""
    return InputError(f"{OPTION}: {text}", fields=(OPTION, *fields))


DEFAULT_ALPHA = 0.01
"""Level of the tests (that of ``kpioed diagnose``)."""
TARGET_POWER = 0.8
"""Power the condition spans of :func:`condition_spread` are sized for."""
DEFAULT_SIZES = {
    "joint_elasticity": 0.1,
    "gear_cyclic": 0.003,
    "joint_scale": 100.0,
    "joint_coupling": 100.0,
    "backlash": 0.003,
    "thermal_expansion": 11.7e-6,
    "tracker_scale": -0.93,
    "tracker_drift": 0.005,
    "column_compliance": 0.1,
    "base_compliance": 0.1,
    "lateral_compliance": 0.1,
}
"""Assumed size of an explanation given without a value: the smallest of SPEC's realistic sizes
(the lower bounds of the sizes the synthetic harness draws), in display units: elasticity and the
column and base compliances as the largest tool displacement [mm] (turned into c for the robot),
gear amplitude ``sqrt(a^2 + b^2)`` [deg], scale and coupling [ppm], backlash [deg], thermal [1/K]
(steel), tracker scale [ppm/K] (air), drift speed [mm/min]."""
CONDITION_FAMILIES = ("thermal_expansion", "tracker_drift", "tracker_scale")
"""Families whose signature needs per-pose temperature or time (not poses alone)."""
_CONDITION = {
    "thermal_expansion": ("temperature_C", "K"),
    "tracker_scale": ("temperature_C", "K"),
    "tracker_drift": ("time_s", "s"),
}


@dataclasses.dataclass(frozen=True)
class Explanation:
    """One of the two explanations and its assumed size.

    Attributes:
        effect: the effect with values (internal units): the given or the assumed size.
        source: ``given`` (the text's values) or ``default`` (:data:`DEFAULT_SIZES`).
        direction_known: the values fix the direction of ``theta`` (given values, or one
            parameter); otherwise only its amplitude is assumed and the worst direction counts.
    """

    effect: Effect
    source: str
    direction_known: bool

    @property
    def theta(self) -> np.ndarray:
        """(k,) assumed parameters [internal units]."""
        return self.effect.value_array()

    def to_dict(self) -> dict:
        out = self.effect.to_dict()
        out["size_source"] = self.source
        out["amplitude"] = float(np.linalg.norm(self.effect.display_values()))
        out["direction"] = (
            "as given" if self.direction_known else "unknown (worst direction of the amplitude)"
        )
        return out


Pair = tuple[Explanation, Explanation]
"""The two competing explanations of ``"A|B"`` (:func:`parse_pair`)."""


def _default(effect: Effect, model: TrackerModel) -> Effect:
    """``effect`` with the assumed size of :data:`DEFAULT_SIZES`."""
    size = DEFAULT_SIZES[effect.family]
    if effect.family == "joint_elasticity" or effect.family in COMPLIANCE_FAMILIES:
        return resolve(dataclasses.replace(effect, tool_mm=size), model)
    if effect.family == "gear_cyclic":
        return effect.with_values(np.deg2rad([size, size]) / np.sqrt(2.0))
    if effect.family == "tracker_drift":
        return effect.with_values(np.array([size, 0.0, 0.0]) / 60.0)
    if effect.family in EXTRA_FAMILIES:
        return parse_effect(f"{effect.name}={size!r}")
    return effect.with_values([size])


def parse_pair(text: str, model: TrackerModel) -> Pair:
    """The two explanations of ``"A|B"`` (texts of :func:`~kpioed_drake.effects.parse_effect`,
    values optional, e.g. ``"joint_scale:2=300|gear_cyclic:2:1"``).

    Raises:
        InputError: naming ``discriminate``: no single '|', an unknown or malformed effect, the
            same effect twice, or an effect this robot cannot show (no gravity torque on the
            joint).
    """
    parts = str(text).split("|")
    if len(parts) != 2 or not all(p.strip() for p in parts):
        raise discriminate_error(
            f"expected two explanations 'A|B', e.g. 'joint_scale:2=300|gear_cyclic:2:1', got {text!r}"
        )
    out = []
    for p in parts:
        try:
            eff = resolve(parse_effect(p.strip()), model)
            if eff.values is None:
                eff = _default(eff, model)
        except InputError as exc:
            raise discriminate_error(str(exc), *exc.fields) from None
        given = "=" in p
        out.append(Explanation(eff, "given" if given else "default", given or eff.n_params == 1))
    if out[0].effect.key == out[1].effect.key:
        raise discriminate_error(f"the two explanations are the same effect ({out[0].effect.name})")
    return out[0], out[1]


def noncentralities(F1: np.ndarray, indices: list[np.ndarray], pair: Pair) -> np.ndarray:
    """(2,) exact non-centralities ``lambda_h`` of the two tests for a weighted Jacobian ``F1``
    (m, k) (geometry, extensions, A, B): the part of h's columns outside the span of all the
    others (a least-squares projection, so also where the geometry is not determined)."""
    out = []
    for h, idx in zip(pair, indices, strict=True):
        others = np.setdiff1d(np.arange(F1.shape[1]), idx)
        X, Z = F1[:, idx], F1[:, others]
        D = np.linalg.norm(Z, axis=0)
        D[D == 0] = 1.0
        coef = np.linalg.lstsq(Z / D, X, rcond=1e-12)[0]
        R = X - (Z / D) @ coef
        S = R.T @ R  # (C_hh)^-1, the Schur complement
        if h.direction_known:
            out.append(float(h.theta @ S @ h.theta))
        else:
            out.append(float(h.theta @ h.theta) * float(np.linalg.eigvalsh(S)[0]))
    return np.array(out)


def power(lam: float, df: int, alpha: float = DEFAULT_ALPHA) -> float:
    """``P(chi2_df(lam) > chi2_{df, 1-alpha})``: power of the level-alpha test of non-centrality lam."""
    crit = scipy.stats.chi2.ppf(1.0 - alpha, df)
    return float(scipy.stats.ncx2.sf(crit, df, max(lam, 1e-12)))


def lambda_for_power(target: float, df: int, alpha: float = DEFAULT_ALPHA) -> float:
    """Non-centrality whose level-alpha test has power ``target``."""
    return float(
        scipy.optimize.brentq(lambda x: power(x, df, alpha) - target, 1e-9, 1e4, xtol=1e-12, rtol=1e-14)
    )


def condition_spread(
    base: Problem, pair: Pair, q: np.ndarray, *, alpha: float = DEFAULT_ALPHA, target: float = TARGET_POWER
) -> list[dict]:
    """What spread of temperature or time the poses ``q`` (n, 6) need to tell the pair apart.

    The condition is taken as an even ramp over the poses (temperature about ``T_REF_C``, time from
    0). An explanation's columns are linear in its own condition, and the span of the other
    explanation's columns does not change with the size of its condition's ramp, so its
    ``lambda`` grows as the square of its condition's span: the span for power ``target`` follows
    from ``lambda`` at a span of 1. A joint effect's ``lambda`` does not depend on the spans.

    Returns:
        per explanation: ``explanation``, and ``condition`` (``temperature_C`` or ``time_s``),
        ``span`` and ``unit`` (K or s) for a condition family, or ``lambda`` and ``power`` for a
        joint effect.
    """
    q = np.atleast_2d(q)
    n = len(q)
    effs = [dataclasses.replace(h.effect, values=None) for h in pair]  # columns at zero, as in a design
    ramp = np.linspace(-0.5, 0.5, n)
    _, H, E = augmented_jacobian(base.model, q, effs, temperature_C=T_REF_C + ramp, time_s=ramp + 0.5)
    G = H[:, :, base.free]
    F1 = np.concatenate([G, E], axis=2).reshape(3 * n, -1) / base.sigma
    k0, k1 = G.shape[2], effs[0].n_params
    lam1 = noncentralities(F1, [k0 + np.arange(k1), k0 + k1 + np.arange(effs[1].n_params)], pair)
    out = []
    for e, x in zip(effs, lam1, strict=True):
        rec = {"explanation": e.name}
        if e.family in _CONDITION:
            need = lambda_for_power(target, e.n_params, alpha)
            column, unit = _CONDITION[e.family]
            rec.update(condition=column, span=float(np.sqrt(need / x)) if x > 0 else float("inf"), unit=unit)
        else:
            rec.update({"lambda": float(x), "power": power(x, e.n_params, alpha)})
        out.append(rec)
    return out


def condition_message(pair: Pair, spans: list[dict], n: int, source: str, alpha: float) -> str:
    """The input error of a pair with a condition family: the spans the data needs."""
    parts = []
    for r in spans:
        if "span" in r:
            parts.append(f"{r['explanation']} true: a {r['condition']} span of {r['span']:.3g} {r['unit']}")
        else:
            parts.append(f"{r['explanation']} true: power {r['power']:.3f} (poses only)")
    cond = ", ".join(h.effect.name for h in pair if h.effect.family in CONDITION_FAMILIES)
    return (
        f"{OPTION}: {cond} cannot be told apart by poses alone (its signature needs per-pose "
        f"temperature or time); over {n} {source} poses with an even ramp of the condition, the data "
        f"needs for power {TARGET_POWER:g} at level {alpha:g}: {'; '.join(parts)}"
    )
