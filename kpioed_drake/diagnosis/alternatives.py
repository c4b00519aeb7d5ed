"""Competing explanations: candidates that explain the data about as well as a named cause.

For a cause A of the extended model (the other named causes R): ``f0`` is the fit of R alone, and
for every candidate B not in the model ``LR_B = chi2(R) - chi2(R + B)`` against
``LR_A = chi2(R) - chi2(R + A)`` (both refitted jointly with the geometry). B is an *alternative* to
A when ``LR_B >= LR_A - c`` with ``c = chi2.isf(alpha, k_A)`` (the critical value at the test level
with A's number of parameters: 6.63 for one, 9.21 for two at 1 %): if B is the truth,
``LR_A - LR_B`` is at most ``LR(A | B) ~ chi2(k_A)``, so a likelihood-ratio test of A against B
cannot reject B at that level, the data cannot tell them apart; and B itself is significant
(``p(LR_B) < alpha``, uncorrected). The margin takes A's degrees of freedom: with one for every A,
a true B beside a two-parameter cause would be dropped more often than ``alpha``. Only B
whose score statistic (the linearised ``LR_B`` at ``f0``, cheap) comes within
``c + max(c, 20 % of LR_A)`` of ``LR_A`` are refitted.

The stepwise search adds causes one at a time, so with the other causes in the model a candidate
may explain the data *better* than a cause chosen earlier: when ``LR_B - LR_A > chi2.isf(alpha,
k_B)`` (if A is the truth, ``LR_B - LR_A <= LR(B | A) ~ chi2(k_B)``) and B also wins
by the penalised likelihood (``LR - k ln(3 n)``) and the held-out RMS, and B's value is physically
plausible (:mod:`.physical`), :func:`settle` swaps B in for A (recorded as a step with ``swapped``)
and looks again, at most ``MAX_EFFECTS`` swaps.

A *nested* alternative (``evidence.nested``) explains less than A alone (``LR_B < LR_A - c``) but is
significant alone and lies within A's signature: beside every cause, no direction of its weighted
columns keeps more than ``NESTED_REMAINING`` (10 %) outside the span of the causes and the geometry
(``remaining_given_causes``), and at most ``NESTED_SHARE`` (1/3) of what it keeps beside the
other causes alone (it is A that holds B).
The data cannot tell whether B is present as well as A (e.g. a gear-ratio error of joint 2 within a
first-harmonic gear error of joint 2 when joint 2 turns over part of a circle): B's own
non-centrality beside A is at most 1 % of its signal.

Evidence of each alternative: ``lr_stat`` (``LR_B``), ``lr_stat_cause`` (``LR_A``), ``dof``,
``delta_bic`` (``LR_B - k ln(3 n)``), ``holdout_rms_mm`` (K-fold, the model R + B), and
``canonical_correlation`` (largest canonical correlation between A's and B's columns after projecting
out the geometry and R: near 1 when the poses make the two signatures alike).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake.diagnosis.common import MAX_ALTERNATIVES, MAX_EFFECTS, NESTED_REMAINING, NESTED_SHARE
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.records import Alternative, Cause, Selection, SelectionStep, Swap
from kpioed_drake.diagnosis.selection import columns
from kpioed_drake.effects.physical import plausibility
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.identifiability import identifiability, projected_basis


def _outside(Q: np.ndarray, C: np.ndarray) -> float:
    """Largest fraction of the columns C (m, k) outside the span of the orthonormal Q: the largest
    singular value of C's orthonormal basis after projecting out Q (0: all of C inside)."""
    Qc, _ = np.linalg.qr(C / np.linalg.norm(C, axis=0))
    return float(np.linalg.svd(Qc - Q @ (Q.T @ Qc), compute_uv=False).max())


def _nested(outside: float, Q0: np.ndarray, C0: np.ndarray) -> bool:
    """Whether B lies within A's signature: beside every cause no direction of B keeps more than
    ``NESTED_REMAINING`` outside (``outside``, :func:`_outside` at the extended fit), and at most
    ``NESTED_SHARE`` of what it keeps beside the other causes alone (``Q0``, B's columns ``C0`` at
    their fit): it is A that holds B (B's non-centrality beside A is at most ``NESTED_SHARE^2`` of
    its non-centrality beside the others)."""
    return outside < NESTED_REMAINING and outside <= NESTED_SHARE * _outside(Q0, C0)


def competing(
    prob: FitProblem, ext: Fit, i: int, f0: Fit, pool, *, alpha: float, k_folds: int
) -> list[tuple[object, Fit, dict]]:
    """The alternatives to cause ``i`` of ``ext`` among the candidates ``pool``.

    Args:
        prob: the fit problem.
        ext: the extended model's fit; its effect ``i`` is the cause A.
        i: index of A in ``ext.effects``.
        f0: the fit of ``ext``'s other effects without A (started from ``ext``).
        pool: the candidate effects (those already in ``ext`` are skipped).
        alpha: the test level; k_folds: folds of the held-out error.

    Returns:
        Up to ``MAX_ALTERNATIVES`` tuples ``(effect B with its fitted values, fit of R + B, evidence)``,
        largest ``LR_B`` first.
    """
    a = ext.effects[i]
    lr_a = max(f0.cost - ext.cost, 0.0)
    # if B is the truth, LR_A - LR_B <= LR(A | B) ~ chi2(k_A): the margin has A's degrees of freedom
    c = float(scipy.stats.chi2.isf(alpha, a.n_params))
    in_model = {e.name for e in ext.effects}
    others = [b for b in pool if b.name not in in_model]
    if not others:
        return []
    Jm, cols = columns(prob, f0, [a] + others)
    Q, _ = np.linalg.qr(Jm)
    r = (f0.residuals / prob.sigma).reshape(-1)
    U_a = projected_basis(Q, cols[0])
    ln_n = np.log(3 * prob.data.n)
    beside: dict = {}  # B's columns beside every cause, built at the first nested check

    def outside_causes(b) -> float:
        """How much of B stays outside the causes' and the geometry's span (:func:`_outside`)."""
        if not beside:
            Jx, cols_x = columns(prob, ext, others)
            Qx, _ = np.linalg.qr(Jx)
            beside.update({e.name: _outside(Qx, Cx) for e, Cx in zip(others, cols_x, strict=True)})
        return beside[b.name]

    found = []
    for b, C in zip(others, cols[1:], strict=True):
        U_b = projected_basis(Q, C)
        if U_b.shape[1] == 0:
            continue
        proj = U_b.T @ r
        score = float(proj @ proj)
        nested = False
        if score < lr_a - c - max(c, 0.2 * lr_a):
            if score < 0.5 * scipy.stats.chi2.isf(alpha, b.n_params):
                continue
            nested = _nested(outside_causes(b), Q, C)
            if not nested:
                continue
        f = prob.fit(list(f0.effects) + [b], start=f0)
        lr_b = max(f0.cost - f.cost, 0.0)
        p_b = float(scipy.stats.chi2.sf(lr_b, b.n_params))
        if lr_b < lr_a - c and not nested:
            nested = _nested(outside_causes(b), Q, C)
        if p_b >= alpha or (lr_b < lr_a - c and not nested):
            continue
        corr = np.linalg.svd(U_a.T @ U_b, compute_uv=False) if U_a.shape[1] else np.zeros(1)
        ev = {
            "lr_stat": lr_b,
            "lr_stat_cause": lr_a,
            "dof": b.n_params,
            "p_value": p_b,
            "delta_bic": lr_b - b.n_params * ln_n,
            "canonical_correlation": float(min(1.0, corr.max())),
        }
        if lr_b < lr_a - c:  # B explains less than A, but all of it lies within A's signature
            ev["nested"] = True
            ev["remaining_given_causes"] = outside_causes(b)
        found.append((f.effects[-1], f, ev))
    found.sort(key=lambda t: -t[2]["lr_stat"])
    found = found[:MAX_ALTERNATIVES]
    for _, f, ev in found:
        ev["holdout_rms_mm"] = rms(prob.holdout(f, k=k_folds))
    return found


def _swap_evidence(prob: FitProblem, f0: Fit, b, fb: Fit, ev: dict, hold, m: int, replaced: str) -> dict:
    """Evidence of a cause B swapped in for ``replaced`` (the keys of a selection step's evidence)."""
    Jm, (C,) = columns(prob, f0, [b])
    return {
        **identifiability(Jm, C),
        "lr_stat": ev["lr_stat"],
        "dof": ev["dof"],
        "p_value": ev["p_value"],
        "p_value_corrected": min(1.0, ev["p_value"] * m),
        "delta_bic": ev["delta_bic"],
        "holdout_rms_mm_with": rms(hold),
        "holdout_rms_mm_without": rms(prob.holdout(f0)),
        "step": "swap",
        "replaced": replaced,
    }


def _plausible(prob: FitProblem, b, fb: Fit) -> bool:
    """Whether the value of B (the last effect of ``fb``) is physically plausible."""
    return plausibility(b, _last_std(fb, b), tau=prob.tau, time_s=prob.data.time_s)[0]


def _last_std(fit: Fit, e) -> np.ndarray:
    """Standard deviations of the values of ``e``, the last effect of ``fit`` (internal units)."""
    return np.sqrt(np.clip(np.diag(fit.Cp), 0, None))[fit.layout.effects][-e.n_params :]


def _swap(sel: Selection, a, f0: Fit, b, fb: Fit, ev: dict, pool, *, k_folds: int) -> Selection:
    """``sel`` with cause ``a`` swapped for ``b`` (fit ``fb``, competing evidence ``ev``; ``f0`` the
    fit without ``a``), recorded as a step."""
    prob, ext = sel.problem, sel.fit
    hold = prob.holdout(fb, k=k_folds)
    m = len([x for x in pool if x.name not in {e.name for e in ext.effects}])
    evidence = dict(sel.evidence)
    evidence.pop(a.name, None)
    evidence[b.name] = _swap_evidence(prob, f0, b, fb, ev, hold, max(m, 1), a.name)
    swap = Swap(replaced=a.name, by=b.name, lr_stat=ev["lr_stat"], lr_stat_replaced=ev["lr_stat_cause"])
    step = SelectionStep(len(sel.steps) + 1, added=(b.name,), removed=(a.name,), swap=swap)
    return dataclasses.replace(
        sel, fit=fb, holdout=hold, evidence=evidence, swaps=(*sel.swaps, swap), steps=(*sel.steps, step)
    )


def settle(sel: Selection, pool, *, alpha: float, k_folds: int) -> tuple[Selection, dict]:
    """Swap causes for competing candidates that explain the data significantly better given the
    other causes.

    Returns:
        (selection, settled): the selection after the swaps and, per final cause's name,
        ``(f0, alternatives)``: the fit without the cause and :func:`competing`'s list.
    """
    prob = sel.problem
    ln_n = np.log(3 * prob.data.n)
    for _ in range(MAX_EFFECTS + 1):
        ext, out, swap = sel.fit, {}, None
        for i, a in enumerate(ext.effects):
            f0 = prob.fit([x for x in ext.effects if x.name != a.name], start=ext)
            found = competing(prob, ext, i, f0, pool, alpha=alpha, k_folds=k_folds)
            lr_a = max(f0.cost - ext.cost, 0.0)
            if found and len(sel.swaps) < MAX_EFFECTS:
                ev = found[0][2]
                c = float(scipy.stats.chi2.isf(alpha, ev["dof"]))  # if A is the truth: LR(B | A) ~ chi2(k_B)
                better = ev["lr_stat"] - lr_a > c and ev["delta_bic"] > lr_a - a.n_params * ln_n
                if better and ev["holdout_rms_mm"] < rms(sel.holdout) and _plausible(prob, *found[0][:2]):
                    swap = (a, f0, *found[0])
                    break
            out[a.name] = (f0, found)
        if swap is None:
            return sel, out
        sel = _swap(sel, *swap, pool, k_folds=k_folds)
    return sel, out


def name_causes(sel: Selection, settled: dict, more: dict) -> tuple[Cause, ...]:
    """The effects of the extended model as causes: values and standard deviations (display units),
    the evidence (the step's statistics, the final LR given all other effects, the size at the
    reflector), plausibility (:mod:`~kpioed_drake.effects.physical`) and the alternatives: those of
    ``settled`` (:func:`settle`'s) and then ``more`` (``{name: [Alternative]}``)."""
    prob, ext = sel.problem, sel.fit
    std = np.sqrt(np.clip(np.diag(ext.Cp), 0, None))
    out, c = [], ext.layout.effects.start
    for i, e in enumerate(ext.effects):
        e_std = std[c : c + e.n_params]
        c += e.n_params
        sig = prob.effect_signal(ext, i)
        f0, found = settled[e.name]
        ev = {
            **sel.evidence.get(e.name, {}),
            "lr_stat_final": max(f0.cost - ext.cost, 0.0),  # given all others (refitted without it)
            "tool_max_mm": float(np.max(np.linalg.norm(sig, axis=1))),
            "tool_rms_mm": float(np.sqrt(np.mean(np.sum(sig**2, axis=1)))),
        }
        alts = []
        for b, fb, ev_b in found:
            ok, why = plausibility(b, _last_std(fb, b), tau=prob.tau, time_s=prob.data.time_s)
            alts.append(Alternative(effect=b, evidence=ev_b, plausible=ok, plausible_reason=why))
        ok, why = plausibility(e, e_std, tau=prob.tau, time_s=prob.data.time_s)
        out.append(
            Cause(
                effect=e,
                std=tuple(e.display_values(e_std)),
                evidence=ev,
                plausible=ok,
                plausible_reason=why,
                alternatives=(*alts, *more.get(e.name, ())),
            )
        )
    return tuple(out)
