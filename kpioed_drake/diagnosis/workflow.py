"""``diagnose``: does the geometric model explain the data, and if not, which effect is missing?

Four steps on laser-tracker data (SPEC "Measured data and model discrepancy"; docs/diagnosis.md):

1. **Geometric calibration and a goodness-of-fit test.** The free geometric parameters are fitted
   (:class:`~kpioed_drake.diagnosis.fit.FitProblem`). With a correct model and the known noise
   sigma, ``chi^2 = |r|^2 / sigma^2`` follows a chi-square law with ``3 n - n_free`` degrees of
   freedom; a p-value below ``alpha`` is a discrepancy.
2. **Residual structure**: the score statistic of every candidate
   (:func:`~kpioed_drake.diagnosis.selection.score_tests`).
3. **Naming the cause**: stepwise selection
   (:func:`~kpioed_drake.diagnosis.selection.select_effects`).
4. **The extended model and the gain**: RMS, chi^2/dof and held-out RMS before and after, and the
   KPI (TCP at ``q_work``): its shift between the two models and its variance tr(Cs)/3
   (:mod:`kpioed_drake.diagnosis.report`); per cause its competing explanations
   (:mod:`~kpioed_drake.diagnosis.alternatives`) and plausibility
   (:mod:`~kpioed_drake.effects.physical`); the unexplained rest when the extended model still
   fails the goodness-of-fit test (:func:`~kpioed_drake.diagnosis.report.unexplained_rest`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake import progress
from kpioed_drake.calibration import calibrate, hold_undetermined
from kpioed_drake.calibration.inputs import read_inputs
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.calibration.workflow import stage_model
from kpioed_drake.diagnosis import report as rp
from kpioed_drake.diagnosis.alternatives import name_causes, replace_implausible, settle
from kpioed_drake.diagnosis.elastic_basis import (
    basis_alternatives,
    basis_for,
    reduce_absorbed,
    upgrade_elasticity,
)
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.options import DEFAULT_SIGMA_MM, DiagnosisOptions
from kpioed_drake.diagnosis.plots import write_plots
from kpioed_drake.diagnosis.records import Selection, describe_causes
from kpioed_drake.diagnosis.selection import candidate_effects, columns, score_tests, select_effects
from kpioed_drake.diagnosis.sides import side_patterns, with_expected_sides
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation import noise as ns
from kpioed_drake.estimation.estimator import covariance
from kpioed_drake.estimation.plausibility import check_data
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.scene3d import diagnosis_page
from kpioed_drake.tracker.data import Measurements, as_measurements, n_poses


def _problem(robot, data, sigma_mm: float, k_folds: int, cell) -> FitProblem:
    """The checked fit problem (sigma, enough poses for the cross-validation)."""
    check_sigma(sigma_mm)
    prob = FitProblem(robot, data, sigma_mm, cell=cell)
    n, n_free = data.n, prob.nominal.layout.n_free
    if 3 * (n - int(np.ceil(n / k_folds))) < n_free + 6:
        raise InputError(
            f"{data.source}: {n} poses are too few to calibrate {n_free} parameters with {k_folds}-fold "
            "cross-validation (use at least 15 poses; 60 or more to name causes)"
        )
    return prob


def _prepared(
    robot: Robot, data: Measurements, opts: DiagnosisOptions, cell, sigma: float
) -> tuple[FitProblem, list, list, tuple]:
    """The fit problem as calibrate's (parameters these poses do not determine held at nominal,
    with a note), every backlash on its expected side (where the file's masses leave it uncertain),
    the candidates with the notes so far and the joints whose gravity basis is sized on the data's
    poses (:func:`~kpioed_drake.effects.gravity_basis.size_on_poses`)."""
    prob = _problem(robot, data, sigma, opts.k_folds, cell)
    warnings = check_data(prob.nominal, data, n_params=prob.nominal.layout.n_free, force=opts.force)
    prob = with_expected_sides(prob.with_nominal(hold_undetermined(prob.nominal, data, False, warnings)))
    sized, resized = gb.size_on_poses(prob.robot, data.q)
    prob = prob.with_robot(lb.size_on_poses(sized, data.q, lb.massless_joints(sized))[0])
    notes = [
        f"joint_elasticity_basis:{j} is sized on these poses: {r} of the {r0} moment combinations of the "
        "joint box vary here (the joint angles are dependent, e.g. a coupled joint)"
        for j, (r0, r) in resized.items()
    ]
    if opts.candidates is None:
        cands, more = candidate_effects(data, prob.tau, robot=prob.robot)
        notes += more
    else:
        cands = [fx.parse_effect(c, model=prob.nominal) for c in opts.candidates]
    stored = [e.name for e in fx.model_effects(robot)]
    if stored:
        notes.append(
            f"the model file's effects ({', '.join(stored)}) are tested as candidates like any other: the "
            "model under test is its geometry; `out` keeps them in the model it writes"
        )
    return prob, cands, warnings + notes, tuple(resized)


def _baseline(prob: FitProblem, k_folds: int) -> tuple[Fit, np.ndarray]:
    """The geometric fit and its held-out residuals; as strict as calibrate: the geometric fit alone
    must be determined by the poses."""
    data = prob.data
    base = prob.fit([])
    try:
        covariance(base.J)
    except np.linalg.LinAlgError:
        raise InputError(
            f"{data.source}: the {data.n} poses do not determine the {base.J.shape[1]} geometric parameters "
            "(information matrix singular); use more, and more varied, poses"
        ) from None
    return base, prob.holdout(base, k=k_folds)


def _noise(prob: FitProblem, base: Fit, cands, stated: tuple[float, str], repeats) -> ns.Noise:
    """The noise the tests rest on (:mod:`~kpioed_drake.estimation.noise`): the stated sigma, checked
    against the robust scale of the residuals beside the geometry, every candidate and the gravity
    basis of every joint gravity can load (the most the selection and the upgrades could name)."""
    have = {e.name for e in cands}
    bases = [
        basis_for(prob, j)
        for j in range(1, prob.robot.n_joints + 1)
        if gb.joint_basis(prob.robot, j).rank > 0 and f"{gb.FAMILY}:{j}" not in have
    ]
    Jm, cols = columns(prob, base, [*cands, *bases])
    scale, dof = ns.residual_scale(base.residuals, np.concatenate([Jm, *cols], axis=1))
    return ns.choose(*stated, scale, dof, repeats)


def _gof_test(base: Fit, alpha: float) -> dict:
    p_gof = float(scipy.stats.chi2.sf(base.cost, base.dof))
    return {
        "chi2": base.cost,
        "dof": base.dof,
        "chi2_per_dof": base.chi2_per_dof,
        "p_value": p_gof,
        "alpha": alpha,
        "rejects": bool(p_gof < alpha),
    }


def _closing_notes(sel: Selection, test: dict, causes, extended: dict, alpha: float) -> list[str]:
    """The notes on the stand-ins left unnamed (not those a later step named after all: their note
    says so), a discrepancy without a cause and a poor final fit."""
    named = {c.effect.name for c in causes}
    notes = [
        f"{si.name} is significant (LR {si.lr_stat:.1f}) but not named: it {si.reason} "
        "(a stand-in for the unexplained rest)"
        if si.name not in named
        else f"{si.name} first looked like a stand-in (LR {si.lr_stat:.1f}: it {si.reason}); a later step "
        "named it as a cause"
        for si in sel.stand_ins
    ]
    if test["rejects"] and not causes:
        notes.append(
            "the geometric model does not explain the data but no candidate effect is named: an "
            "effect outside the candidate list, outliers, or a sigma that is too small (see 'unexplained')"
        )
    if causes and extended["p_value"] < alpha:
        notes.append(
            f"the extended model still does not fit to the noise level (p = {extended['p_value']:.2g}): "
            "more effects or a larger sigma"
        )
    return notes


def _named_causes(
    sel: Selection, cands: list, robot: Robot, *, alpha: float, k_folds: int
) -> tuple[Selection, tuple, list[str]]:
    """The selection's effects as named causes: the elasticities upgraded to a mass-free basis where the
    masses are off, swaps for better competitors (:func:`settle`), implausible causes replaced where a
    plausible alternative explains as much, each described in words; with the notes of these steps."""
    sel, notes, basis_alts = upgrade_elasticity(sel, alpha=alpha, k_folds=k_folds)  # masses off
    sel, settled = settle(sel, cands, alpha=alpha, k_folds=k_folds)
    causes = name_causes(sel, settled, basis_alternatives(sel, basis_alts, alpha=alpha), k_folds=k_folds)
    sel, settled, replaced = replace_implausible(sel, causes, settled, cands, alpha=alpha, k_folds=k_folds)
    if replaced:
        causes = name_causes(sel, settled, basis_alternatives(sel, basis_alts, alpha=alpha), k_folds=k_folds)
    notes += replaced + _implausible_notes(causes)
    return sel, describe_causes(causes, robot, sel.problem, sel.fit), notes


def diagnose(
    robot: Robot, data: Measurements, options: DiagnosisOptions | None = None, *, cell: Cell | None = None
) -> rp.DiagnosisReport:
    """Diagnose the model discrepancy of a robot's laser-tracker data.

    Args:
        robot: the robot (:func:`~kpioed_drake.robot.models.load_robot`).
        data: the measurements (:func:`~kpioed_drake.tracker.data.read_data`,
            :meth:`~kpioed_drake.tracker.data.Measurements.from_table`).
        options: noise, levels, folds, candidates (default :class:`DiagnosisOptions`).
        cell: the cell (default: the robot's cell file).

    Returns:
        :class:`~kpioed_drake.diagnosis.report.DiagnosisReport`.
    """
    opts = DiagnosisOptions() if options is None else options
    alpha, k_folds = opts.alpha, opts.k_folds
    data = as_measurements(data, robot)
    data.check()
    if data.R_TP is not None:
        raise InputError(
            f"{data.path}: the data hold a 6-DoF probe's orientations, which the diagnosis's effects do not "
            "model yet; the diagnosis takes positions (x, y, z per row, one or several targets per pose): "
            "diagnose the same poses without the orientation columns (qw, qx, qy, qz and their sigmas), "
            "or read by a format file without its orientation block"
        )
    repeats = ns.repeat_scatter(data.q, data.eta, data.target)
    stated = ns.stated(opts.sigma_mm, repeats, DEFAULT_SIGMA_MM)
    with progress.stage("diagnosis", total=4, unit="stage"):
        prob, cands, notes, resized = _prepared(robot, data, opts, cell, stated[0])
        sides = side_patterns(prob, [e.joint for e in cands if e.family == "backlash"])
        base, base_hold = _baseline(prob, k_folds)
        prob, cands, more = reduce_absorbed(prob, base, cands, resized)
        notes += more
        progress.step(done="geometric fit", candidates=len(cands))
        noise = _noise(prob, base, cands, stated, repeats)
        if noise.sigma_mm != prob.sigma:  # the tests rest on the residuals' scale
            prob = dataclasses.replace(prob, sigma=noise.sigma_mm)
            base, base_hold = _baseline(prob, k_folds)
        test = _gof_test(base, alpha)
        structure = score_tests(prob, base, cands)
        progress.step(done="noise and goodness of fit")
        sel = select_effects(
            prob,
            base,
            base_hold,
            cands,
            sides=sides,
            alpha=alpha,
            k_folds=k_folds,
            max_effects=opts.max_effects,
        )
        progress.step(done="stepwise selection", effects=len(sel.fit.effects))
        sel, causes, basis_notes = _named_causes(sel, cands, robot, alpha=alpha, k_folds=k_folds)
        progress.step(done="causes and their alternatives")
    final = sel.problem
    baseline = rp.fit_summary(base, base_hold)
    extended = rp.fit_summary(sel.fit, sel.holdout)
    kpi = rp.kpi_summary(final, base, sel.fit)
    return rp.DiagnosisReport(
        robot=robot.name,
        n_poses=n_poses(data),
        n_rows=data.n,
        sigma_mm=final.sigma,
        noise=noise.as_dict(),
        discrepancy=bool(test["rejects"] or causes),
        test=test,
        cause_records=causes,
        baseline=baseline,
        extended=extended,
        gain=rp.gain(final, baseline, extended, kpi),
        kpi=kpi,
        residual_structure=structure,
        step_records=sel.steps,
        notes=notes + basis_notes + _closing_notes(sel, test, causes, extended, alpha),
        details={
            "prob": final,
            "base": base,
            "ext": sel.fit,
            "base_holdout": base_hold,
            "ext_holdout": sel.holdout,
            "candidates": cands,
        },
        unexplained=rp.unexplained_rest(final, sel.fit, alpha=alpha, robot=robot),
        joint_names=tuple(robot.joint_names),
        selection_stop=sel.stop,
    )


def diagnose_file(
    robot: str | Path,
    data_path: str | Path,
    options: DiagnosisOptions | None = None,
    *,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    data_format: str | Path | None = None,
    out: str | Path | None = None,
) -> rp.DiagnosisReport:
    """Diagnose a measurement file (``kpioed diagnose``); outputs written after all succeeded (a
    picture that fails is a note in the report, the other outputs are still written).

    Args:
        robot: model name or YAML path.
        data_path: the measurement CSV.
        options: noise, levels, folds, candidates (default :class:`DiagnosisOptions`).
        json_path: JSON report to write.
        plots_dir: folder for the residual pictures (PNG).
        html: 3-D page (Meshcat) of the residuals before and after the named extension.
        data_format: format file of a measurement file of another layout (docs/data-formats.md).
        out: the extended model file to write (the geometry calibrated with the named causes;
            the geometric model when none is named): a YAML file, a URDF robot's ``.urdf``.
    """
    opts = DiagnosisOptions() if options is None else options
    check_sigma(opts.sigma_mm, allow_none=True)
    rob, cell, data = read_inputs(
        robot, data_path, data_format, model_out=out, outputs=[json_path], folders=[plots_dir], html=html
    )
    report = diagnose(rob, data, opts, cell=cell)
    with Outputs() as staged:
        if out:
            stage_model(staged, extended_calibration(rob, data, report, opts), out)
        if plots_dir:
            _stage_plots(report, staged.folder(plots_dir))
        if json_path:
            staged.add_json(json_path, report.to_json())
        if html:
            d = report.details
            label = ", ".join(c["effect"] for c in report.causes) or "no extension"
            page = diagnosis_page(
                rob,
                cell,
                d["base"].model,
                d["prob"].data.q,
                d["base"].residuals,
                d["ext"].residuals,
                label=label,
            )
            staged.add_text(html, page)
        staged.commit()
    return report


def extended_calibration(
    robot: Robot, data: Measurements, report: rp.DiagnosisReport, opts: DiagnosisOptions
) -> CalibrationReport:
    """The calibration of the diagnosed extended model: the geometry with the named causes (started
    from their fitted values), as ``calibrate`` with ``effects`` runs it, at the sigma the diagnosis
    rested on: the model the report's figures describe. A cause flagged implausible that no plausible
    alternative could replace (:func:`~kpioed_drake.diagnosis.alternatives.replace_implausible`) is
    written too (it predicts fresh poses better), with a note in ``report``."""
    keep = [c.effect for c in report.cause_records]
    keep += [e for e in fx.model_effects(robot) if e.key not in {k.key for k in keep}]  # the file's stay
    for c in report.cause_records:
        if not c.plausible:
            report.notes.append(
                f"out: {c.effect.name} is written although its value is implausible ({c.plausible_reason}); "
                "it predicts fresh poses better, as a stand-in for an effect with its signature"
            )
    robot = report.details["prob"].robot  # with the gravity bases sized on these poses
    cal = calibrate(
        robot, data, CalibrationOptions(sigma_mm=report.sigma_mm, effects=tuple(keep), force=opts.force)
    )
    names = ", ".join(e.name for e in keep) or "no effect (the geometric model)"
    report.notes.append(f"out: the model written is the geometry calibrated with {names}")
    return cal


def _implausible_notes(causes) -> list[str]:
    """A note per cause whose value is implausible and that no plausible alternative replaced."""
    return [
        f"{c.effect.name} is kept in the model although its value is implausible ({c.plausible_reason}): "
        "no plausible candidate explains the data as well; it stands in for an effect with its signature"
        for c in causes
        if not c.plausible
    ]


def _stage_plots(report: rp.DiagnosisReport, folder: Path) -> None:
    """The residual pictures; one that fails is a note in the report (the JSON is still written)."""
    try:
        write_plots(report, folder)
    except Exception as exc:  # a picture must not cost the results
        report.notes.append(f"plots: a picture could not be drawn ({type(exc).__name__}: {exc})")
