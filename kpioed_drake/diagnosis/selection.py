"""Naming the cause: candidate effects, their identifiability, score tests and stepwise selection.

- :func:`candidate_effects`: joint elasticity of the joints gravity loads (2..6 of a floor-mounted
  six-joint robot), gear errors of every joint with n in {1, 2}, gear-ratio errors (joint scale)
  of every joint, the couplings of :data:`~kpioed_drake.diagnosis.common.COUPLING_PAIRS`, backlash
  of the joints whose gravity torque takes both signs, thermal expansion and tracker scale if the
  temperature varies, tracker drift if the time does.
- :func:`identifiability`: the fraction of a candidate's columns outside the span of the current
  model's columns (``remaining``; 1 = orthogonal, 0 = absorbed) and the largest canonical
  correlation with them.
- :func:`score_tests`: the residual structure, ``r^T P r / sigma^2`` per candidate with P the
  projector on the part of its columns the model cannot absorb (chi^2 under "no effect").
- :func:`select_effects`: forward selection with the likelihood ratio against the known noise
  (``LR = chi^2_before - chi^2_after`` ~ chi^2(k), its family-wise p-value over the candidates of a
  step by the weighted min-p method, :mod:`~kpioed_drake.estimation.multiplicity`; a backlash scored
  with every side its joint's torque may take under the mass prior, its sides weighted by
  :func:`~kpioed_drake.diagnosis.sides.side_weights`),
  BIC (``LR > k ln(3 n)``) and K-fold held-out error; after each addition every chosen effect is
  re-tested for removal (stepwise).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.common import (
    BACKLASH_MIN_SIDE,
    COUPLING_PAIRS,
    MIN_EXCESS_SHARE,
    MIN_HOLDOUT_GAIN,
    MIN_REMAINING,
    PAIR_ALPHA_SHARE,
)
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.pairs import pair_step
from kpioed_drake.diagnosis.sides import set_side, side_penalty, side_weights, unit_columns
from kpioed_drake.effects.compliance import candidates as compliance_candidates
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.multiplicity import adjusted_p, critical_p, min_p_null, normalized
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
}


def candidate_effects(
    data: Measurements, tau: np.ndarray | None = None, *, robot: Robot | None = None
) -> tuple[list, list[str]]:
    """The candidate extensions for this data and notes on the ones left out.

    Args:
        data: the measurements (n poses of nj joints).
        tau: (n, nj) gravity torques at the commanded angles [N m] (``FitProblem.tau``): the
            elasticity and backlash of joint j are candidates when gravity exerts a torque on it (a
            joint with a vertical axis has none, e.g. joint 1 of a floor-mounted robot; a robot
            mounted sideways has one). None: joint 1 is taken for vertical (the floor-mounted
            six-joint robots) and no backlash is a candidate.
        robot: the robot; with it, the compliance of a lifting column (a prismatic joint within 30
            deg of gravity that moves in the data) and of the base (a robot with such a column or
            ``compliant_base: true``) are candidates (:func:`~kpioed_drake.effects.compliance.candidates`).
    """
    notes = []
    nj = data.q.shape[1]
    if tau is None:
        loaded = np.arange(nj) > 0
    else:
        size = np.max(np.abs(tau), axis=0)
        loaded = size > 1e-9 * max(1.0, float(np.max(size)))
    cands = [fx.Effect("joint_elasticity", j + 1) for j in range(nj) if loaded[j]]
    for j in np.flatnonzero(~loaded) + 1:
        notes.append(
            f"joint_elasticity:{j} and backlash:{j} are not candidates: joint {j} turns about the vertical "
            "axis, gravity exerts no torque on it"
        )
    cands += [fx.Effect("gear_cyclic", j, n) for j in range(1, nj + 1) for n in (1, 2)]
    cands += [fx.Effect("joint_scale", j) for j in range(1, nj + 1)]
    cands += [fx.Effect("joint_coupling", i, coupled=j) for i, j in COUPLING_PAIRS if max(i, j) <= nj]
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
        notes.append(
            "thermal_expansion and tracker_scale are not candidates: "
            + (
                "no temperature_C column"
                if data.temperature_C is None
                else "the temperature varies by < 0.5 K"
            )
            + " (a constant temperature only rescales lengths, which the geometric parameters absorb)"
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


def identifiability(J_model: np.ndarray, J_cand: np.ndarray) -> dict:
    """How well candidate columns separate from the model's columns (both weighted, (m, .)).

    Returns ``remaining`` (smallest singular value of the candidate's orthonormalised columns after
    projecting out the model's span: 1 = orthogonal, 0 = absorbed), ``max_corr`` (largest canonical
    correlation with the model's columns, ``sqrt(1 - remaining^2)``) and ``condition`` (of the
    column-scaled joint matrix).
    """
    Q, _ = np.linalg.qr(J_model)
    Dc = np.linalg.norm(J_cand, axis=0)
    if np.any(Dc == 0):
        return {"remaining": 0.0, "max_corr": 1.0, "condition": float("inf")}
    Qc, _ = np.linalg.qr(J_cand / Dc)
    R = Qc - Q @ (Q.T @ Qc)
    sv = np.linalg.svd(R, compute_uv=False)
    remaining = float(sv.min())
    A = np.concatenate([J_model, J_cand], axis=1)
    D = np.linalg.norm(A, axis=0)
    D[D == 0] = 1.0
    s = np.linalg.svd(A / D, compute_uv=False)
    return {
        "remaining": remaining,
        "max_corr": float(np.sqrt(max(0.0, 1.0 - remaining**2))),
        "condition": float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
    }


def columns(prob: FitProblem, fit: Fit, cands) -> tuple[np.ndarray, list[np.ndarray]]:
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


def projected_basis(Q: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Orthonormal basis (m, <= k) of the part of the columns C (m, k) outside the span of the
    orthonormal Q (m, p): the directions in which a candidate moves the fit's residuals."""
    Cp = C - Q @ (Q.T @ C)
    Qc, sv, _ = np.linalg.svd(Cp, full_matrices=False)
    keep = sv > 1e-9 * max(sv.max(), 1e-300)
    return Qc[:, keep]


def score_tests(prob: FitProblem, fit: Fit, cands) -> list:
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


@dataclasses.dataclass
class Selection:
    """Outcome of :func:`select_effects`.

    Attributes:
        fit: the extended model's fit (the baseline if nothing was added).
        holdout: (n, 3) its held-out residuals [mm].
        steps: one record per step: the candidates' statistics, what was added and removed.
        evidence: per chosen effect's key, the statistics of the step that added it.
        stand_ins: significant candidates left unnamed because their held-out gain was negligible
            (:func:`_stand_in`) while the model still failed the goodness-of-fit test.
        swaps: causes replaced by a candidate that fits significantly better given the other causes
            (:func:`~kpioed_drake.diagnosis.alternatives.settle`).
    """

    fit: Fit
    holdout: np.ndarray
    steps: list
    evidence: dict
    stand_ins: list = dataclasses.field(default_factory=list)
    swaps: list = dataclasses.field(default_factory=list)


def _public(row: dict) -> dict:
    return {k: v for k, v in row.items() if not k.startswith("_")}


SCREEN_FRACTION = 0.5
"""A candidate is refitted only if its score statistic reaches this fraction of the critical value."""
SCREEN_MARGIN = 10.0
"""... and its penalised score is within max(this, 10 %) of the best penalised score."""


def _screen(tested, level, ln_n: float):
    """The candidates worth a full fit, by their score statistic (the linearised LR at the current
    fit, within 2e-4 (1 + LR) of the refitted LR on the KR 16 cases measured): those whose score
    reaches half the corrected critical value (``level(weight)``: the marginal p-value a candidate of
    that normalized weight needs) and whose penalised score ``score - k ln(3 n)`` is
    within ``max(SCREEN_MARGIN, 10 %)`` of the best one; the others are marked (no LR in their row)."""
    if not tested:
        return []
    pen = [row["score"] - e.n_params * ln_n for e, row in tested]
    top = max(pen)
    out = []
    for (e, row), p in zip(tested, pen, strict=True):
        crit = float(scipy.stats.chi2.isf(level(row["_weight"]), e.n_params))
        if row["score"] >= SCREEN_FRACTION * crit and p >= top - max(SCREEN_MARGIN, 0.1 * abs(top)):
            out.append((e, row))
        else:
            row["status"] = "not refitted: its score statistic (linearised LR) cannot make it the best"
    return out


def _test_step(prob: FitProblem, current: Fit, pool, *, alpha: float, ln_n: float, k_folds: int):
    """Identifiability and score statistic of every candidate in ``pool``, LR test and BIC of those
    the score screen keeps (:func:`_screen`), held-out error of the best significant one. Returns the
    rows (in pool order) and the best significant (effect, row)."""
    Jm, cols = columns(prob, current, pool)
    Q, _ = np.linalg.qr(Jm)
    r = (current.residuals / prob.sigma).reshape(-1)
    units = unit_columns(
        prob, current, [e.joint for e in pool if e.family == "backlash" and e.joint in prob.side_patterns]
    )
    rows, tested, bases, raw = [], [], [], []
    for e, Jc in zip(pool, cols, strict=True):
        row = {"candidate": e.name, **identifiability(Jm, Jc)}
        rows.append(row)
        if row["remaining"] < MIN_REMAINING:
            row["status"] = "absorbed by the model's parameters (not identifiable from these poses)"
            continue
        U = [projected_basis(Q, Jc)]
        if e.family == "backlash" and e.joint in units:  # every side the mass prior allows
            pats = prob.side_patterns[e.joint]
            g = units[e.joint].reshape(-1, 3)
            U = [projected_basis(Q, (g * s[:, None]).reshape(-1, 1)) for s in pats]
        keep = [i for i, u in enumerate(U) if u.shape[1]]
        if not keep:
            continue
        w = side_weights([U[i] for i in keep])  # a backlash: its expected side and the other sides
        scores = [float(np.sum((U[i].T @ r) ** 2)) for i in keep]
        best_i = int(np.argmax(scores))
        i = keep[best_i]
        row["score"] = scores[best_i]
        row["_basis"] = U[0]  # the pair step's: the current (expected) side, not one the residuals chose
        row["_index"] = len(bases) + best_i  # its best side's place among the step's bases
        if len(U) > 1:
            row["_side"] = pats[i]
            row["side_patterns"] = len(U)
            row["_side_bases"] = U
        tested.append((e, row))
        bases += [U[i] for i in keep]
        raw += list(w)
    m = max(len(bases), 1)
    weights = normalized(raw, len(raw)) if raw else np.ones(0)
    for _, row in tested:
        row["_weight"] = float(weights[row.pop("_index")])
    # the min-p law only where a candidate can be significant (its family-wise p-value is never below
    # its marginal one; the refitted LR is within 2e-4 (1 + LR) of the score): else Bonferroni's
    p_min = min((float(scipy.stats.chi2.sf(row["score"], e.n_params)) for e, row in tested), default=1.0)
    null = min_p_null(bases, weights=weights) if bases and p_min < 2 * alpha else None
    best = None
    saved_side = prob.conditions.side
    for e, row in _screen(tested, lambda w: critical_p(alpha, null, m, weight=w), ln_n):
        if "_side" in row:
            set_side(prob, e.joint, row["_side"])
        f = prob.fit(list(current.effects) + [e], start=current)
        prob.conditions = dataclasses.replace(prob.conditions, side=saved_side)
        lr = max(current.cost - f.cost, 0.0)
        p = float(scipy.stats.chi2.sf(lr, e.n_params))
        row.update(
            {
                "lr_stat": lr,
                "dof": e.n_params,
                "p_value": p,
                "p_value_corrected": adjusted_p(p, null, m, weight=row["_weight"]),
                "delta_bic": lr - e.n_params * ln_n,
            }
        )
        if "_side_bases" in row:  # the best of several sides: ranked as one test (2 ln of their number)
            row["side_penalty"] = side_penalty(row["_side_bases"])
            row["delta_bic"] -= row["side_penalty"]
        if row["p_value_corrected"] < alpha and row["delta_bic"] > 0:
            row["_fit"] = f
            if best is None or row["delta_bic"] > best[1]["delta_bic"]:
                best = (e, row)
    # held-out error of the best significant candidate only: the one the step may add (the others'
    # held-out errors would not change the decision, and they are the expensive part)
    if best is not None:
        if "_side" in best[1]:  # its backlash's side from now on
            set_side(prob, best[0].joint, best[1]["_side"])
        best[1]["_hold"] = prob.holdout(best[1]["_fit"], k=k_folds)
        best[1]["holdout_rms_mm"] = rms(best[1]["_hold"])
    return rows, best


def backward_step(prob: FitProblem, sel: Selection, added, *, alpha: float, ln_n: float, k_folds: int):
    """Remove every chosen effect (but the one just added) that no longer earns its place."""
    removed = []
    for old in list(sel.fit.effects):
        if old.key == added.key or len(sel.fit.effects) < 2:
            continue
        rest = [x for x in sel.fit.effects if x.key != old.key]
        f = prob.fit(rest, start=sel.fit)
        lr = max(f.cost - sel.fit.cost, 0.0)
        p = float(scipy.stats.chi2.sf(lr, old.n_params))
        if p >= alpha or lr - old.n_params * ln_n <= 0:
            sel.fit, sel.holdout = f, prob.holdout(f, k=k_folds)
            removed.append(old.name)
            sel.evidence.pop(old.key, None)
    return removed


def _stand_in(row: dict, before: float, sigma: float, alpha: float) -> str | None:
    """Why a significant candidate is a stand-in (not named), or None.

    A stand-in: the model with it still fails the goodness-of-fit test and it lowers the held-out
    RMS by less than ``MIN_HOLDOUT_GAIN`` or removes less than ``MIN_EXCESS_SHARE`` of the held-out
    mean square above the noise (``before^2 - sigma^2``): a small piece of an error outside the
    candidate list that the candidate's columns happen to fit.
    """
    f, after = row["_fit"], row["holdout_rms_mm"]
    if scipy.stats.chi2.sf(f.cost, f.dof) >= alpha:
        return None
    gain = 1.0 - after / before
    excess = before**2 - sigma**2
    share = (before**2 - after**2) / excess if excess > 0 else 1.0
    if gain >= MIN_HOLDOUT_GAIN and share >= MIN_EXCESS_SHARE:
        return None
    return (
        f"lowers the held-out RMS by {100 * gain:.1f} % and removes {100 * share:.0f} % of its excess "
        f"over the noise (named from {100 * MIN_HOLDOUT_GAIN:g} % and {100 * MIN_EXCESS_SHARE:g} %) while "
        "the model with it still fails the goodness-of-fit test"
    )


def _pair(
    prob: FitProblem, sel: Selection, pool, rows, rec: dict, *, alpha: float, ln_n: float, k_folds: int
):
    """After a step that added nothing: the joint test of correlated pairs (:func:`.pairs.pair_step`).
    Adds the accepted pair to ``sel`` (with ``rec``, the step's record, and the backward step) and
    returns it, else records the pairs in ``rec`` and returns None."""
    tested = [
        (e, row["_basis"], prob.side_patterns[e.joint][0] if "_side" in row else None)
        for e, row in zip(pool, rows, strict=True)
        if "_basis" in row
    ]
    r = (sel.fit.residuals / prob.sigma).reshape(-1)
    level = alpha * PAIR_ALPHA_SHARE
    pair_rows, best = pair_step(prob, sel.fit, tested, r, alpha=level, ln_n=ln_n, k_folds=k_folds)
    if pair_rows:
        rec["pairs"] = [_public(x) for x in pair_rows]
    if best is None:
        return None
    (a, b), row = best
    before = rms(sel.holdout)
    gain = 1.0 - row["holdout_rms_mm"] / before
    why = _stand_in(row, before, prob.sigma, alpha)
    if gain <= 0 or why:
        row["status"] = f"stand-in: {why}" if why else "significant but does not lower the held-out error"
        rec["pairs"][0] = _public(row)
        return None
    rec["added"] = f"{a.name} + {b.name}"
    rec["pair"] = [a.name, b.name]
    _accept(prob, sel, rec, row, (a, b), before, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
    return best


def _accept(prob: FitProblem, sel: Selection, rec: dict, row: dict, effects, before: float, **kw) -> None:
    """Add ``effects`` (one candidate, or a pair) to ``sel`` with the step's ``row``: their evidence
    (a pair member's says ``added_with``), the fit, the backward step and the step's record ``rec``."""
    ev = {k: v for k, v in _public(row).items() if k not in ("candidate", "pair")}
    ev["holdout_rms_mm_with"] = ev.pop("holdout_rms_mm")
    ev.update({"step": rec["step"], "holdout_rms_mm_without": before})
    for e in effects:
        with_ = [x.name for x in effects if x.key != e.key]
        sel.evidence[e.key] = {**ev, "added_with": with_[0]} if with_ else ev
    sel.fit, sel.holdout = row["_fit"], row["_hold"]
    removed = backward_step(prob, sel, effects[-1], **kw)
    if removed:
        rec["removed"] = removed
    sel.steps.append(rec)


def select_effects(
    prob: FitProblem, base: Fit, base_holdout, cands, *, alpha: float, k_folds: int, max_effects: int
) -> Selection:
    """Stepwise selection of effects from ``cands`` on top of the geometric fit ``base``."""
    sel = Selection(fit=base, holdout=base_holdout, steps=[], evidence={})
    ln_n = np.log(3 * prob.data.n)
    for step in range(1, max_effects + 1):
        pool = [c for c in cands if c.key not in {e.key for e in sel.fit.effects}]
        if not pool:
            break
        rows, best = _test_step(prob, sel.fit, pool, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
        before = rms(sel.holdout)
        accepted = None
        if best is not None:
            e_best, row = best
            gain = 1.0 - row["holdout_rms_mm"] / before
            why = _stand_in(row, before, prob.sigma, alpha)
            if gain <= 0:
                row["status"] = "significant but does not lower the held-out error"
            elif why:
                row["status"] = f"stand-in: {why}"
                sel.stand_ins.append(
                    {"candidate": e_best.name, "holdout_gain": gain, "lr_stat": row["lr_stat"], "reason": why}
                )
            else:
                accepted = best
        rec = {
            "step": step,
            "holdout_rms_mm_before": before,
            "chi2_before": sel.fit.cost,
            "candidates": [_public(r) for r in rows],
        }
        if accepted is None and len(sel.fit.effects) + 2 <= max_effects:
            accepted = _pair(prob, sel, pool, rows, rec, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
            if accepted is not None:
                continue
        if accepted is None:
            rec["added"] = None
            sel.steps.append(rec)
            break
        e, row = accepted
        rec["added"] = e.name
        _accept(prob, sel, rec, row, (e,), before, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
    return sel
