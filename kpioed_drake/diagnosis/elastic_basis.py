"""Elasticity without trusting the masses in the diagnosis: upgrade a named ``joint_elasticity:j``
to the gravity basis ``joint_elasticity_basis:j`` when the data show that the model file's masses
are wrong (:mod:`kpioed_drake.effects.gravity_basis`).

The selection names elasticity with the model file's torques (one parameter, the most powerful
test when the masses are right). Afterwards each named ``joint_elasticity:j`` is refitted with the
basis in its place (``r_j`` moments, plus the payload compliance when the payload varies), and
every other named effect is re-tested for removal (the selection's backward step: a stand-in for
the mass mismatch goes). The result replaces the model if it has a lower BIC
(``chi2 + k ln(3 n)``, k = effect parameters) and a lower held-out RMS. The cause is then
``joint_elasticity_basis:j``; its evidence gains the upgrade's statistics (``basis_upgrade``: the
likelihood ratio against the file's masses ``LR = chi2_elasticity - chi2_basis`` on
``n_basis - 1`` dof, the removed stand-ins) and the compliance against the file's torques
(:func:`~kpioed_drake.effects.gravity_basis.basis_compliance`). If the result is not better but
the backward step removed effects (the basis explains them together with the elasticity: e.g. a
``gear_cyclic:2:1`` that mimics the joint-2 torque of other masses), the data cannot tell "those
effects" from "other masses": each removed effect's cause gets the basis as an ``alternative``.
When the model then still fails the goodness-of-fit test, the basis of every joint without an
elasticity is a further candidate (:func:`_add_basis_if_unexplained`).

:func:`basis_size`: how far a fitted mass-free basis turns what its joint carries (the rotation a
plausibility bound judges, :mod:`~kpioed_drake.effects.physical`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.fit import Fit, FitProblem, independent
from kpioed_drake.diagnosis.options import BACKLASH_MIN_SIDE, MIN_REMAINING
from kpioed_drake.diagnosis.records import Alternative, Selection
from kpioed_drake.diagnosis.selection import backward_step, columns
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects.physical import BasisSize
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.estimation.identifiability import model_factors
from kpioed_drake.tracker.measurement import reflector_world


def basis_for(prob: FitProblem, joint: int) -> fx.Effect:
    """The ``joint_elasticity_basis:joint`` extension sized for this robot and data's payload."""
    return gb.resolve_basis(fx.Effect(gb.FAMILY, joint), prob.nominal, prob.data.payload_kg)


ABSORBED_MARGIN = 2.0
"""A basis direction is kept if it keeps this many times the selection's ``MIN_REMAINING`` outside
the model's span at the geometric fit (the columns move a little as effects are added)."""


def reduce_absorbed(
    prob: FitProblem, base: Fit, cands: list[fx.Effect], joints: Iterable[int] = ()
) -> tuple[FitProblem, list, list[str]]:
    """Drop from each gravity basis the deflections the geometric model absorbs on these poses.

    For every ``joint_elasticity_basis`` in ``cands`` (and the ``joints`` whose basis was sized on
    the data's poses), the basis's weighted columns at the geometric fit ``base`` (3 n, r), scaled
    to unit norm, are projected off the span of the model's columns; the right singular vectors
    whose singular value is below :data:`~kpioed_drake.diagnosis.options.MIN_REMAINING` (the
    selection's "absorbed") are dropped, the rest orthonormalised in moment space and made the
    joint's basis of the problem's robot (:func:`~kpioed_drake.effects.gravity_basis.store_basis`).
    A direction the joint offsets and frame rotations reproduce (e.g. a torque that depends only on
    a joint moving with the deflected one) would otherwise make the whole basis "absorbed"
    or the fit singular.

    Returns:
        (prob, cands, notes): the problem with the reduced bases, the candidates with their bases
        resized, one note per reduced joint.
    """
    todo = sorted({e.joint for e in cands if e.family == gb.FAMILY} | set(joints))
    notes, sizes = [], {}
    for j in todo:
        jb = gb.joint_basis(prob.robot, j)
        if jb.rank == 0:
            continue
        b = dataclasses.replace(fx.Effect(gb.FAMILY, j), n_basis=jb.rank)
        Jm, (C,) = columns(prob, base, [b])
        Q = model_factors(Jm)[0]
        nc = np.linalg.norm(C, axis=0)
        nc[nc == 0] = 1.0
        Qc, Rc = np.linalg.qr(C / nc)
        _, sv, Wt = np.linalg.svd(Qc - Q @ (Q.T @ Qc), full_matrices=False)
        keep = sv >= ABSORBED_MARGIN * MIN_REMAINING
        if keep.all():
            continue
        theta = np.linalg.solve(Rc, Wt[keep].T) / nc[:, None]  # (r, kept): Qc W = C theta
        V = np.linalg.qr(jb.V @ theta)[0] if keep.any() else jb.V[:, :0]
        prob = prob.with_robot(gb.store_basis(prob.robot, j, jb.D, V))
        sizes[j] = V.shape[1]
        notes.append(
            f"joint_elasticity_basis:{j}: {jb.rank - V.shape[1]} of its {jb.rank} moment combinations "
            "deflect the reflector as the geometric parameters do at these poses (absorbed); "
            f"{V.shape[1]} kept"
        )
    varies = int(gb.payload_varies(prob.data.payload_kg))
    out = []
    for e in cands:
        if e.family == gb.FAMILY and e.joint in sizes:
            if sizes[e.joint] == 0:
                continue
            e = dataclasses.replace(e, n_basis=sizes[e.joint] + varies)
        out.append(e)
    return prob, out, notes


def _bic(fit) -> float:
    """chi2 plus the BIC penalty of the effect parameters, ``k ln(3 n)``."""
    return fit.cost + fit.k * np.log(fit.residuals.size)


def _upgradable(prob: FitProblem, e) -> bool:
    """A named elasticity, or a named backlash of a joint gravity loads (a large elasticity whose
    torque the file's masses get wrong can pass for a backlash with a side chosen from the mass
    prior, :mod:`~kpioed_drake.diagnosis.sides`)."""
    if e.family == "joint_elasticity":
        return True
    return e.family == "backlash" and gb.joint_basis(prob.robot, e.joint).rank > 0


def _mass_alternative(b: fx.Effect, evidence: dict) -> Alternative:
    """The gravity basis ``b`` as a competing explanation (the cause with other link masses)."""
    return Alternative(effect=b, evidence=evidence)


def _upgrade_one(sel: Selection, e, *, alpha: float, k_folds: int, ln_n: float):
    """The upgrade of one named effect ``e`` to its joint's gravity basis (:func:`upgrade_elasticity`).

    Returns:
        (selection, note, alternatives): the upgraded selection and its note, or the selection
        unchanged, no note and ``{name: [Alternative]}`` for the effects the upgrade's backward step
        removed.
    """
    prob = sel.problem
    b = basis_for(prob, e.joint)
    f = prob.fit([b if x.name == e.name else x for x in sel.fit.effects], start=sel.fit)
    dof = b.n_params - e.n_params
    lr = max(sel.fit.cost - f.cost, 0.0)
    p = float(scipy.stats.chi2.sf(lr, dof))
    trial = dataclasses.replace(sel, fit=f, holdout=prob.holdout(f, k=k_folds))
    trial, removed = backward_step(trial, b, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
    before, after = rms(sel.holdout), rms(trial.holdout)
    if _bic(trial.fit) >= _bic(sel.fit) or after >= before:
        # not better, but the effects it makes redundant are stand-ins for a mass mismatch
        ev = {"lr_stat_vs_file_masses": lr, "dof": dof, "p_value": p}
        masses = f"{e.name} with the link masses and centres of mass unlike the model file's"
        alts = {
            nm: [_mass_alternative(b, {**ev, "explains": f"{nm} and {e.name} together: {masses}"})]
            for nm in removed
        }
        return sel, None, alts
    fb = next(x for x in trial.fit.effects if x.name == b.name)
    comp = gb.basis_compliance(fb, trial.fit.model)
    upgrade = {
        "replaces": e.name,
        "lr_stat": lr,
        "dof": dof,
        "p_value": p,
        "delta_bic": _bic(sel.fit) - _bic(trial.fit),
        "removed": removed,
        "holdout_rms_mm_before": before,
        "holdout_rms_mm_after": after,
        **{f"basis_{k}": v for k, v in comp.items()},
    }
    if e.family == "joint_elasticity":
        upgrade["compliance_file_masses"] = float(e.value_array()[0])
    evidence = dict(trial.evidence)
    evidence[b.name] = {**evidence.pop(e.name, {}), "basis_upgrade": upgrade}
    why = (
        "the model file's masses do not explain the deflection"
        if e.family == "joint_elasticity"
        else "a deflection with the gravity torque of other link masses explains the data better"
    )
    note = (
        f"{e.name}: {why} (LR {lr:.1f} on {dof} dof); "
        f"named with the gravity basis {b.name} ({b.n_params} moments), compliance against the "
        f"file's torques {comp['compliance']:.3g} rad/(N m)"
        + (f"; removed as stand-ins: {', '.join(removed)}" if removed else "")
    )
    return dataclasses.replace(sel, fit=trial.fit, holdout=trial.holdout, evidence=evidence), note, {}


def upgrade_elasticity(sel: Selection, *, alpha: float, k_folds: int) -> tuple[Selection, list[str], dict]:
    """Replace named elasticities by their gravity basis where the data demand it.

    For each named ``joint_elasticity:j`` (and ``backlash:j``, :func:`_upgradable`): the basis in its
    place, then the backward step (effects that were stand-ins for the mass mismatch, e.g. a gear
    error of joint j, go). Accepted if the result has a lower BIC (``chi2 + k ln(3 n)``) and a lower
    held-out RMS than the current model. If the upgrade is not better but its backward step removes
    effects (the basis explains them with the elasticity), each removed effect gets the basis as a
    competing explanation. Then a named elasticity or backlash is tried as a backlash whose side
    follows the torque fitted from the data (:func:`_backlash_with_fitted_torque`), and, while the
    model fails the goodness-of-fit test, the basis of the joints without one
    (:func:`_add_basis_if_unexplained`).

    Returns:
        (selection, notes, alternatives): the selection after the upgrades, notes for the report
        (one per upgrade) and per effect name the alternatives to add to its cause
        (:func:`basis_alternatives`).
    """
    notes, alternatives = [], {}
    ln_n = np.log(3 * sel.problem.data.n)
    for e in [x for x in sel.fit.effects if _upgradable(sel.problem, x)]:
        sel, note, alts = _upgrade_one(sel, e, alpha=alpha, k_folds=k_folds, ln_n=ln_n)
        notes += [note] if note else []
        for name, found in alts.items():
            alternatives.setdefault(name, []).extend(found)
    # the named causes' sides first, then (if the model still fails the test) further causes
    done = {e.name for e in sel.fit.effects}
    kw = {"alpha": alpha, "k_folds": k_folds, "ln_n": ln_n}
    sel, more = _backlash_with_fitted_torque(sel, **kw)
    notes += more
    sel, more = _add_basis_if_unexplained(sel, **kw)
    notes += more
    sel, more = _backlash_with_fitted_torque(sel, **kw, skip=done)
    return sel, notes + more, alternatives


def _stand_in_alternatives(sel: Selection, *, alpha: float) -> dict:
    """A named joint-angle cause of joint j (gear, scale, coupling, backlash) that adds nothing to
    the gravity basis of joint j (likelihood ratio not significant at ``alpha`` once the basis is in
    the model) is also joint j's elasticity with masses unlike the file's: the basis becomes its
    alternative (e.g. ``gear_cyclic:2:1``, whose sin/cos(q_2) are part of joint 2's torque).
    Returns ``{name: [Alternative]}``."""
    prob, out = sel.problem, {}
    named = {e.joint for e in sel.fit.effects if e.family in ("joint_elasticity", gb.FAMILY)}
    tried = [
        x
        for x in sel.fit.effects
        if x.family in fx.JOINT_FAMILIES and x.family != "joint_elasticity" and x.joint not in named
        and gb.joint_basis(prob.robot, x.joint).rank > 0
    ]  # fmt: skip

    def fits(k: int) -> tuple[Fit, Fit]:  # the basis in x's place, then x beside it
        x = tried[k]
        b = basis_for(prob, x.joint)
        others = [y for y in sel.fit.effects if y.name != x.name]
        f_b = prob.fit([*others, b], start=sel.fit)
        return f_b, prob.fit([*others, b, x], start=f_b)

    for x, (f_b, f_bx) in zip(tried, independent(fits, len(tried), size=sel.fit.J.size), strict=True):
        b = basis_for(prob, x.joint)
        lr_x = max(f_b.cost - f_bx.cost, 0.0)
        p_x = float(scipy.stats.chi2.sf(lr_x, x.n_params))
        if p_x < alpha:
            continue
        evidence = {
            "chi2_difference": f_b.cost - sel.fit.cost,
            "n_params": b.n_params,
            "lr_stat_cause_given_basis": lr_x,
            "p_value_cause_given_basis": p_x,
            "explains": f"{x.name} lies within the gravity torque of joint {x.joint} with other link "
            f"masses: an elasticity of joint {x.joint} explains it as well",
        }
        out.setdefault(x.name, []).append(_mass_alternative(b, evidence))
    return out


def _best_side(prob: FitProblem, sel: Selection, e, Y: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(n,) the torque shape ``Y theta'`` whose sign, as a backlash of e's joint, best explains the
    residuals of the model without e (score statistic): ``theta`` of the basis fit and, for a
    two-dimensional basis (a wrist joint), 36 directions over the half circle."""
    others = [x for x in sel.fit.effects if x.name != e.name]
    f0 = prob.fit(others, start=sel.fit)
    tau1 = prob.tau.copy()
    tau1[:, e.joint - 1] = 1.0
    n = prob.data.n
    _, H, E = prob.with_tau(tau1).response(f0.model, [*others, fx.Effect("backlash", e.joint)], np.arange(n))
    Q, _ = np.linalg.qr(np.concatenate([H[:, :, f0.free], E[:, :, :-1]], axis=2).reshape(3 * n, -1))
    G = E[:, :, -1] / prob.sigma  # (n, 3) the joint's angle column
    r0 = (f0.residuals / prob.sigma).reshape(-1)
    dirs = [theta]
    if theta.size == 2:
        dirs += [np.array([np.cos(a), np.sin(a)]) for a in np.linspace(0.0, np.pi, 36, endpoint=False)]
    best, out = -1.0, Y @ theta
    for d in dirs:
        c = (G * np.sign(Y @ d)[:, None]).reshape(-1)
        c = c - Q @ (Q.T @ c)
        cc = float(c @ c)
        score = float(c @ r0) ** 2 / cc if cc > 0 else 0.0
        if score > best:
            best, out = score, Y @ d
    return out


def _fitted_torque(prob: FitProblem, joint: int, shape: np.ndarray) -> np.ndarray:
    """(n, 6) the problem's torques with joint's replaced by ``shape`` scaled to its RMS [N m]."""
    tau = prob.tau.copy()
    tau[:, joint - 1] = shape * np.sqrt(np.mean(prob.tau[:, joint - 1] ** 2) / np.mean(shape**2))
    return tau


def _basis_theta(sel: Selection, e) -> np.ndarray:
    """The first moments of joint e's gravity basis: e's values (a basis) or of a fit with the basis
    in e's place (an elasticity or a backlash)."""
    prob = sel.problem
    rank = gb.joint_basis(prob.robot, e.joint).rank
    if e.family == gb.FAMILY:
        return e.value_array()[:rank]
    f = prob.fit(
        [basis_for(prob, e.joint) if x.name == e.name else x for x in sel.fit.effects], start=sel.fit
    )
    return next(x for x in f.effects if x.joint == e.joint and x.family == gb.FAMILY).value_array()[:rank]


def _backlash_with_fitted_torque(
    sel: Selection, *, alpha: float, k_folds: int, ln_n: float, skip=()
) -> tuple[Selection, list[str]]:
    """A named elasticity that is a backlash whose side the file's masses get wrong.

    ``backlash:j`` follows the sign of joint j's gravity torque; with masses unlike the file's that
    sign is wrong near its zero crossings (for a wrist joint everywhere: its torque comes from a
    centre of mass near the axis), and the selection names the elasticity as the closest stand-in.
    For each named elasticity (file masses or basis) of joint j: the torque shape ``Y_j theta`` of
    the basis fit replaces the file's torque of joint j in the fit conditions (scaled to its RMS) and
    ``backlash:j`` replaces the elasticity. Accepted, with the conditions kept (the report's plots
    and signals then use the fitted torque of joint j), if the BIC is lower and the held-out RMS
    too. For a wrist joint (two basis moments) the side is searched over 36 directions of the
    torque (:func:`_best_side`). A named ``backlash:j`` (whose side is the file's torque's expected
    sign) is tried with the fitted side alike. After an accepted replacement the backward step
    removes the effects that stood in for the poses on the wrong side. Effects whose name is in
    ``skip`` (already tried) are left alone.
    """
    notes = []
    for e in [x for x in sel.fit.effects if x.family in ("joint_elasticity", gb.FAMILY, "backlash")]:
        if e.name in skip or e.name not in {x.name for x in sel.fit.effects}:
            continue  # tried before, or removed by the backward step of an earlier replacement
        prob = sel.problem
        jb = gb.joint_basis(prob.robot, e.joint)
        shape = _best_side(prob, sel, e, jb.regressor(prob.robot, prob.data.q), _basis_theta(sel, e))
        side = np.sign(shape)
        if min(np.sum(side > 0), np.sum(side < 0)) < BACKLASH_MIN_SIDE or not np.any(shape):
            continue
        trial = prob.with_tau(_fitted_torque(prob, e.joint, shape))
        bl = fx.Effect("backlash", e.joint)
        f = trial.fit([bl if x.name == e.name else x for x in sel.fit.effects], start=sel.fit)
        if _bic(f) >= _bic(sel.fit):
            continue
        hold = trial.holdout(f, k=k_folds)
        if rms(hold) >= rms(sel.holdout):
            continue
        side_ev = {
            "replaces": e.name,
            "chi2_with": f.cost,
            "chi2_without": sel.fit.cost,
            "holdout_rms_mm_before": rms(sel.holdout),
            "holdout_rms_mm_after": rms(hold),
            "poses_side_differs_from_file": int(np.sum(side != np.sign(prob.tau[:, e.joint - 1]))),
        }
        evidence = dict(sel.evidence)
        ev = evidence.pop(e.name, {})
        evidence[bl.name] = {**ev, "backlash_side_from_data": side_ev}
        sel = dataclasses.replace(sel, problem=trial, fit=f, holdout=hold, evidence=evidence)
        sel, removed = backward_step(sel, bl, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
        evidence = dict(sel.evidence)
        evidence[bl.name] = {**ev, "backlash_side_from_data": {**side_ev, "removed": removed}}
        sel = dataclasses.replace(sel, evidence=evidence)
        notes.append(
            f"{e.name} is a backlash: backlash:{e.joint} with the side of the gravity torque fitted from the "
            f"data (the file's masses put {side_ev['poses_side_differs_from_file']} poses on the other "
            f"side) fits better (chi2 {f.cost:.1f} against {side_ev['chi2_without']:.1f})"
            + (f"; removed as stand-ins: {', '.join(removed)}" if removed else "")
        )
    return sel, notes


def _unexplained_candidates(sel: Selection) -> list[tuple]:
    """``(effect, problem, fit)`` of :func:`_add_basis_if_unexplained`'s candidates: per joint without
    an elasticity or a backlash, its gravity basis and a backlash on the side of the torque fitted
    from the data (:func:`_best_side`), each fitted beside the model."""
    prob = sel.problem
    have = {e.joint for e in sel.fit.effects if e.family in ("joint_elasticity", gb.FAMILY, "backlash")}
    joints = [
        j for j in range(1, prob.robot.n_joints + 1) if j not in have and gb.joint_basis(prob.robot, j).rank
    ]

    def tried(k: int) -> list[tuple]:  # (effect, the torques of its fit or None: the problem's, fit)
        j, jb = joints[k], gb.joint_basis(prob.robot, joints[k])
        b = basis_for(prob, j)
        f = prob.fit([*sel.fit.effects, b], start=sel.fit)
        theta = next(x for x in f.effects if x.name == b.name).value_array()[: jb.rank]
        shape = _best_side(prob, sel, b, jb.regressor(prob.robot, prob.data.q), theta)
        side = np.sign(shape)
        if min(np.sum(side > 0), np.sum(side < 0)) < BACKLASH_MIN_SIDE:
            return [(b, None, f)]
        tau, bl = _fitted_torque(prob, j, shape), fx.Effect("backlash", j)
        return [(b, None, f), (bl, tau, prob.with_tau(tau).fit([*sel.fit.effects, bl], start=sel.fit))]

    every = independent(tried, len(joints), size=sel.fit.J.size)  # the joints at once
    return [(e, prob if tau is None else prob.with_tau(tau), f) for ts in every for e, tau, f in ts]


def _add_basis_if_unexplained(
    sel: Selection, *, alpha: float, k_folds: int, ln_n: float
) -> tuple[Selection, list[str]]:
    """If the model still fails the goodness-of-fit test: for each joint j without an elasticity,
    its gravity basis and a backlash whose side follows the torque fitted from the data
    (:func:`_best_side`) as further candidates (likelihood ratio, Bonferroni over these
    candidates, BIC, held-out RMS, as in the selection); the best one is added if the model with
    it passes the test (else it would be a stand-in for an unexplained rest), then the backward
    step. This finds an elasticity or a backlash whose torque with the true masses looks nothing
    like the file's (e.g. a wrist joint whose link's centre of mass sits near its axis in the file)."""
    if scipy.stats.chi2.sf(sel.fit.cost, sel.fit.dof) >= alpha:
        return sel, []
    tried = _unexplained_candidates(sel)
    best = None
    for b, pb, f in tried:
        lr = max(sel.fit.cost - f.cost, 0.0)
        p = float(scipy.stats.chi2.sf(lr, b.n_params))
        dbic = lr - b.n_params * ln_n
        if min(1.0, p * len(tried)) < alpha and dbic > 0 and (best is None or dbic > best[4]):
            best = (b, pb, f, p, dbic, lr)
    if best is None:
        return sel, []
    b, pb, f, p, dbic, lr = best
    if scipy.stats.chi2.sf(f.cost, f.dof) < alpha:  # not the rest, at most a stand-in for it
        return sel, []
    hold = pb.holdout(f, k=k_folds)
    before = rms(sel.holdout)
    if rms(hold) >= before:
        return sel, []
    ev = {
        "lr_stat": lr,
        "dof": b.n_params,
        "p_value": p,
        "p_value_corrected": min(1.0, p * len(tried)),
        "delta_bic": dbic,
        "holdout_rms_mm_without": before,
        "holdout_rms_mm_with": rms(hold),
        "step": "after the selection (the model failed the fit test)",
    }
    if b.family == gb.FAMILY:
        comp = gb.basis_compliance(next(x for x in f.effects if x.name == b.name), f.model)
        ev.update({f"basis_{k}": v for k, v in comp.items()})
        what = f"the gravity torque of joint {b.joint} with any link masses; " + (
            f"compliance against the file's torques {comp['compliance']:.3g} rad/(N m)"
            if np.isfinite(comp["compliance"])
            else "the model file has no masses to compare its compliance with"
        )
    else:
        what = f"the side of joint {b.joint}'s gravity torque fitted from the data"
    sel = dataclasses.replace(sel, problem=pb, fit=f, holdout=hold, evidence={**sel.evidence, b.name: ev})
    sel, removed = backward_step(sel, b, alpha=alpha, ln_n=ln_n, k_folds=k_folds)
    return sel, [
        f"the model still failed the fit test; {b.name} ({what}) explains the rest (LR {lr:.1f} on "
        f"{b.n_params} dof)" + (f"; removed: {', '.join(removed)}" if removed else "")
    ]


def basis_alternatives(sel: Selection, alternatives: dict, *, alpha: float) -> dict:
    """``{name: [Alternative]}``: the basis alternatives of :func:`upgrade_elasticity` and then those of
    :func:`_stand_in_alternatives` (on the final model ``sel.fit``)."""
    out = {k: list(v) for k, v in alternatives.items()}
    for name, found in _stand_in_alternatives(sel, alpha=alpha).items():
        out.setdefault(name, []).extend(found)
    return out


def basis_size(prob: FitProblem, fit: Fit, i: int, cov: np.ndarray) -> BasisSize | None:
    """How far the mass-free basis ``i`` of ``fit`` (covariance ``cov`` of its values) turns what its
    joint carries: the largest displacement at the reflector that no geometric parameter takes (its
    signal beside the span of the geometric columns: a level the joint's offset or a frame's tilt
    absorbs is no deflection the data show) over the reflector's distance from the joint (poses at
    least 10 mm from it), a lower bound of the angle; None for a zero effect."""
    e, q, n = fit.effects[i], prob.data.q, prob.data.n
    v = e.value_array()
    vv = float(v @ v)
    if vv == 0.0:
        return None
    _, H, E = prob.response(fit.model, fit.effects, np.arange(n))
    Q = np.linalg.qr(H[:, :, fit.free].reshape(3 * n, -1))[0]
    c = sum(x.n_params for x in fit.effects[:i])
    sig = (E[:, :, c : c + e.n_params] @ v).reshape(-1)
    size = np.linalg.norm((sig - Q @ (Q.T @ sig)).reshape(n, 3), axis=1)
    p_W = reflector_world(fit.model, q, prob.data.target)
    lever = np.linalg.norm(p_W - fit.model.frames(q).joint_points[:, e.joint - 1], axis=1)
    ratio = np.where(lever > 10.0, size / np.maximum(lever, 10.0), 0.0)
    k = int(np.argmax(ratio))
    return BasisSize(
        angle=float(ratio[k]),
        relative_std=float(np.sqrt(max(float(v @ cov @ v), 0.0)) / vv),
        max_mm=float(size[k]),
        lever_mm=float(lever[k]),
        reach_mm=float(prob.robot.reach),
    )
