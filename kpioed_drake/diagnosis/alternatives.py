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
``c + max(c, 20 % of LR_A)`` of ``LR_A`` are refitted, the best-scoring ``MAX_ALTERNATIVES +
REFIT_MARGIN`` of them (and as many nested ones).

The stepwise search adds causes one at a time, so with the other causes in the model a candidate
may explain the data *better* than a cause chosen earlier: when ``LR_B - LR_A > chi2.isf(alpha,
k_B)`` (if A is the truth, ``LR_B - LR_A <= LR(B | A) ~ chi2(k_B)``) and B also wins
by the penalised likelihood (``LR - k ln(3 n)``) and the held-out RMS, and B's value is physically
plausible (:mod:`.physical`), :func:`settle` swaps B in for A (recorded as a step with ``swapped``)
and looks again, at most ``MAX_SWAPS`` swaps (a round looks at the causes in order and ends at its
first swap: the causes after it are looked at with the swapped model).

A *nested* alternative (``evidence.nested``) explains less than A alone (``LR_B < LR_A - c``) but is
significant alone and lies within A's signature: beside every cause, no direction of its weighted
columns keeps more than ``NESTED_REMAINING`` (10 %) outside the span of the causes and the geometry
(``remaining_given_causes``), and at most ``NESTED_SHARE`` (1/3) of what it keeps beside the
other causes alone (it is A that holds B).
The data cannot tell whether B is present as well as A (e.g. a gear-ratio error of joint 2 within a
first-harmonic gear error of joint 2 when joint 2 turns over part of a circle): B's own
non-centrality beside A is at most 1 % of its signal.

Evidence of each alternative: ``lr_stat`` (``LR_B``), ``lr_stat_cause`` (``LR_A``), ``dof``,
``delta_bic`` (``LR_B - k ln(3 n)``), ``holdout_rms_mm`` (K-fold, the model R + B; computed only for
the alternatives a swap test or a cause's record asks for, :func:`held_out`), and
``canonical_correlation`` (largest canonical correlation between A's and B's columns after projecting
out the geometry and R: near 1 when the poses make the two signatures alike).

:func:`replace_implausible`: a named cause with an implausible value is replaced by its best
plausible alternative; after a first replacement the next cause's alternatives are searched again
beside the causes as they then are (the ones :func:`settle` found were beside the replaced cause).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.stats

from kpioed_drake.diagnosis.elastic_basis import basis_size
from kpioed_drake.diagnosis.fit import Fit, FitProblem, independent, ordered
from kpioed_drake.diagnosis.options import (
    K_FOLDS,
    MAX_ALTERNATIVES,
    MAX_SWAPS,
    NESTED_REMAINING,
    NESTED_SHARE,
)
from kpioed_drake.diagnosis.records import Alternative, Cause, Selection, SelectionStep, Swap
from kpioed_drake.diagnosis.selection import columns
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.model import Effect
from kpioed_drake.effects.physical import plausibility
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.identifiability import identifiability, projected_basis

ALTERNATIVE_MAX_ITER = 25
"""Levenberg-Marquardt iterations of an alternative's refit from the fit without the cause (most take
4-6; the few that crawl along a direction the geometry nearly takes took 100 each; on the two-arm
stand-in those that reach the cap, lateral bases, are still descending there, and 100 iterations
give the same named causes and alternatives: docs/diagnosis-structure.md)."""
REFIT_MARGIN = 2
"""Candidates refitted beyond the alternatives a cause lists (:data:`MAX_ALTERNATIVES`), by score."""


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


class _Beside:
    """How much of each candidate B stays outside the causes' and the geometry's span
    (:func:`_outside` beside every cause of ``ext``), built at the first nested check."""

    def __init__(self, prob: FitProblem, ext: Fit, others: list) -> None:
        self.prob, self.ext, self.others, self.outside = prob, ext, others, {}

    def __call__(self, b) -> float:
        if not self.outside:
            Jx, cols_x = columns(self.prob, self.ext, self.others)
            Qx, _ = np.linalg.qr(Jx)
            self.outside.update({e.name: _outside(Qx, Cx) for e, Cx in zip(self.others, cols_x, strict=True)})
        return self.outside[b.name]


def _screen(
    Q: np.ndarray,
    r: np.ndarray,
    others: list,
    cols: list,
    lr_a: float,
    c: float,
    alpha: float,
    beside: _Beside,
) -> list[tuple]:
    """The candidates worth a refit, ``(score, b, C, U_b, nested)`` (score: the linearised ``LR_B``):
    those within ``c + max(c, 20 % of LR_A)`` of ``LR_A``, or nested ones of a fair score; the best
    ``MAX_ALTERNATIVES + REFIT_MARGIN`` of each kind, best first."""
    screened = []
    for b, C in zip(others, cols, strict=True):
        U_b = projected_basis(Q, C)
        if U_b.shape[1] == 0:
            continue
        proj = U_b.T @ r
        score = float(proj @ proj)
        nested = False
        if score < lr_a - c - max(c, 0.2 * lr_a):
            if score < 0.5 * scipy.stats.chi2.isf(alpha, b.n_params):
                continue
            nested = _nested(beside(b), Q, C)
            if not nested:
                continue
        screened.append((score, b, C, U_b, nested))
    # the refits: the best-scoring REFIT_MARGIN more than are listed, of each kind (the score is the
    # linearised LR_B, close to the refitted one)
    screened.sort(key=lambda t: -t[0])
    keep = [t for t in screened if not t[4]][: MAX_ALTERNATIVES + REFIT_MARGIN]
    return keep + [t for t in screened if t[4]][: MAX_ALTERNATIVES + REFIT_MARGIN]


def _refit(
    prob: FitProblem,
    f0: Fit,
    cand: tuple,
    U_a: np.ndarray,
    Q: np.ndarray,
    lr_a: float,
    c: float,
    *,
    alpha: float,
    beside: _Beside,
) -> tuple[object, Fit, dict] | None:
    """A screened candidate ``cand`` (:func:`_screen`'s) refitted beside ``f0``: ``(B with its fitted
    values, fit of R + B, evidence)``, or None when B is no alternative."""
    _, b, C, U_b, nested = cand
    f = prob.fit(list(f0.effects) + [b], start=f0, max_iter=ALTERNATIVE_MAX_ITER)
    lr_b = max(f0.cost - f.cost, 0.0)
    p_b = float(scipy.stats.chi2.sf(lr_b, b.n_params))
    if lr_b < lr_a - c and not nested:
        nested = _nested(beside(b), Q, C)
    if p_b >= alpha or (lr_b < lr_a - c and not nested):
        return None
    corr = np.linalg.svd(U_a.T @ U_b, compute_uv=False) if U_a.shape[1] else np.zeros(1)
    ev = {
        "lr_stat": lr_b,
        "lr_stat_cause": lr_a,
        "dof": b.n_params,
        "p_value": p_b,
        "delta_bic": lr_b - b.n_params * np.log(3 * prob.data.n),
        "canonical_correlation": float(min(1.0, corr.max())),
    }
    if lr_b < lr_a - c:  # B explains less than A, but all of it lies within A's signature
        ev["nested"] = True
        ev["remaining_given_causes"] = beside(b)
    return f.effects[-1], f, ev


def competing(
    prob: FitProblem, ext: Fit, i: int, f0: Fit, pool: Sequence, *, alpha: float, beside=None
) -> list[tuple[object, Fit, dict]]:
    """The alternatives to cause ``i`` of ``ext`` among the candidates ``pool``.

    Args:
        prob: the fit problem.
        ext: the extended model's fit; its effect ``i`` is the cause A.
        i: index of A in ``ext.effects``.
        f0: the fit of ``ext``'s other effects without A (started from ``ext``).
        pool: the candidate effects (those already in ``ext`` are skipped).
        alpha: the test level.
        beside: the :class:`_Beside` of ``ext`` and the candidates not in it, shared by its causes
            (computed once); None: made here.

    Returns:
        Up to ``MAX_ALTERNATIVES`` tuples ``(effect B with its fitted values, fit of R + B, evidence)``,
        largest ``LR_B`` first; the evidence's ``holdout_rms_mm`` is added by :func:`held_out`.
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
    beside = _Beside(prob, ext, others) if beside is None else beside
    keep = _screen(Q, r, others, cols[1:], lr_a, c, alpha, beside)
    found = [_refit(prob, f0, t, U_a, Q, lr_a, c, alpha=alpha, beside=beside) for t in keep]
    return sorted((t for t in found if t is not None), key=lambda t: -t[2]["lr_stat"])[:MAX_ALTERNATIVES]


def held_out(prob: FitProblem, fit: Fit, ev: dict, *, k_folds: int) -> float:
    """``ev["holdout_rms_mm"]``, the K-fold held-out RMS of an alternative's model R + B (``fit``) [mm],
    computed at the first ask (the swap test of :func:`settle`, the causes' records of
    :func:`name_causes`): a round that ends at a swap, or whose causes are replaced, never asks for
    most of them."""
    if "holdout_rms_mm" not in ev:
        ev["holdout_rms_mm"] = rms(prob.holdout(fit, k=k_folds))
    return ev["holdout_rms_mm"]


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
    return judged(prob, fb, len(fb.effects) - 1)[0]


def judged(prob: FitProblem, fit: Fit, i: int) -> tuple[bool, str | None]:
    """:func:`~kpioed_drake.effects.physical.plausibility` of effect ``i`` of ``fit``: the bounds of
    its joint's drive, a mass-free basis by the rotation it causes (:func:`~.elastic_basis.basis_size`)."""
    e = fit.effects[i]
    c = fit.layout.effects.start + sum(x.n_params for x in fit.effects[:i])
    cov = fit.Cp[c : c + e.n_params, c : c + e.n_params]
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    size = basis_size(prob, fit, i, cov) if e.family in (gb.FAMILY, lb.FAMILY) else None
    return plausibility(e, std, tau=prob.tau, time_s=prob.data.time_s, robot=prob.robot, size=size)


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


def settle(sel: Selection, pool: Sequence[Effect], *, alpha: float, k_folds: int) -> tuple[Selection, dict]:
    """Swap causes for competing candidates that explain the data significantly better given the
    other causes.

    Returns:
        (selection, settled): the selection after the swaps and, per final cause's name,
        ``(f0, alternatives)``: the fit without the cause and :func:`competing`'s list (their held-out
        RMS as :func:`held_out` adds it).
    """
    prob = sel.problem
    ln_n = np.log(3 * prob.data.n)

    def better(a: Effect, f0: Fit, ext: Fit, found: list) -> bool:
        """Whether the best alternative B explains the data significantly better than A (LR and BIC);
        then its held-out RMS is computed (in the worker that found it)."""
        if not found or len(sel.swaps) >= MAX_SWAPS:
            return False
        lr_a, (_, fb, ev) = max(f0.cost - ext.cost, 0.0), found[0]
        c = float(scipy.stats.chi2.isf(alpha, ev["dof"]))  # if A is the truth: LR(B | A) ~ chi2(k_B)
        if not (ev["lr_stat"] - lr_a > c and ev["delta_bic"] > lr_a - a.n_params * ln_n):
            return False
        held_out(prob, fb, ev, k_folds=k_folds)  # the swap test's next question, asked here
        return True

    for _ in range(MAX_SWAPS + 1):
        ext, out, swap = sel.fit, {}, None
        # what the candidates keep beside all causes: the same for every cause, computed once
        beside = _Beside(prob, ext, [b for b in pool if b.name not in {e.name for e in ext.effects}])

        def alternatives(i: int, ext=ext, beside=beside) -> tuple[Fit, list, bool]:
            f0 = prob.fit([x for j, x in enumerate(ext.effects) if j != i], start=ext)
            found = competing(prob, ext, i, f0, pool, alpha=alpha, beside=beside)
            return f0, found, better(ext.effects[i], f0, ext, found)

        # each cause's in order (workers running ahead): a swap ends the round, the causes after it
        # are looked at again in the next one
        with ordered(alternatives, len(ext.effects), size=ext.J.size) as every:
            for a, (f0, found, wins) in zip(ext.effects, every, strict=False):
                if wins and found[0][2]["holdout_rms_mm"] < rms(sel.holdout):
                    if _plausible(prob, *found[0][:2]):
                        swap = (a, f0, *found[0])
                        break
                out[a.name] = (f0, found)
        if swap is None:
            return sel, out
        sel = _swap(sel, *swap, pool, k_folds=k_folds)
    return sel, out


def _plausible_alternative(
    sel: Selection, i: int, pool: Sequence[Effect], *, alpha: float
) -> tuple[Fit, tuple | None]:
    """The fit without cause ``i`` of ``sel`` and its best plausible, not nested alternative beside
    the selection's other causes as they are now, or None."""
    prob, ext = sel.problem, sel.fit
    f0 = prob.fit([x for j, x in enumerate(ext.effects) if j != i], start=ext)
    found = competing(prob, ext, i, f0, pool, alpha=alpha)
    ok = (t for t in found if not t[2].get("nested") and _plausible(prob, t[0], t[1]))
    return f0, next(ok, None)


def replace_implausible(
    sel: Selection,
    causes: Sequence[Cause],
    settled: dict,
    pool: Sequence[Effect],
    *,
    alpha: float,
    k_folds: int,
) -> tuple[Selection, dict, list[str]]:
    """Each named cause whose value is implausible replaced by the effect it stands for: its best
    plausible alternative that explains the data as well (not a nested one), recorded as a swap
    step; then :func:`settle` again. A cause without such an alternative stays (the report says so).

    Returns:
        (selection, settled, notes): the selection after the replacements, :func:`settle`'s
        ``settled`` of it and one note per replacement.
    """
    notes: list[str] = []
    for c in causes:
        names = [e.name for e in sel.fit.effects]
        if c.plausible or c.effect.name not in names:
            continue
        if notes:  # an earlier replacement changed the model: the alternatives beside the causes now
            f0, best = _plausible_alternative(sel, names.index(c.effect.name), pool, alpha=alpha)
        else:
            f0, found = settled[c.effect.name]
            ok = {a.effect.name for a in c.alternatives if a.plausible and not a.evidence.get("nested")}
            best = next(((b, fb, ev) for b, fb, ev in found if b.name in ok), None)
        if best is None:
            continue
        a = sel.fit.effects[names.index(c.effect.name)]
        sel = _swap(sel, a, f0, *best, pool, k_folds=k_folds)
        notes.append(
            f"{a.name} is implausible ({c.plausible_reason}); replaced by {best[0].name}, which explains the "
            f"data as well (LR {best[2]['lr_stat']:.1f} against {best[2]['lr_stat_cause']:.1f}) with a "
            "plausible value: the effect it stood in for"
        )
    if notes:
        sel, settled = settle(sel, pool, alpha=alpha, k_folds=k_folds)
    return sel, settled, notes


def name_causes(sel: Selection, settled: dict, more: dict, *, k_folds: int = K_FOLDS) -> tuple[Cause, ...]:
    """The effects of the extended model as causes: values and standard deviations (display units),
    the evidence (the step's statistics, the final LR given all other effects, the size at the
    reflector), plausibility (:mod:`~kpioed_drake.effects.physical`) and the alternatives: those of
    ``settled`` (:func:`settle`'s, with their held-out RMS over ``k_folds`` folds) and then ``more``
    (``{name: [Alternative]}``)."""
    prob, ext = sel.problem, sel.fit
    std = np.sqrt(np.clip(np.diag(ext.Cp), 0, None))
    starts = np.cumsum([ext.layout.effects.start] + [e.n_params for e in ext.effects])

    def cause(i: int) -> Cause:
        e, sig = ext.effects[i], prob.effect_signal(ext, i)
        f0, found = settled[e.name]
        ev = {
            **sel.evidence.get(e.name, {}),
            "lr_stat_final": max(f0.cost - ext.cost, 0.0),  # given all others (refitted without it)
            "tool_max_mm": float(np.max(np.linalg.norm(sig, axis=1))),
            "tool_rms_mm": float(np.sqrt(np.mean(np.sum(sig**2, axis=1)))),
        }
        alts = []
        for b, fb, ev_b in found:
            held_out(prob, fb, ev_b, k_folds=k_folds)
            ok, why = judged(prob, fb, len(fb.effects) - 1)
            alts.append(Alternative(effect=b, evidence=ev_b, plausible=ok, plausible_reason=why))
        ok, why = judged(prob, ext, i)
        e_std = std[starts[i] : starts[i + 1]]
        alts += more.get(e.name, ())
        return Cause(e, tuple(e.display_values(e_std)), ev, ok, why, alternatives=tuple(alts))

    return tuple(independent(cause, len(ext.effects), size=ext.J.size))  # the causes at once
