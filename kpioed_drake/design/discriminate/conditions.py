"""Measurement plans for explanations that need temperature or time (or gain from a payload): two
blocks of the same poses.

``thermal_expansion`` and ``tracker_scale`` act through the temperature, ``tracker_drift`` through
the time of each measurement (:mod:`kpioed_drake.effects`): poses alone cannot tell them apart from
each other or from a joint effect. A *plan* fixes the condition of every new measurement too. The
physically sensible plan, and the one used here: the ``n`` designed poses are measured twice, once
in block 1 at the first data's condition (its mean temperature, right after its last time; without
a given condition: ``T_REF_C`` and 0 s) and once in block 2 after the temperature has changed by
``dT`` (the hall warmed up, a later shift) or the time by ``dt`` (a pause). Temperature cannot be
set pose by pose, and a repeated pose isolates exactly what changed between the blocks. A block is
taken at one temperature and one time (its own duration, short against ``dt``, is left out; the
diagnosis later uses the measured times).

Per pose the plan has 6 rows of the weighted Jacobian, ``F1(q_i; block 1)`` and ``F1(q_i; block
2)``: the columns of geometry and joint effects are the same in both, a condition effect's column
is evaluated at its block's temperature or time. The criterion is that of
:mod:`~kpioed_drake.design.discriminate.design` (the larger of ``v_A``, ``v_B``, T-optimality) on these
rows, with the same collision avoidance and solver; the reported non-centralities
``lambda_h = theta_h^T J_h^T (I - P_[G, other]) J_h theta_h / sigma^2`` are those of the first data
(with its own conditions) and the plan together (:func:`plan_assessment`). :class:`SequenceProblem`
is the same model for measurements listed one by one with their conditions (the plan's 2n rows in
order), for the KPI values and pictures of a plan.

A payload plan (opt-in, ``--condition-span 10kg``) is the same two blocks for a pair with an effect
that acts through the gravity torque (:data:`PAYLOAD_FAMILIES`): block 1 without a payload, block 2
with the given mass at the reflector point, which changes the torque effect's signature at a fixed
pose and not a joint effect's (:func:`plan_conditions`; the design CSV's ``payload_offset_kg``).

The span of each condition is the user's (``--condition-span 3K``, ``600s``, ``10min``,
``2h``, or both ``3K,600s``) or, by default, the span at which each condition explanation's test
reaches power :data:`~kpioed_drake.design.discriminate.explanations.TARGET_POWER` on the start poses
under this plan (:func:`required_spans`), rounded up to two significant digits. A span of 0 forbids the
condition: no plan can help, and the command exits 2 naming the span the data would need. The
design itself is :func:`~kpioed_drake.design.discriminate.plan.plan_design`.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import scipy.optimize

from kpioed_drake.design.discriminate.design import DiscriminationProblem, explanation_indices, tests_record
from kpioed_drake.design.discriminate.explanations import (
    CONDITION_FAMILIES,
    DEFAULT_ALPHA,
    OPTION,
    TARGET_POWER,
    Pair,
    lambda_for_power,
    noncentralities,
)
from kpioed_drake.effects import COMPLIANCE_FAMILIES, T_REF_C, Effect, extension_columns
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.files.designs import OFFSET_COLUMNS
from kpioed_drake.files.tables import read_joint_table
from kpioed_drake.robot.kinematics import Frames
from kpioed_drake.tracker.measurement import measurement_jacobian

SPAN_OPTION = "condition_span"
"""The API parameter the messages name (their ``fields``; the command line shows ``--condition-span``)."""
CONDITIONS = {
    "thermal_expansion": "temperature_C",
    "tracker_scale": "temperature_C",
    "tracker_drift": "time_s",
}
"""The condition each condition family needs."""
PAYLOAD = "payload_kg"
PAYLOAD_FAMILIES = ("joint_elasticity", BASIS_FAMILY, "backlash", *COMPLIANCE_FAMILIES)
"""Families that act through the gravity torque: a payload in block 2 changes their signature and
not the pose's, so it can separate them from a joint effect that looks alike over the reachable
poses (opt-in: ``--condition-span 10kg``)."""
UNITS = {"temperature_C": "K", "time_s": "s", PAYLOAD: "kg"}
"""Unit of each condition's span."""
PLAN_COLUMNS = OFFSET_COLUMNS
"""Column of the design CSV with each row's planned condition, from block 1's."""
_SPAN_UNITS = {
    "k": ("temperature_C", 1.0),
    "s": ("time_s", 1.0),
    "min": ("time_s", 60.0),
    "h": ("time_s", 3600.0),
    "kg": (PAYLOAD, 1.0),
}
MAX_PAYLOAD_KG = 1e4
"""Largest payload span searched for [kg] (the payload advice says "none up to" it)."""
_MAX_SPAN = {"temperature_C": 1e3, "time_s": 1e7, PAYLOAD: MAX_PAYLOAD_KG}
"""Largest span searched for [K, s, kg]: beyond, no plan can help."""
_START_SPAN = {"temperature_C": 1.0, "time_s": 60.0, PAYLOAD: 1.0}
"""First span tried when sizing one [K, s, kg]."""


def condition_of(effect: Effect) -> str | None:
    """The condition that changes ``effect``'s signature at a fixed pose: ``temperature_C`` or
    ``time_s`` (which it needs), ``payload_kg`` (a gravity-torque effect), or None."""
    if effect.family in PAYLOAD_FAMILIES:
        return PAYLOAD
    return CONDITIONS.get(effect.family)


def acts_through_torque(pair: Pair) -> bool:
    """Whether an explanation of ``pair`` acts through the gravity torque (a payload plan can help)."""
    return any(condition_of(h.effect) == PAYLOAD for h in pair)


def needed_conditions(pair: Pair) -> list[str]:
    """The conditions (``temperature_C``, ``time_s``) the explanations of ``pair`` need, in order."""
    out = []
    for h in pair:
        c = CONDITIONS.get(h.effect.family)
        if c is not None and c not in out:
            out.append(c)
    return out


def plan_conditions(pair: Pair, spans: dict) -> list[str]:
    """The conditions of a plan for ``pair``: those it needs, then ``payload_kg`` if a span for it
    is given (``spans``, :func:`parse_condition_span`) and an explanation acts through the torque."""
    out = needed_conditions(pair)
    if PAYLOAD in spans and acts_through_torque(pair):
        out.append(PAYLOAD)
    return out


def parse_condition_span(text: str | None, pair: Pair) -> dict[str, float]:
    """The spans of ``--condition-span`` (``"3K"``, ``"600s"``, ``"10min"``, ``"2h"``, ``"3K,600s"``,
    ``"10kg"``) as ``{condition: span}`` [K, s or kg]; None: ``{}`` (the default spans).

    Raises:
        InputError: naming the option: no unit or an unknown one, not a finite number >= 0, a
            condition given twice, or one that neither explanation of ``pair`` needs.
    """
    if text is None:
        return {}
    needed = needed_conditions(pair)
    if acts_through_torque(pair):
        needed = [*needed, PAYLOAD]
    if not needed:
        raise InputError(
            f"{SPAN_OPTION}: only for a {OPTION} pair with {', '.join(CONDITION_FAMILIES)} "
            f"(a temperature or time span) or with {', '.join(PAYLOAD_FAMILIES)} (a payload) "
            f"(got {' and '.join(h.effect.name for h in pair)})",
            fields=(SPAN_OPTION, OPTION),
        )
    out: dict[str, float] = {}
    for part in str(text).split(","):
        m = re.fullmatch(r"\s*([-+0-9.eE]+|nan|inf)\s*([A-Za-z]+)\s*", part, flags=re.IGNORECASE)
        unit = m.group(2).lower() if m else ""
        if m is None or unit not in _SPAN_UNITS:
            raise InputError(
                f"{SPAN_OPTION}: expected a number with a unit, K (temperature), s, min, h (time) or kg "
                f"(payload), e.g. '3K', '600s', '3K,600s' or '10kg', got {part.strip()!r}",
                fields=(SPAN_OPTION,),
            )
        try:
            value = float(m.group(1))
        except ValueError:
            value = float("nan")
        if not (np.isfinite(value) and value >= 0):
            raise InputError(
                f"{SPAN_OPTION}: expected a finite span >= 0, got {part.strip()!r}", fields=(SPAN_OPTION,)
            )
        cond, factor = _SPAN_UNITS[unit]
        if cond in out:
            raise InputError(
                f"{SPAN_OPTION}: the {cond} span is given twice ({text!r})", fields=(SPAN_OPTION,)
            )
        if cond not in needed:
            names = " and ".join(h.effect.name for h in pair)
            raise InputError(
                f"{SPAN_OPTION} {part.strip()}: {names} need no {cond} span (they need "
                f"{', '.join(f'{c} [{UNITS[c]}]' for c in needed)})",
                fields=(SPAN_OPTION,),
            )
        out[cond] = value * factor
    return out


def read_given_conditions(path: str | Path, n: int) -> dict[str, np.ndarray]:
    """The ``temperature_C`` and ``time_s`` columns of the given (first) data file, where present
    ((n,) each; a measurement CSV has them, a design CSV not)."""
    if path is None:
        return {}
    out = read_joint_table(path, None, joints="none", optional=tuple(UNITS), empty=None).values
    for c, x in out.items():
        if len(x) != n:
            raise InputError(f"{path}: column {c!r} has {len(x)} values for {n} poses")
    return out


def nice_ceil(x: float) -> float:
    """``x`` > 0 rounded up to two significant digits (2.66 -> 2.7, 13.2 -> 14)."""
    e = 10.0 ** (np.floor(np.log10(x)) - 1)
    return float(np.ceil(x / e * (1 - 1e-12)) * e)


def condition_rows(
    problem: Problem, q: np.ndarray, cond: dict, with_dq: bool, frames: Frames | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Weighted rows (n, 3, k) of geometry and ``problem``'s extensions for the poses ``q`` at the
    conditions ``cond`` (``temperature_C``, ``time_s``: (n,) or scalars), and with ``with_dq`` their
    derivative (n, 6, 3, k) (else None)."""
    out = measurement_jacobian(problem.model, q, with_dq=with_dq, frames=frames)
    ext = extension_columns(problem.model, q, problem.extensions, with_dq=with_dq, **cond)
    E, dE = ext if with_dq else (ext, None)
    H = np.concatenate([out[1][:, :, problem.free], E], axis=2) / problem.sigma
    if not with_dq:
        return H, None
    return H, np.concatenate([out[2][..., problem.free], dE], axis=3) / problem.sigma


@dataclasses.dataclass(frozen=True)
class SequenceProblem(Problem):
    """A :class:`Problem` whose measurements have known conditions, row by row: :meth:`F1` of
    exactly as many poses as :attr:`row_conditions` has values (a plan's 2n measurements, with or
    without the first data before them); its KPI is the problem's (the TCP at the working poses)."""

    row_conditions: tuple = ()
    """((condition, (N,) values [C or s]), ...)."""

    def F1(
        self, q: np.ndarray, *, with_dq: bool = False, frames: Frames | None = None
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(q)
        cond = {c: np.asarray(v) for c, v in self.row_conditions}
        if any(len(v) != len(q) for v in cond.values()):
            sizes = sorted({len(v) for v in cond.values()})
            raise InputError(f"the plan has conditions for {sizes[0]} measurements, not {len(q)}")
        H, dH = condition_rows(self, q, cond, with_dq, frames)
        return (H.reshape(-1, self.n_params), dH) if with_dq else H.reshape(-1, self.n_params)


def sequence_problem(base: Problem, conditions: dict) -> SequenceProblem:
    """``base`` (with the pair as extensions) with the conditions {condition: (N,)} of N measurements."""
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Problem)}
    return SequenceProblem(**fields, row_conditions=tuple(sorted(conditions.items())))


@dataclasses.dataclass(frozen=True)
class PlanProblem(DiscriminationProblem):
    """A :class:`DiscriminationProblem` whose poses are measured in two blocks (module docstring):
    :meth:`F1` gives 6 rows per pose. Poses whose array starts with :attr:`given_q` (the first data
    set, as the optimiser stacks it) get their own conditions (3 rows and 3 zero rows each)."""

    spans: tuple = ()
    """((condition, span [K or s]), ...) of block 2 from block 1."""
    base: tuple = ()
    """((condition, value [C or s]), ...) of block 1 (the first data's mean temperature, its last time)."""
    given_q: np.ndarray | None = None
    """(m, 6) [rad] poses already measured, or None."""
    given_conditions: tuple = ()
    """((condition, (m,) values), ...) of the given poses (missing: the base value)."""

    def conditions(self, block: int, n: int) -> dict[str, np.ndarray]:
        """``temperature_C``, ``time_s`` and ``payload_kg`` (n,) of block 1 or 2 (block 1 without a
        payload)."""
        span = dict(self.spans) if block == 2 else {}
        base = dict(self.base)
        return {c: np.full(n, base.get(c, 0.0) + span.get(c, 0.0)) for c in UNITS}

    def _block(self, q, cond, with_dq: bool, frames=None):
        """Rows (n, 3, k) (and (n, 6, 3, k)) of the poses ``q`` at the conditions ``cond``, a
        backlash smoothed."""
        H, dH = condition_rows(self, q, cond, with_dq, frames)
        if not with_dq:
            return self.smoothed(q, H.reshape(3 * len(q), -1)).reshape(len(q), 3, -1), None
        F, dF = self.smoothed(q, (H.reshape(3 * len(q), -1), dH), with_dq=True, frames=frames)
        return F.reshape(len(q), 3, -1), dF

    def given_rows_conditions(self) -> dict[str, np.ndarray]:
        """``temperature_C``, ``time_s`` (and ``payload_kg`` where the file has it) (m,) of the given
        poses (the base value where unknown)."""
        m = 0 if self.given_q is None else len(self.given_q)
        cond = {c: np.full(m, v) for c, v in self.base}
        cond.update({c: np.asarray(v, dtype=float) for c, v in self.given_conditions})
        return cond

    def sequence_conditions(self, n: int) -> dict[str, np.ndarray]:
        """``temperature_C``, ``time_s`` and ``payload_kg`` (2n,) of n poses measured as planned
        (block 1, block 2)."""
        one, two = self.conditions(1, n), self.conditions(2, n)
        return {c: np.concatenate([one[c], two[c]]) for c in UNITS}

    def F1(
        self, q: np.ndarray, *, with_dq: bool = False, frames: Frames | None = None
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(q)
        g = self.given_q
        m = len(g) if g is not None and len(q) >= len(g) and np.array_equal(q[: len(g)], g) else 0
        rows, drows = [], []
        if m:
            F, dF = self._block(q[:m], self.given_rows_conditions(), with_dq)
            rows.append(np.concatenate([F, np.zeros_like(F)], axis=1))
            drows.append(None if dF is None else np.concatenate([dF, np.zeros_like(dF)], axis=2))
            frames = None
        if len(q) > m:
            n = len(q) - m
            F1, dF1 = self._block(q[m:], self.conditions(1, n), with_dq, frames)
            F2, dF2 = self._block(q[m:], self.conditions(2, n), with_dq, frames)
            rows.append(np.concatenate([F1, F2], axis=1))
            drows.append(None if dF1 is None else np.concatenate([dF1, dF2], axis=2))
        F = np.concatenate(rows).reshape(-1, self.n_params)
        return (F, np.concatenate(drows)) if with_dq else F


def plan_problem(
    dprob: DiscriminationProblem,
    spans: dict,
    *,
    given: np.ndarray | None = None,
    given_conditions: dict | None = None,
) -> PlanProblem:
    """The :class:`PlanProblem` of ``dprob`` with block 2 ``spans`` {condition: span} [K, s] after
    block 1; block 1 at the given data's mean temperature and last time (``T_REF_C`` and 0 without)."""
    gc = {c: np.asarray(v, dtype=float) for c, v in (given_conditions or {}).items()}
    base = {
        "temperature_C": float(np.mean(gc["temperature_C"])) if "temperature_C" in gc else T_REF_C,
        "time_s": float(np.max(gc["time_s"])) if "time_s" in gc else 0.0,
        PAYLOAD: 0.0,
    }
    fields = {f.name: getattr(dprob, f.name) for f in dataclasses.fields(DiscriminationProblem)}
    return PlanProblem(
        **fields,
        spans=tuple(sorted(spans.items())),
        base=tuple(sorted(base.items())),
        given_q=None if given is None else np.asarray(given, dtype=float),
        given_conditions=tuple(sorted(gc.items())),
    )


def with_spans(plan: PlanProblem, spans: dict) -> PlanProblem:
    """``plan`` with other spans."""
    return dataclasses.replace(plan, spans=tuple(sorted(spans.items())))


def plan_lambdas(plan: PlanProblem, base: Problem, pair: Pair, q_all: np.ndarray) -> np.ndarray:
    """(2,) non-centralities of the two tests for the rows of ``q_all`` (given poses first) under
    ``plan`` (a backlash's signature as its sign, not smoothed as in the criterion)."""
    exact = dataclasses.replace(plan, backlash_tau0=())
    return noncentralities(exact.F1(q_all), explanation_indices(base, pair), pair)


def plan_assessment(
    plan: PlanProblem, base: Problem, pair: Pair, q_all: np.ndarray, *, alpha: float = DEFAULT_ALPHA
) -> dict:
    """Non-centrality and power of both tests (as :func:`~kpioed_drake.design.discriminate.design.assessment`)
    of the given poses and the poses of ``q_all`` after them measured as planned."""
    return tests_record(pair, plan_lambdas(plan, base, pair, q_all), len(np.atleast_2d(q_all)), alpha)


def _span_for(plan, base, pair, q_all, k: int, cond: str, need: float) -> float:
    """Span of ``cond`` at which explanation k's non-centrality reaches ``need`` (the other spans
    as in ``plan``); inf if none up to :data:`_MAX_SPAN`."""
    spans = dict(plan.spans)

    def lam(s: float) -> float:
        return float(plan_lambdas(with_spans(plan, {**spans, cond: s}), base, pair, q_all)[k])

    lo, lam_lo = 0.0, lam(0.0)
    if lam_lo >= need:
        return 0.0
    hi = _START_SPAN[cond]
    while (lam_hi := lam(hi)) < need:
        if hi > _MAX_SPAN[cond] or not np.isfinite(lam_hi):
            return float("inf")
        lo, hi = hi, 4.0 * hi
    return float(scipy.optimize.brentq(lambda s: lam(s) - need, lo, hi, xtol=1e-9, rtol=1e-6))


def required_spans(
    plan: PlanProblem,
    base: Problem,
    pair: Pair,
    q_all: np.ndarray,
    *,
    fixed: tuple[str, ...] = (),
    conditions: list[str] | None = None,
    alpha: float = DEFAULT_ALPHA,
    target: float = TARGET_POWER,
) -> dict[str, float]:
    """Per condition the span [K, s, kg] at which every explanation that acts through it reaches
    power ``target`` with the poses ``q_all`` under the plan (the largest over them); the spans of
    ``fixed`` conditions stay as in ``plan``, the others start at 1 K / 60 s / 1 kg and are found
    in turn (twice when there are two). ``conditions``: those to size (default: the ones the pair
    needs, :func:`needed_conditions`); a payload's span is 0 where the poses alone reach the power."""
    spans = dict(plan.spans)
    free = [c for c in (needed_conditions(pair) if conditions is None else conditions) if c not in fixed]
    for c in free:
        spans.setdefault(c, _START_SPAN[c])
    for _ in range(2 if len(free) > 1 else 1):
        for c in free:
            need = [
                _span_for(
                    with_spans(plan, spans),
                    base,
                    pair,
                    q_all,
                    k,
                    c,
                    lambda_for_power(target, h.effect.n_params, alpha),
                )
                for k, h in enumerate(pair)
                if condition_of(h.effect) == c
            ]
            spans[c] = max(need)
    return {c: spans[c] for c in free}
