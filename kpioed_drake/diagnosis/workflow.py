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
   fails the goodness-of-fit test (:mod:`~kpioed_drake.diagnosis.rest`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.arguments import check_paths
from kpioed_drake.calibration import hold_undetermined
from kpioed_drake.diagnosis import report as rp
from kpioed_drake.diagnosis.common import ALPHA, K_FOLDS, MAX_EFFECTS
from kpioed_drake.diagnosis.elastic_basis import add_alternatives, upgrade_elasticity, use_expected_sides
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.plots import write_plots
from kpioed_drake.diagnosis.rest import unexplained_rest
from kpioed_drake.diagnosis.selection import candidate_effects, score_tests, select_effects
from kpioed_drake.diagnosis.sides import side_patterns
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation.estimator import covariance
from kpioed_drake.estimation.plausibility import check_data
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Robot, load_robot
from kpioed_drake.scene3d import diagnosis_page
from kpioed_drake.tracker.data import Measurements, as_measurements
from kpioed_drake.tracker.formats import read_data


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


def diagnose(
    robot: str | Path | Robot,
    data: str | Path | Measurements,
    *,
    sigma_mm: float = 0.02,
    alpha: float = ALPHA,
    k_folds: int = K_FOLDS,
    max_effects: int = MAX_EFFECTS,
    candidates=None,
    cell=None,
    force: bool = False,
) -> rp.DiagnosisReport:
    """Diagnose the model discrepancy of a robot's laser-tracker data.

    Args:
        robot: model name, path or :class:`~kpioed_drake.robot.models.Robot`.
        data: a path to a SPEC measurement CSV or :class:`~kpioed_drake.tracker.data.Measurements`.
        sigma_mm: the known noise standard deviation per coordinate [mm].
        alpha: level of the goodness-of-fit test and family-wise level of each selection step.
        k_folds: folds of the cross-validation over poses.
        max_effects: most effects to add.
        candidates: override the candidate list (effects or texts).
        cell: the cell (default: the robot's cell file).
        force: go on with implausible data (:func:`kpioed_drake.estimation.plausibility.check_data`), noted.

    Returns:
        :class:`~kpioed_drake.diagnosis.report.DiagnosisReport`.
    """
    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    data = as_measurements(data, robot)
    data.check()
    prob = _problem(robot, data, sigma_mm, k_folds, cell)
    warnings = check_data(prob.nominal, data, n_params=prob.nominal.layout.n_free, force=force)
    # as calibrate: parameters these poses do not determine are held at nominal, with a note
    prob.nominal = hold_undetermined(prob.nominal, data, False, warnings)
    use_expected_sides(prob)  # a backlash's side where the file's masses leave it uncertain
    if candidates is None:
        cands, notes = candidate_effects(data, prob.tau, robot=robot)
    else:
        cands = [
            fx.parse_effect(c, model=prob.nominal)
            if isinstance(c, str)
            else dataclasses.replace(c, values=None)
            for c in candidates
        ]
        notes = []
    notes = warnings + notes
    prob.side_patterns = side_patterns(prob, [e.joint for e in cands if e.family == "backlash"])

    base = prob.fit([])
    try:  # as strict as calibrate: the geometric fit alone must be determined by the poses
        covariance(base.J)
    except np.linalg.LinAlgError:
        raise InputError(
            f"{data.source}: the {data.n} poses do not determine the {base.J.shape[1]} geometric parameters "
            "(information matrix singular); use more, and more varied, poses"
        ) from None
    base_hold = prob.holdout(base, k=k_folds)
    test = _gof_test(base, alpha)
    structure = score_tests(prob, base, cands)
    sel = select_effects(prob, base, base_hold, cands, alpha=alpha, k_folds=k_folds, max_effects=max_effects)
    basis_notes, basis_alts = upgrade_elasticity(prob, sel, alpha=alpha, k_folds=k_folds)  # masses off

    causes = rp.causes(prob, sel, cands, alpha=alpha, k_folds=k_folds)
    add_alternatives(prob, sel, causes, basis_alts, alpha=alpha)
    notes += basis_notes
    rest = unexplained_rest(prob, sel.fit, alpha=alpha)
    for si in sel.stand_ins:
        notes.append(
            f"{si['candidate']} is significant (LR {si['lr_stat']:.1f}) but not named: it {si['reason']} "
            "(a stand-in for the unexplained rest)"
        )
    baseline = rp.fit_summary(base, base_hold)
    extended = rp.fit_summary(sel.fit, sel.holdout)
    kpi = rp.kpi_summary(prob, base, sel.fit)
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
    return rp.DiagnosisReport(
        robot=robot.name,
        n_poses=data.n,
        sigma_mm=prob.sigma,
        discrepancy=bool(test["rejects"] or causes),
        test=test,
        causes=causes,
        baseline=baseline,
        extended=extended,
        gain=rp.gain(prob, baseline, extended, kpi),
        kpi=kpi,
        residual_structure=structure,
        steps=sel.steps,
        notes=notes,
        details={
            "prob": prob,
            "base": base,
            "ext": sel.fit,
            "base_holdout": base_hold,
            "ext_holdout": sel.holdout,
            "candidates": cands,
        },
        unexplained=rest,
    )


def diagnose_file(
    robot: str,
    data_path: str | Path,
    *,
    sigma_mm: float = 0.02,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    force: bool = False,
    data_format: str | Path | None = None,
) -> rp.DiagnosisReport:
    """Diagnose a measurement file (``kpioed diagnose``); outputs written after all succeeded.

    Args:
        robot: model name or YAML path.
        data_path: the measurement CSV.
        sigma_mm: the known noise standard deviation per coordinate [mm].
        json_path: JSON report to write.
        plots_dir: folder for the residual pictures (PNG).
        html: 3-D page (Meshcat) of the residuals before and after the named extension.
        force: go on with implausible data, noted in the report.
        data_format: format file of a measurement file of another layout (docs/data-formats.md).
    """
    check_sigma(sigma_mm)
    check_paths(
        robot=robot, inputs=[data_path, data_format], outputs=[json_path], folders=[plots_dir], html=html
    )
    rob = load_robot(robot)
    report = diagnose(rob, read_data(data_path, rob, data_format), sigma_mm=sigma_mm, force=force)
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, report.to_json())
        if plots_dir:
            write_plots(report, staged.folder(plots_dir))
        if html:
            d = report.details
            prob = d["prob"]
            label = ", ".join(c["effect"] for c in report.causes) or "no extension"
            page = diagnosis_page(
                prob.robot,
                prob.cell,
                d["base"].model,
                prob.data.q,
                d["base"].residuals,
                d["ext"].residuals,
                label=label,
            )
            staged.add_text(html, page)
        staged.commit()
    return report
