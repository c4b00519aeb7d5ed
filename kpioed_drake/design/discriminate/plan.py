"""The discrimination design of a pair that needs temperature or time: poses and their conditions.

:func:`plan_design` is what ``kpioed design --discriminate "A|B"`` runs (through
:func:`~kpioed_drake.design.workflow.run_design`): a pair of joint effects goes to
:func:`~kpioed_drake.design.discriminate.design.discrimination_design` (poses only); a pair with
``thermal_expansion``, ``tracker_scale`` or ``tracker_drift`` (or a gravity-torque effect with a
payload span, ``--condition-span 10kg``) gets a measurement plan of
:mod:`~kpioed_drake.design.discriminate.conditions`: ``n`` poses, each measured in block 1 and again in
block 2 after the span of temperature or time, chosen to maximise the smaller non-centrality (T-optimal) of
the first data and the plan together. The result's rows are the measurements in order (block 1,
then block 2: 2n rows) with their block and planned condition offset (:attr:`PlanReport.plan_columns`,
the design CSV's ``block``, ``temperature_offset_K`` / ``time_offset_s``); its ``discrimination``
record has ``before``, ``after`` and the ``plan`` (spans, where they come from, the span the designed
poses need, and the heuristic poses under the same plan for comparison). Its KPI values (tr(Cs)/3,
scaled tr(Cp)) are those of the extended model with the first data and the plan, each measurement
at its condition (:class:`~kpioed_drake.design.discriminate.conditions.SequenceProblem`, also the problem
returned for the JSON record and the 3-D page).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from kpioed_drake.design.discriminate.conditions import (
    MAX_PAYLOAD_KG,
    PAYLOAD,
    PLAN_COLUMNS,
    SPAN_OPTION,
    UNITS,
    PlanProblem,
    acts_through_torque,
    nice_ceil,
    parse_condition_span,
    plan_assessment,
    plan_conditions,
    plan_problem,
    required_spans,
    sequence_problem,
    with_spans,
)
from kpioed_drake.design.discriminate.design import (
    DiscriminationReport,
    checked_pair,
    discrimination_design,
    discrimination_problem,
    discrimination_record,
    heuristic_start,
    optimize_discrimination,
    result_fields,
)
from kpioed_drake.design.discriminate.explanations import (
    DEFAULT_ALPHA,
    OPTION,
    TARGET_POWER,
    Pair,
    condition_message,
    condition_spread,
    discriminate_error,
)
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.report import DesignReport
from kpioed_drake.effects import T_REF_C, extension_columns
from kpioed_drake.errors import InputError, param
from kpioed_drake.estimation.problem import Problem


@dataclasses.dataclass
class PlanReport(DiscriminationReport):
    """A :class:`DiscriminationReport` whose rows ``q`` (2n, 6) are the planned measurements in
    order, with each row's block and condition offset."""

    plan_columns: dict | None = None
    """Per row: ``block`` (1 or 2) and ``temperature_offset_K`` and/or ``time_offset_s`` (from block 1)."""

    def summary(self) -> dict:
        out = super().summary()
        for k, pose in enumerate(out["poses"]):
            pose.update({c: v[k].item() for c, v in (self.plan_columns or {}).items()})
        return out


def _kpi_values(view: Problem, q) -> dict:
    try:
        return view.criteria(q)
    except InputError:
        return {"kpi_avg_var_mm2": float("nan"), "param_crit": float("nan")}


def plan_lines(rec: dict) -> list[str]:
    """Printed lines of a ``discrimination`` record's ``plan`` (none without one)."""
    plan = rec.get("plan")
    if not plan:
        return []
    lines = [
        f"  plan: {plan['n_distinct_poses']} poses measured twice, block 1 at the first data's condition, "
        f"block 2 after the span ({plan['n_measurements']} measurements)"
    ]
    for s in plan["spans"]:
        lines.append(
            f"  {s['condition']} span {s['span']:.4g} {s['unit']} ({s['source']}); needed for power "
            f"{plan['target_power']:g}: {s['required_start']:.3g} {s['unit']} with the start poses, "
            f"{s['required']:.3g} {s['unit']} with the designed poses"
        )
    heur = plan["heuristic"]
    lines.append(
        "  heuristic poses, same plan: "
        + "; ".join(
            f"{name} lambda {heur[name]['lambda']:.3g}, power {heur[name]['power']:.3f}"
            for name in rec["pair"]
        )
    )
    return lines


def payload_advice(
    base: Problem, pair: Pair, given: np.ndarray | None, q: np.ndarray, *, alpha: float = DEFAULT_ALPHA
) -> dict:
    """What a payload would add to a poses-only design of a pair with a gravity-torque effect: the
    payload [kg] at which every torque explanation's test reaches power :data:`TARGET_POWER` when
    the designed poses ``q`` (n, 6) are measured again with it at the reflector (block 2 of a payload
    plan; ``given`` (m, 6) or None before them). 0: the repeated poses reach the power without one;
    None: no payload up to :data:`~kpioed_drake.design.discriminate.conditions.MAX_PAYLOAD_KG` does.
    ``rated_payload_kg``: the robot's (model file), or None."""
    plan = plan_problem(discrimination_problem(base, pair), {}, given=given)
    g = np.zeros((0, base.robot.n_joints)) if given is None else given
    need = required_spans(plan, base, pair, np.concatenate([g, q]), conditions=[PAYLOAD], alpha=alpha)
    kg = need[PAYLOAD]
    return {
        "model": "the designed poses measured again with the payload at the reflector "
        f"({param(SPAN_OPTION)})",
        "target_power": TARGET_POWER,
        "required_kg": nice_ceil(kg) if np.isfinite(kg) and kg > 0 else (0.0 if kg == 0 else None),
        "rated_payload_kg": base.robot.rated_payload_kg,
    }


def payload_lines(rec: dict) -> list[str]:
    """Printed line of a poses-only record's ``payload`` advice (none without one)."""
    adv = rec.get("payload")
    if not adv:
        return []
    kg = adv["required_kg"]
    if kg is None:
        return [
            f"  payload: no payload up to {MAX_PAYLOAD_KG / 1000:g} t makes the repeated poses reach power "
            f"{adv['target_power']:g}"
        ]
    if kg == 0:
        return [
            f"  payload: not needed (the designed poses measured twice reach power {adv['target_power']:g})"
        ]
    rated = adv.get("rated_payload_kg")
    if rated is not None and kg > rated:
        return [
            f"  payload: the designed poses would need {kg:g} kg at the reflector for power "
            f"{adv['target_power']:g}, more than the rated {rated:g} kg: more poses instead"
        ]
    carries = (
        f"within the rated {rated:g} kg" if rated is not None else "if the robot carries it; else more poses"
    )
    return [
        f"  payload: the designed poses measured again with {kg:g} kg at the reflector reach power "
        f"{adv['target_power']:g} ({param(SPAN_OPTION)} {kg:g}kg, {carries})"
    ]


def _no_plan(problem: Problem, pair, q, alpha: float, why: str) -> InputError:
    """The exit-2 error where no plan can help: ``why`` and the spans an even ramp would need."""
    spans = condition_spread(problem, pair, q, alpha=alpha)
    return InputError(
        f"{condition_message(pair, spans, len(q), 'start', alpha)} ({why})", fields=(OPTION, SPAN_OPTION)
    )


def plan_design(
    problem: Problem,
    pair_text: str,
    *,
    n: int,
    given: np.ndarray | None = None,
    given_conditions: dict | None = None,
    condition_span: str | None = None,
    alpha: float = DEFAULT_ALPHA,
    **options: Any,
) -> tuple[DesignReport, Problem]:
    """Poses and conditions that tell the two explanations of ``pair_text`` apart (module docstring).

    Args:
        problem: the identification problem (its extensions are estimated too, as nuisance).
        pair_text: ``"A|B"`` (:func:`~kpioed_drake.design.discriminate.explanations.parse_pair`).
        n: new poses (each measured twice when the pair needs a condition: 2n rows).
        given: (m, 6) [rad] the first data set's poses, held fixed; None: none ("before" is then
            the heuristic start under the same plan).
        given_conditions: {``temperature_C``: (m,), ``time_s``: (m,), ``payload_kg``: (m,)} of the
            given poses, where known
            (:func:`~kpioed_drake.design.discriminate.conditions.read_given_conditions`); missing: one
            constant condition (no payload).
        condition_span: ``--condition-span`` text (``"3K"``, ``"600s"``, ``"3K,600s"``, ``"10kg"``) or None
            (the span for power :data:`TARGET_POWER` on the start poses, rounded up).
        alpha: level of the tests.
        options: ``collision``, ``solver``, ``seed``, ``starts``, ``allow_infeasible``, ``start``
            of :func:`~kpioed_drake.design.optimize.optimize_design`.

    Returns:
        the result (:class:`PlanReport`, or the poses-only result for a pair of joint effects) and
        the extended problem (for a plan: its
        :class:`~kpioed_drake.design.discriminate.conditions.SequenceProblem` of the 2n measurements).

    Raises:
        InputError: bad pair or span (naming the option), a span of 0 or a pair no span can
            separate (naming the span an even ramp would need).
    """
    pair = checked_pair(problem, pair_text, alpha)
    spans_user = _user_spans(problem, pair, condition_span)
    conds = plan_conditions(pair, spans_user)
    if not conds:
        res, base = discrimination_design(problem, pair_text, n=n, given=given, alpha=alpha, **options)
        if acts_through_torque(pair):
            res.discrimination["payload"] = payload_advice(base, pair, given, res.q, alpha=alpha)
        return res, base
    if problem.n_targets > 1:
        raise discriminate_error(f"a measurement plan for {pair_text!r} takes one target per pose")
    start = heuristic_start(options)
    seed, collision = int(options.get("seed", 0)), options.get("collision", True)
    base = _extended(problem, pair)
    q_start = heuristic_design(base, n=n, seed=seed, collision=collision)
    plan, spans = _sized_plan(
        base, pair, q_start, spans_user, given=given, given_conditions=given_conditions, alpha=alpha
    )
    res = optimize_discrimination(plan, n=n, given=given, start=start, **options)
    tests = _assessments(plan, base, pair, q_start, res.q, given=given, conds=conds, alpha=alpha)
    criterion = (
        "the larger of v_A, v_B over the planned rows (each pose in block 1 and block 2); 1/v_h <= "
        "lambda_h (kpioed_drake.design.discriminate.conditions)"
    )
    record = discrimination_record(pair, alpha, criterion, res, tests["before"], tests["after"])
    record["plan"] = _plan_record(res, plan, pair, spans, spans_user, conds, tests)
    return _result(res, plan, base, given, spans, record)


def _user_spans(problem: Problem, pair, condition_span) -> dict:
    """The spans ``condition_span`` asks for (a 0 kg payload dropped: the poses alone), checked
    against the robot's rated payload."""
    spans_user = parse_condition_span(condition_span, pair)
    if spans_user.get(PAYLOAD) == 0:  # no payload: the poses alone (a payload is never needed)
        del spans_user[PAYLOAD]
    rated = problem.robot.rated_payload_kg
    if PAYLOAD in spans_user and rated is not None and spans_user[PAYLOAD] > rated:
        raise InputError(
            f"{SPAN_OPTION} {spans_user[PAYLOAD]:g}kg: more than {problem.robot.name}'s rated payload of "
            f"{rated:g} kg (rated_payload_kg in its model file)",
            fields=(SPAN_OPTION,),
        )
    return spans_user


def _extended(problem: Problem, pair) -> Problem:
    """``problem`` with the pair's two effects as further extensions (values unknown), after checking
    that each changes the measurements at all."""
    zero = [dataclasses.replace(h.effect, values=None) for h in pair]
    base = dataclasses.replace(problem, extensions=(*problem.extensions, *zero))
    probe = heuristic_design(base, n=base.min_poses(), seed=0, collision=False)
    for h in pair:
        if not np.any(
            extension_columns(base.model, probe, [h.effect], temperature_C=T_REF_C + 1.0, time_s=1.0)
        ):
            raise discriminate_error(f"{h.effect.name} does not change the measurements of {base.robot.name}")
    return base


def _sized_plan(base: Problem, pair, q_start, spans_user: dict, *, given, given_conditions, alpha: float):
    """The plan with its spans: the user's, and for the others the span the start poses ``q_start``
    need for the target power, rounded up. Returns (plan, spans)."""
    forbidden = [c for c, s in spans_user.items() if s == 0]
    if forbidden:
        raise _no_plan(base, pair, q_start, alpha, f"{SPAN_OPTION} forbids a {forbidden[0]} span")
    plan = plan_problem(
        discrimination_problem(base, pair), spans_user, given=given, given_conditions=given_conditions
    )
    g = np.zeros((0, base.robot.n_joints)) if given is None else given
    need_start = required_spans(plan, base, pair, np.concatenate([g, q_start]), fixed=spans_user, alpha=alpha)
    if not all(np.isfinite(list(need_start.values()))):
        raise _no_plan(base, pair, q_start, alpha, "no span of the plan reaches the power")
    spans = {**spans_user, **{c: nice_ceil(s) if s > 0 else 0.0 for c, s in need_start.items()}}
    return with_spans(plan, spans), spans


def _assessments(
    plan: PlanProblem, base: Problem, pair, q_start, q_new, *, given, conds, alpha: float
) -> dict:
    """Both tests under the plan: ``before`` (the given poses, else the heuristic start), ``after``
    (with the designed poses ``q_new``) and ``heuristic`` (with the start poses instead); and the
    spans the designed and the start poses need, ``need_after`` and ``need_final``."""
    g = np.zeros((0, base.robot.n_joints)) if given is None else given
    q_all = np.concatenate([g, q_new])
    after = plan_assessment(plan, base, pair, q_all, alpha=alpha)
    after["poses"] = "given + plan" if given is not None else "plan"
    if given is not None:
        before = plan_assessment(plan, base, pair, given, alpha=alpha)
        before["poses"] = "given"
    else:
        before = plan_assessment(plan, base, pair, q_start, alpha=alpha)
        before["poses"] = "heuristic, same plan"
    heuristic = plan_assessment(plan, base, pair, np.concatenate([g, q_start]), alpha=alpha)
    need_after = required_spans(plan, base, pair, q_all, conditions=conds, alpha=alpha)
    need_final = required_spans(plan, base, pair, np.concatenate([g, q_start]), conditions=conds, alpha=alpha)
    return dict(before=before, after=after, heuristic=heuristic, need_after=need_after, need_final=need_final)


def _plan_record(
    res: DesignReport, plan: PlanProblem, pair, spans: dict, spans_user: dict, conds, tests: dict
) -> dict:
    """The JSON record's ``plan``: the blocks, the spans with where they come from and what the start
    and the designed poses need (``tests`` of :func:`_assessments`), and the heuristic poses under
    the same plan."""
    need_final, need_after, heuristic = tests["need_final"], tests["need_after"], tests["heuristic"]
    return {
        "model": "each designed pose measured twice: block 1 at the first data's condition (mean "
        "temperature, after its last time, no payload), block 2 after the span (warmer, later, or "
        "with the payload at the reflector)",
        "n_distinct_poses": int(res.n),
        "n_measurements": 2 * int(res.n),
        "block1": {c: v for c, v in plan.base if c in spans},
        "spans": [
            {
                "condition": c,
                "column": PLAN_COLUMNS[c],
                "span": spans[c],
                "unit": UNITS[c],
                "source": "given" if c in spans_user else f"default: for power {TARGET_POWER:g}, rounded up",
                "required_start": need_final[c],
                "required": need_after[c],
            }
            for c in conds
        ],
        "target_power": TARGET_POWER,
        "heuristic": {h.effect.name: heuristic[h.effect.name] for h in pair},
    }


def _result(
    res: DesignReport, plan: PlanProblem, base: Problem, given, spans: dict, record: dict
) -> tuple[PlanReport, Problem]:
    """The :class:`PlanReport` (``res``'s poses as the 2n planned measurements) and the problem of
    those measurements (:class:`~kpioed_drake.design.discriminate.conditions.SequenceProblem`)."""
    n = res.n
    rows = plan.sequence_conditions(n)
    seq = np.concatenate([res.q, res.q])
    if given is None:
        crit, alone = _kpi_values(sequence_problem(base, rows), seq), None
    else:
        first = plan.given_rows_conditions()
        both = {c: np.concatenate([first[c], rows[c]]) for c in rows}
        crit = _kpi_values(sequence_problem(base, both), np.concatenate([given, seq]))
        alone = _kpi_values(sequence_problem(base, first), given)
    fields = result_fields(res, crit, alone)
    fields.update(q=seq, reports=[*res.reports, *(dict(r) for r in res.reports)])
    columns = {"block": np.repeat([1, 2], n)}
    for c, s in spans.items():
        columns[PLAN_COLUMNS[c]] = np.repeat([0.0, float(s)], n)
    return PlanReport(**fields, discrimination=record, plan_columns=columns), sequence_problem(base, rows)
