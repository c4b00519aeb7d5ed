"""Naming the cause: candidate effects, their identifiability, score tests and stepwise selection.

- :func:`candidate_effects`: joint elasticity of the joints gravity loads, gear errors (n in {1, 2})
  and gear-ratio errors of every joint, the couplings of the robot's structure (joint-map followers
  and their leaders, each branch's drive trains: :func:`~kpioed_drake.robot.drivetrain.coupling_pairs`),
  backlash of the joints whose gravity torque takes both signs, thermal expansion and tracker scale
  if the temperature varies, tracker drift if the time does.
- :func:`identifiability`: the fraction of a candidate's columns outside the span of the current
  model's (``remaining``; 1 = orthogonal, 0 = absorbed), the largest canonical correlation with them.
- :func:`score_tests`: the residual structure, ``r^T P r / sigma^2`` per candidate with P the
  projector on the part of its columns the model cannot absorb (chi^2 under "no effect").
- :func:`select_effects`: forward selection with the likelihood ratio against the known noise
  (``LR = chi^2_before - chi^2_after`` ~ chi^2(k), its family-wise p-value over the candidates of a
  step by the weighted min-p method, :mod:`~kpioed_drake.estimation.multiplicity`; a backlash scored
  with every side its joint's torque may take under the mass prior, its sides weighted by
  :func:`~kpioed_drake.diagnosis.sides.side_weights`), BIC (``LR > k ln(3 n)``) and the K-fold
  held-out error, which must fall by more than its own uncertainty (:func:`.fit.held_out_gain`); no
  fixed number of effects; after each addition every chosen effect is re-tested for removal.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis import fit as ft
from kpioed_drake.diagnosis.fit import Fit, FitProblem, HeldOutGain, held_out_gain, pose_groups, stop_reason
from kpioed_drake.diagnosis.options import BACKLASH_MIN_SIDE, MIN_REMAINING, PAIR_ALPHA_SHARE
from kpioed_drake.diagnosis.pairs import pair_step
from kpioed_drake.diagnosis.records import CandidateTest, PairTest, Selection, SelectionStep, StandIn
from kpioed_drake.diagnosis.sides import side_penalty, side_weights, unit_columns
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.compliance import candidates as compliance_candidates
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.identifiability import identifiability, model_factors, projected_basis
from kpioed_drake.estimation.multiplicity import adjusted_p, critical_p, min_p_null, normalized
from kpioed_drake.robot.drivetrain import coupling_pairs
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.data import Measurements

_VARIABLE = {
    "joint_elasticity": "gravity torque tau_{joint}",
    "gear_cyclic": "sin/cos({harmonic} q_{joint})",
    "thermal_expansion": "temperature x reflector position",
    "tracker_drift": "time",
    "joint_scale": "q_{joint}",
    "joint_coupling": "q_{coupled} (on joint {joint})",
    "tracker_scale": "temperature x tracker distance",
    "backlash": "sign of tau_{joint}",
    "column_compliance": "carriage height x gravity moment above joint {joint}",
    "base_compliance": "gravity moment about the base",
    "lateral_compliance": "gravity moment across the axis of joint {joint}",
    gb.FAMILY: "gravity torque of joint {joint} with any link masses",
    lb.FAMILY: "gravity moment across the axis of joint {joint} with any link masses",
}


def candidate_effects(
    data: Measurements, tau: np.ndarray | None = None, *, robot: Robot | None = None
) -> tuple[list, list[str]]:
    """The candidate extensions for this data and notes on the ones left out.

    Args:
        data: the measurements (n poses of nj joints).
        tau: (n, nj) gravity torques at the commanded angles [N m] (``FitProblem.tau``): joint j's
            elasticity and backlash are candidates where it is nonzero; where it is zero, the
            mass-free bases if only the file's masses make it so (:func:`.gravity_basis.
            unloaded_candidates`, :func:`.lateral_basis.candidates`). None: joint 1 vertical.
        robot: the robot; with it, the compliance of a lifting column (a prismatic joint within 30
            deg of gravity that moves in the data) and of the base (a robot with such a column or
            ``compliant_base: true``) are candidates (:func:`~kpioed_drake.effects.compliance.candidates`).
    """
    nj = data.q.shape[1]
    if tau is None:
        loaded = np.arange(nj) > 0
    else:
        size = np.max(np.abs(tau), axis=0)
        loaded = size > 1e-9 * max(1.0, float(np.max(size)))
    cands = [fx.Effect("joint_elasticity", j + 1) for j in range(nj) if loaded[j]]
    idle = np.flatnonzero(~loaded) + 1
    more, notes = gb.unloaded_candidates(tau is not None and robot, data.q, idle, data.payload_kg)
    cands += [dataclasses.replace(fx.Effect(gb.FAMILY, j), n_basis=n) for j, n in more]
    lateral, lnotes = lb.candidates(tau is not None and robot, data.q, data.payload_kg)
    cands, notes = (
        cands + [dataclasses.replace(fx.Effect(lb.FAMILY, j), n_basis=n) for j, n in lateral],
        notes + lnotes,
    )
    cands += [fx.Effect("gear_cyclic", j, n) for j in range(1, nj + 1) for n in (1, 2)]
    cands += [fx.Effect("joint_scale", j) for j in range(1, nj + 1)]
    cands += [fx.Effect("joint_coupling", i, coupled=j) for i, j in coupling_pairs(robot or None, nj)]
    one_sided = []
    for j in np.flatnonzero(loaded) + 1:
        side = np.sign(tau[:, j - 1]) if tau is not None else np.zeros(1)
        if min(np.sum(side > 0), np.sum(side < 0)) >= BACKLASH_MIN_SIDE:
            cands.append(fx.Effect("backlash", int(j)))
        else:
            one_sided.append(str(j))
    if one_sided:
        notes.append(
            f"backlash of joint(s) {', '.join(one_sided)} is not a candidate: the gravity torque does not "
            f"take both signs at {BACKLASH_MIN_SIDE} poses or more (a one-sided backlash is the joint's zero)"
        )
    if data.temperature_C is not None and np.ptp(data.temperature_C) > 0.5:
        cands += [fx.Effect("thermal_expansion"), fx.Effect("tracker_scale")]
    else:
        why = "no temperature_C column" if data.temperature_C is None else "the temperature varies by < 0.5 K"
        notes.append(
            f"thermal_expansion and tracker_scale are not candidates: {why} (a constant temperature only "
            "rescales lengths, which the geometric parameters absorb)"
        )
    if data.time_s is not None and np.ptp(data.time_s) > 0:
        cands.append(fx.Effect("tracker_drift"))
    else:
        notes.append("tracker_drift is not a candidate: no time_s column or a constant time")
    if robot is not None:
        pairs, more = compliance_candidates(robot, data.q)
        cands += [fx.Effect(f, j) for f, j in pairs]
        notes += more
    return cands, notes


def columns(prob: FitProblem, fit: Fit, cands: list[fx.Effect]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Weighted columns at ``fit`` over all poses: the model's (3 n, n_params) and each candidate's."""
    n = prob.data.n
    _, H, E = prob.response(fit.model, list(fit.effects) + list(cands), np.arange(n))
    k0 = fit.k
    Jm = np.concatenate([H[:, :, fit.free], E[:, :, :k0]], axis=2).reshape(3 * n, -1) / prob.sigma
    out, c = [], k0
    for e in cands:
        out.append(E[:, :, c : c + e.n_params].reshape(3 * n, -1) / prob.sigma)
        c += e.n_params
    return Jm, out


def score_tests(prob: FitProblem, fit: Fit, cands: list[fx.Effect]) -> list:
    """Residual structure: score statistic of each candidate's columns against ``fit``'s residuals."""
    r = (fit.residuals / prob.sigma).reshape(-1)
    Jm, cols = columns(prob, fit, cands)
    Q, _ = np.linalg.qr(Jm)
    out = []
    for e, C in zip(cands, cols, strict=True):
        U = projected_basis(Q, C)
        proj = U.T @ r
        stat = float(proj @ proj)
        dof = int(U.shape[1])
        out.append(
            {
                "candidate": e.name,
                "variable": _VARIABLE[e.family].format(joint=e.joint, harmonic=e.harmonic, coupled=e.coupled),
                "score": stat,
                "dof": dof,
                "p_value": float(scipy.stats.chi2.sf(stat, dof)) if dof else 1.0,
            }
        )
    return sorted(out, key=lambda d: d["p_value"])


ABSORBED = "absorbed by the model's parameters (not identifiable from these poses)"
NOT_REFITTED = "not refitted: its score statistic (linearised LR) cannot make it the best"
NO_GAIN = "significant but does not lower the held-out error"

SCREEN_FRACTION = 0.5
"""A candidate is refitted only if its score statistic reaches this fraction of the critical value."""
SCREEN_MARGIN = 10.0
"""... and its penalised score is within max(this, 10 %) of the best penalised score."""


def _screen(tests: list[CandidateTest], level, ln_n: float) -> tuple[list[CandidateTest], list[int]]:
    """The scored candidates worth a full fit, by their score statistic (the linearised LR at the
    current fit, close to the refitted LR): those whose score reaches half the corrected critical
    value (``level(weight)``: the marginal p-value a candidate of that normalized weight needs) and
    whose penalised score ``score - k ln(3 n)`` is within ``max(SCREEN_MARGIN, 10 %)`` of the best
    one. Returns the tests with the others marked (no LR in their row) and the places to refit."""
    scored = [i for i, t in enumerate(tests) if t.score is not None]
    if not scored:
        return tests, []
    pen = {i: tests[i].score - tests[i].effect.n_params * ln_n for i in scored}
    top = max(pen.values())
    out, keep = list(tests), []
    for i in scored:
        t = tests[i]
        crit = float(scipy.stats.chi2.isf(level(t.weight), t.effect.n_params))
        if t.score >= SCREEN_FRACTION * crit and pen[i] >= top - max(SCREEN_MARGIN, 0.1 * abs(top)):
            keep.append(i)
        else:
            out[i] = dataclasses.replace(t, status=NOT_REFITTED)
    return out, keep


def _scored(prob: FitProblem, current: Fit, pool, sides) -> tuple[list[CandidateTest], list, np.ndarray]:
    """Identifiability and score statistic of every candidate in ``pool`` at ``current``; a backlash
    whose joint has several candidate sides (``sides``: ``{joint: (K, n)}``) is scored with each and
    keeps the best. Returns the tests (pool order), the orthonormal bases of the step's weighted
    min-p test and their normalized weights (each candidate's sides weighted by
    :func:`~kpioed_drake.diagnosis.sides.side_weights`)."""
    Jm, cols = columns(prob, current, pool)
    Q, _ = factors = model_factors(Jm)
    r = (current.residuals / prob.sigma).reshape(-1)
    units = unit_columns(
        prob, current, [e.joint for e in pool if e.family == "backlash" and e.joint in sides]
    )
    tests, bases, raw, index = [], [], [], []
    for e, Jc in zip(pool, cols, strict=True):
        t = CandidateTest(effect=e, **identifiability(Jm, Jc, factors=factors))
        if t.remaining < MIN_REMAINING:
            tests.append(dataclasses.replace(t, status=ABSORBED))
            continue
        U, pats = [projected_basis(Q, Jc)], None
        if e.family == "backlash" and e.joint in units:  # every side the mass prior allows
            pats = sides[e.joint]
            g = units[e.joint].reshape(-1, 3)
            U = [projected_basis(Q, (g * s[:, None]).reshape(-1, 1)) for s in pats]
        keep = [i for i, u in enumerate(U) if u.shape[1]]
        if not keep:
            tests.append(t)
            continue
        w = side_weights([U[i] for i in keep])  # a backlash: its expected side and the other sides
        scores = [float(np.sum((U[i].T @ r) ** 2)) for i in keep]
        best_i = int(np.argmax(scores))
        several = len(U) > 1
        t = dataclasses.replace(
            t,
            score=scores[best_i],
            basis=U[0],  # the pair step's: the current (expected) side, not one the residuals chose
            n_sides=len(U) if several else None,
            side=pats[keep[best_i]] if several else None,
            side_bases=tuple(U) if several else None,
        )
        index.append(len(bases) + best_i)  # its best side's place among the step's bases
        tests.append(t)
        bases += [U[i] for i in keep]
        raw += list(w)
    weights = normalized(raw, len(raw)) if raw else np.ones(0)
    scored = [i for i, t in enumerate(tests) if t.score is not None]
    for i, k in zip(scored, index, strict=True):
        tests[i] = dataclasses.replace(tests[i], weight=float(weights[k]))
    return tests, bases, weights


def _refit(prob: FitProblem, current: Fit, t: CandidateTest, *, null, m: int, alpha: float, ln_n: float):
    """``t`` with its likelihood-ratio test and BIC: the refit of the current model with the
    candidate (a backlash on the side its score chose), kept in the test if it is significant with a
    BIC gain. The best of several sides is ranked as one test: its BIC gain is lowered by
    :func:`~kpioed_drake.diagnosis.sides.side_penalty`."""
    e = t.effect
    trial = prob if t.side is None else prob.with_side(e.joint, t.side)
    f = trial.fit(list(current.effects) + [e], start=current)
    lr = max(current.cost - f.cost, 0.0)
    p = float(scipy.stats.chi2.sf(lr, e.n_params))
    penalty = None if t.side_bases is None else side_penalty(t.side_bases)
    delta_bic = lr - e.n_params * ln_n
    if penalty is not None:
        delta_bic -= penalty
    t = dataclasses.replace(
        t,
        lr_stat=lr,
        dof=e.n_params,
        p_value=p,
        p_value_corrected=adjusted_p(p, null, m, weight=t.weight),
        delta_bic=delta_bic,
        side_penalty=penalty,
    )
    return dataclasses.replace(t, fit=f) if t.p_value_corrected < alpha and delta_bic > 0 else t


def _test_step(prob: FitProblem, current: Fit, pool, sides, *, alpha: float, ln_n: float, k_folds: int):
    """Identifiability and score statistic of every candidate in ``pool``, LR test and BIC of those
    the score screen keeps (:func:`_screen`), held-out error of the best significant one.

    Returns:
        (tests, best, problem): the tests in pool order, the place of the best significant one (or
        None) and the problem from now on (a backlash chosen best keeps the side its score chose).
    """
    tests, bases, weights = _scored(prob, current, pool, sides)
    m = max(len(bases), 1)
    # the min-p law only where a candidate can be significant (its family-wise p-value is never below
    # its marginal one, and the refitted LR is close to the score): else Bonferroni's
    p_min = min(
        (float(scipy.stats.chi2.sf(t.score, t.effect.n_params)) for t in tests if t.score is not None),
        default=1.0,
    )
    null = min_p_null(bases, weights=weights) if bases and p_min < 2 * alpha else None
    tests, refit = _screen(tests, lambda w: critical_p(alpha, null, m, weight=w), ln_n)
    best, kw = None, {"null": null, "m": m, "alpha": alpha, "ln_n": ln_n}
    done = ft.independent(
        lambda k: _refit(prob, current, tests[refit[k]], **kw), len(refit), size=current.J.size
    )  # the refits at once
    for i, t in zip(refit, done, strict=True):
        tests[i] = t
        if t.fit is not None and (best is None or t.delta_bic > tests[best].delta_bic):
            best = i
    # held-out error of the best significant candidate only: the one the step may add (the others'
    # held-out errors would not change the decision, and they are the expensive part)
    if best is not None:
        t = tests[best]
        if t.side is not None:  # its backlash's side from now on
            prob = prob.with_side(t.effect.joint, t.side)
        hold = prob.holdout(t.fit, k=k_folds)
        tests[best] = dataclasses.replace(t, holdout=hold, holdout_rms_mm=rms(hold))
    return tests, best, prob


def backward_step(
    sel: Selection, added: fx.Effect, *, alpha: float, ln_n: float, k_folds: int
) -> tuple[Selection, list[str]]:
    """Remove every chosen effect (but ``added``, the one just added) that no longer earns its place.

    An effect whose Wald statistic ``v^T C^-1 v`` (its values and their covariance in the current
    fit, the linearised LR of its removal) exceeds twice the larger of the critical value and the
    BIC penalty is kept without a refit; the others are refitted without it and tested.

    Returns:
        (selection, removed): the selection without them and their names.
    """
    prob, fit, hold = sel.problem, sel.fit, sel.holdout
    evidence, removed = dict(sel.evidence), []
    for old in list(sel.fit.effects):
        if old.name == added.name or len(fit.effects) < 2:
            continue
        bar = max(float(scipy.stats.chi2.isf(alpha, old.n_params)), old.n_params * ln_n)
        if _wald(fit, old) > 2.0 * bar:
            continue
        rest = [x for x in fit.effects if x.name != old.name]
        f = prob.fit(rest, start=fit)
        lr = max(f.cost - fit.cost, 0.0)
        p = float(scipy.stats.chi2.sf(lr, old.n_params))
        if p >= alpha or lr - old.n_params * ln_n <= 0:
            fit, hold = f, prob.holdout(f, k=k_folds)
            removed.append(old.name)
            evidence.pop(old.name, None)
    return dataclasses.replace(sel, fit=fit, holdout=hold, evidence=evidence), removed


def _wald(fit: Fit, e) -> float:
    """``v^T C^-1 v`` of effect ``e``'s values ``v`` in ``fit`` (0 where its covariance is singular)."""
    c = fit.layout.effects.start
    for x in fit.effects:
        if x.name == e.name:
            break
        c += x.n_params
    C = fit.Cp[c : c + e.n_params, c : c + e.n_params]
    v = next(x for x in fit.effects if x.name == e.name).value_array()
    try:
        return float(v @ np.linalg.solve(C, v))
    except np.linalg.LinAlgError:
        return 0.0


def stand_in_reason(fit: Fit, gain: HeldOutGain, *, alpha: float) -> str | None:
    """Why a significant candidate is a stand-in (not named), or None.

    A stand-in: the model with it (``fit``) still fails the goodness-of-fit test and its held-out
    gain (``gain``, :func:`~.fit.held_out_gain`) is positive but not above its own standard
    error: a piece of an error outside the candidate list that the candidate's columns happen to fit
    on the poses it was fitted to.
    """
    if scipy.stats.chi2.sf(fit.cost, fit.dof) >= alpha or gain.predicts_better or gain.gain_mm2 <= 0:
        return None
    return (
        f"does not predict fresh poses better by more than its uncertainty ({gain.text()}) while the "
        "model with it still fails the goodness-of-fit test"
    )


def _verdict(t: CandidateTest, before: np.ndarray, groups: np.ndarray, alpha: float):
    """Whether the step's best candidate joins: (status, stand-in record, gain); status None: add it.

    It joins when it predicts the held-out poses better by more than the gain's uncertainty
    (:class:`~.fit.HeldOutGain`), or, when the model with it fits to the noise level (the
    goodness-of-fit test passes, so that its likelihood-ratio test is exact), better at all: a
    small true effect that the noise hides from the held-out error is still named by its LR.
    """
    gain = held_out_gain(before, t.holdout, groups)
    fits = scipy.stats.chi2.sf(t.fit.cost, t.fit.dof) >= alpha
    if gain.gain_mm2 > 0 and (fits or gain.predicts_better):
        return None, None, gain
    why = stand_in_reason(t.fit, gain, alpha=alpha)
    if why:
        name = t.effect.name if isinstance(t, CandidateTest) else " + ".join(e.name for e in t.effects)
        return f"stand-in: {why}", StandIn(name, 1.0 - gain.after_mm / gain.before_mm, t.lr_stat, why), gain
    return f"{NO_GAIN} ({gain.text()})", None, gain


def _pair(sel: Selection, tests, sides, step: SelectionStep, *, alpha: float, ln_n: float, k_folds: int):
    """After a step that added nothing: the joint test of correlated pairs (:func:`.pairs.pair_step`).

    Returns:
        (selection, step, pair): the selection with the pair step's problem, the step with the pairs'
        tests and the pair's test to add, or None.
    """
    tested = [
        (t.effect, t.basis, sides[t.effect.joint][0] if t.side is not None else None)
        for t in tests
        if t.basis is not None
    ]
    r = (sel.fit.residuals / sel.problem.sigma).reshape(-1)
    level = alpha * PAIR_ALPHA_SHARE
    pairs, best, problem = pair_step(sel.problem, sel.fit, tested, r, alpha=level, ln_n=ln_n, k_folds=k_folds)
    sel, step = dataclasses.replace(sel, problem=problem), dataclasses.replace(step, pairs=tuple(pairs))
    if best is None:
        return sel, step, None
    status, _, gain = _verdict(best, sel.holdout, pose_groups(problem.data.q), alpha)
    if status is not None:
        step = dataclasses.replace(step, pairs=(dataclasses.replace(best, status=status), *step.pairs[1:]))
        return sel, step, None
    return sel, step, dataclasses.replace(best, holdout_gain=gain)


def _accept(
    sel: Selection, step: SelectionStep, t: CandidateTest | PairTest, before: float, **kw
) -> Selection:
    """Add the effects of ``t`` (one candidate, or a pair) to ``sel``: their evidence (a pair
    member's says ``added_with``), the fit, the backward step and the step's record."""
    ev = t.statistics()
    ev["holdout_rms_mm_with"] = ev.pop("holdout_rms_mm")
    ev.update({"step": step.step, "holdout_rms_mm_without": before})
    if t.holdout_gain is not None:
        ev["holdout_gain"] = t.holdout_gain.as_dict()
    evidence = dict(sel.evidence)
    for e in t.effects:
        with_ = [x.name for x in t.effects if x.name != e.name]
        evidence[e.name] = {**ev, "added_with": with_[0]} if with_ else ev
    sel = dataclasses.replace(sel, fit=t.fit, holdout=t.holdout, evidence=evidence)
    sel, removed = backward_step(sel, t.effects[-1], **kw)
    step = dataclasses.replace(step, added=tuple(e.name for e in t.effects), removed=tuple(removed))
    return dataclasses.replace(sel, steps=(*sel.steps, step))


def select_effects(
    prob: FitProblem,
    base: Fit,
    base_holdout: np.ndarray,
    cands: list[fx.Effect],
    *,
    sides: dict,
    alpha: float,
    k_folds: int,
    max_effects: int | None = None,
) -> Selection:
    """Stepwise selection of effects from ``cands`` on top of the geometric fit ``base``: each step
    adds the best significant candidate (or correlated pair) while it predicts the held-out poses
    better by more than its uncertainty (:func:`.fit.held_out_gain`); why it stopped is ``Selection.stop``.

    Args:
        prob, base, base_holdout: the fit problem, the geometric fit and its held-out residuals.
        cands: the candidate effects.
        sides: ``{joint: (K, n)}`` candidate sides of each backlash whose side the masses leave
            uncertain (:func:`~kpioed_drake.diagnosis.sides.side_patterns`; row 0 the problem's).
        alpha, k_folds: the family-wise level of a step and the folds of the held-out error.
        max_effects: the most effects to add (None: as many as the data support).
    """
    sel = Selection(problem=prob, fit=base, holdout=base_holdout)
    kw = {"alpha": alpha, "ln_n": np.log(3 * prob.data.n), "k_folds": k_folds}
    groups = pose_groups(prob.data.q)
    limit = len(cands) if max_effects is None else int(max_effects)
    number = 0
    while True:
        number += 1
        in_model = {e.name for e in sel.fit.effects}
        pool = [c for c in cands if c.name not in in_model]
        if len(sel.fit.effects) >= limit:
            return dataclasses.replace(sel, stop=stop_reason("max_effects" if pool else "no_candidate"))
        if not pool:
            return dataclasses.replace(sel, stop=stop_reason("no_candidate"))
        tests, best, problem = _test_step(sel.problem, sel.fit, pool, sides, **kw)
        sel = dataclasses.replace(sel, problem=problem)
        before = rms(sel.holdout)
        accepted, stop = None, _no_best_reason(tests) if best is None else None
        if best is not None:
            status, stand_in, gain = _verdict(tests[best], sel.holdout, groups, alpha)
            if status is None:
                accepted = dataclasses.replace(tests[best], holdout_gain=gain)
            else:
                tests[best] = dataclasses.replace(tests[best], status=status)
                sel = dataclasses.replace(sel, stand_ins=sel.stand_ins + ((stand_in,) if stand_in else ()))
                stop = stop_reason(
                    "stand_in" if stand_in else "no_holdout_gain", f"{tests[best].effect.name}: {gain.text()}"
                )
        step = SelectionStep(
            number, candidates=tuple(tests), holdout_rms_mm_before=before, chi2_before=sel.fit.cost
        )
        if accepted is None and len(sel.fit.effects) + 2 <= limit:
            sel, step, accepted = _pair(sel, tests, sides, step, **kw)
        if accepted is None:
            return dataclasses.replace(sel, steps=(*sel.steps, step), stop=stop)
        sel = _accept(sel, step, accepted, before, **kw)


def _no_best_reason(tests) -> dict:
    """Why a step found no significant candidate: all absorbed, or none significant."""
    if all(t.status == ABSORBED for t in tests):
        return stop_reason("identifiability", f"{len(tests)} candidates")
    absorbed = sum(t.status == ABSORBED for t in tests)
    return stop_reason(
        "not_significant", f"{len(tests) - absorbed} tested, {absorbed} absorbed" if absorbed else ""
    )
