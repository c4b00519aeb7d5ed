"""Naming the cause: candidate effects, their identifiability, score tests and stepwise selection.

- :func:`candidate_effects`: joint elasticity of the joints gravity loads (2..6 of a floor-mounted
  six-joint robot), gear errors of every joint with
  n in {1, 2}, thermal expansion if the temperature varies, tracker drift if the time does.
- :func:`identifiability`: the fraction of a candidate's columns outside the span of the current
  model's columns (``remaining``; 1 = orthogonal, 0 = absorbed) and the largest canonical
  correlation with them.
- :func:`score_tests`: the residual structure, ``r^T P r / sigma^2`` per candidate with P the
  projector on the part of its columns the model cannot absorb (chi^2 under "no effect").
- :func:`select_effects`: forward selection with the likelihood ratio against the known noise
  (``LR = chi^2_before - chi^2_after`` ~ chi^2(k), Bonferroni-corrected over the candidates tested
  in a step), BIC (``LR > k ln(3 n)``) and K-fold held-out error; after each addition every chosen
  effect is re-tested for removal (stepwise).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.common import MIN_REMAINING
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.estimation import rms
from kpioed_drake.measurements import Measurements

_VARIABLE = {
    "joint_elasticity": "gravity torque tau_{joint}",
    "gear_cyclic": "sin/cos({harmonic} q_{joint})",
    "thermal_expansion": "temperature x reflector position",
    "tracker_drift": "time",
}


def candidate_effects(data: Measurements, *, tau: np.ndarray | None = None) -> tuple[list, list[str]]:
    """The candidate extensions for this data and notes on the ones left out.

    Args:
        data: the measurements (n poses of nj joints).
        tau: (n, nj) gravity torques at the data's poses [N m]: joint j's elasticity is a candidate
            when gravity exerts a torque on it (a joint with a vertical axis has none, e.g. joint 1
            of a floor-mounted robot; a robot mounted sideways has one). None: joint 1 is taken
            for vertical (the floor-mounted six-joint robots).
    """
    notes = []
    nj = data.q.shape[1]
    if tau is None:
        loaded = np.arange(nj) > 0
    else:
        size = np.max(np.abs(tau), axis=0)
        loaded = size > 1e-9 * max(1.0, float(np.max(size)))
    cands = [fx.Effect("joint_elasticity", j + 1) for j in range(nj) if loaded[j]]
    for j in np.flatnonzero(~loaded):
        notes.append(
            f"joint_elasticity:{j + 1} is not a candidate: joint {j + 1} turns about a vertical axis, "
            "gravity exerts no torque on it"
        )
    cands += [fx.Effect("gear_cyclic", j, n) for j in range(1, nj + 1) for n in (1, 2)]
    if data.temperature_C is not None and np.ptp(data.temperature_C) > 0.5:
        cands.append(fx.Effect("thermal_expansion"))
    else:
        notes.append(
            "thermal_expansion is not a candidate: "
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


def _columns(prob: FitProblem, fit: Fit, cands) -> tuple[np.ndarray, list[np.ndarray]]:
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


def score_tests(prob: FitProblem, fit: Fit, cands) -> list:
    """Residual structure: score statistic of each candidate's columns against ``fit``'s residuals."""
    r = (fit.residuals / prob.sigma).reshape(-1)
    Jm, cols = _columns(prob, fit, cands)
    Q, _ = np.linalg.qr(Jm)
    out = []
    for e, C in zip(cands, cols, strict=True):
        Cp = C - Q @ (Q.T @ C)
        Qc, sv, _ = np.linalg.svd(Cp, full_matrices=False)
        keep = sv > 1e-9 * max(sv.max(), 1e-300)
        proj = Qc[:, keep].T @ r
        stat = float(proj @ proj)
        dof = int(keep.sum())
        out.append(
            {
                "candidate": e.name,
                "variable": _VARIABLE[e.family].format(joint=e.joint, harmonic=e.harmonic),
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
    """

    fit: Fit
    holdout: np.ndarray
    steps: list
    evidence: dict


def _public(row: dict) -> dict:
    return {k: v for k, v in row.items() if not k.startswith("_")}


def _test_step(prob: FitProblem, current: Fit, pool, *, alpha: float, ln_n: float, k_folds: int):
    """Identifiability, LR test and BIC of every candidate in ``pool``; held-out error of the
    significant ones. Returns the rows (in pool order) and the best significant (effect, row)."""
    Jm, cols = _columns(prob, current, pool)
    rows, tested = [], []
    for e, Jc in zip(pool, cols, strict=True):
        row = {"candidate": e.name, **identifiability(Jm, Jc)}
        rows.append(row)
        if row["remaining"] < MIN_REMAINING:
            row["status"] = "absorbed by the model's parameters (not identifiable from these poses)"
        else:
            tested.append((e, row))
    m = max(len(tested), 1)
    best = None
    for e, row in tested:
        f = prob.fit(list(current.effects) + [e], start=current)
        lr = max(current.cost - f.cost, 0.0)
        p = float(scipy.stats.chi2.sf(lr, e.n_params))
        row.update(
            {
                "lr_stat": lr,
                "dof": e.n_params,
                "p_value": p,
                "p_value_corrected": min(1.0, p * m),
                "delta_bic": lr - e.n_params * ln_n,
            }
        )
        if row["p_value_corrected"] < alpha and row["delta_bic"] > 0:
            row["_fit"] = f
            if best is None or row["delta_bic"] > best[1]["delta_bic"]:
                best = (e, row)
    # held-out error of the significant candidates (the expensive part)
    for _, row in tested:
        if "_fit" in row:
            row["_hold"] = prob.holdout(row["_fit"], k=k_folds)
            row["holdout_rms_mm"] = rms(row["_hold"])
    return rows, best


def _backward(prob: FitProblem, sel: Selection, added, *, alpha: float, ln_n: float, k_folds: int):
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
            if best[1]["holdout_rms_mm"] < before:
                accepted = best
            else:
                best[1]["status"] = "significant but does not lower the held-out error"
        rec = {
            "step": step,
            "holdout_rms_mm_before": before,
            "chi2_before": sel.fit.cost,
            "candidates": [_public(r) for r in rows],
        }
        if accepted is None:
            rec["added"] = None
            sel.steps.append(rec)
            break
        e, row = accepted
        rec["added"] = e.name
        ev = {k: v for k, v in _public(row).items() if k != "candidate"}
        ev["holdout_rms_mm_with"] = ev.pop("holdout_rms_mm")
        ev["step"] = step
        ev["holdout_rms_mm_without"] = before
        sel.evidence[e.key] = ev
        sel.fit, sel.holdout = row["_fit"], row["_hold"]
        removed = _backward(prob, sel, e, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
        if removed:
            rec["removed"] = removed
        sel.steps.append(rec)
    return sel
