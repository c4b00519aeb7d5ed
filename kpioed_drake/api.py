"""The Python API: one documented function per ``kpioed`` command, and the only entry the CLI calls.

| command | function | implemented in |
|---|---|---|
| ``kpioed info`` | :func:`info` | here |
| ``kpioed evaluate`` | :func:`evaluate` | :func:`kpioed_drake.design.evaluate_file` |
| ``kpioed design`` | :func:`design` | :func:`kpioed_drake.design.run_design` |
| ``kpioed simulate`` | :func:`simulate` | :func:`kpioed_drake.simulation.workflow.simulate_file` |
| ``kpioed calibrate`` | :func:`calibrate` | :func:`kpioed_drake.calibration.calibrate_file` |
| ``kpioed validate`` | :func:`validate` | :func:`kpioed_drake.calibration.validate.validate_file` |
| ``kpioed diagnose`` | :func:`diagnose` | :func:`kpioed_drake.diagnosis.diagnose_file` |
| ``kpioed study`` | :func:`study` | :func:`kpioed_drake.study.workflow.run_study` |
| ``kpioed next`` | :func:`next` | :func:`kpioed_drake.online.workflow.next_file` |
| ``kpioed compensate`` | :func:`compensate` | :func:`kpioed_drake.compensation.workflow.compensate_file` |

Example::

    from kpioed_drake import api
    print(api.info("kr16")["n_params"])                      # 27
    report = api.evaluate("kr16", "design.csv")               # the design's KPI variance
    print(report["kpi_avg_var_mm2"], report["feasible"])
    res = api.design("kr16", discriminate="joint_scale:2=300|gear_cyclic:2:1", given="first.csv", n=20)
    print(res.discrimination["after"])                        # lambda, power of both tests
    plan = api.design("kr16", discriminate="thermal_expansion|tracker_scale", given="first.csv", n=20,
                      condition_span="3K")                    # poses and their temperature
    print(plan.discrimination["plan"]["spans"], plan.plan_columns["temperature_offset_K"])
    val = api.validate("kr16-cal.yaml", "fresh.csv")           # the calibration's tracker frame kept
    moved = api.validate("kr16-cal.yaml", "other-day.csv", tracker_frame="cross")  # tracker moved
    print(val.figures().mean_error_mm, moved.to_dict()["tracker"]["method"])
    comp = api.compensate("kr16-cal.yaml", program="program.csv", out="compensated.csv")
    print(comp.summary())                                     # rows reached, largest correction

Every command function checks its arguments and its output paths before any work (an output may
not overwrite an input, name a folder, or be named twice; :mod:`kpioed_drake.arguments`) and raises
:class:`~kpioed_drake.errors.InputError` with a message naming the argument, file, row or field.
Outputs are written only after everything succeeded, each atomically. Units follow the files:
millimetres and degrees in and out.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from kpioed_drake.calibration import CalibrationReport, calibrate_file, contacts
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.validate import ValidationReport, validate_file
from kpioed_drake.compensation.report import CompensationReport
from kpioed_drake.compensation.workflow import EffectsArgument, compensate_file
from kpioed_drake.design import DesignOptions, DesignReport, evaluate_file, run_design
from kpioed_drake.diagnosis import DiagnosisOptions, DiagnosisReport, diagnose_file
from kpioed_drake.effects.model import Effect
from kpioed_drake.estimation.identifiability import check_identifiability, pose_identifiability
from kpioed_drake.online import NextOptions, next_file
from kpioed_drake.options import options_from
from kpioed_drake.robot.geometry import beam_targets
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Robot, load_cell, load_robot
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.workflow import simulate_file
from kpioed_drake.study import StudyReport, run_study

__all__ = [
    "calibrate",
    "compensate",
    "design",
    "diagnose",
    "evaluate",
    "info",
    "next",
    "simulate",
    "study",
    "validate",
]

MaybePath = str | Path | None
"""A file argument that may be left out: its path (text or :class:`~pathlib.Path`), or None."""
Poses = str | Sequence[float] | Sequence[Sequence[float]] | np.ndarray | None
"""Working poses or weights as text (``"q1,...,q6"``) or numbers."""


def info(robot: str, *, cell_path: MaybePath = None) -> dict:
    """What the tool knows about a robot (``kpioed info``).

    Returns:
        dict with ``robot``, ``reach_mm``, ``q_work_deg``, ``joint_limits_deg``, ``parameters``
        (all 33 names), ``estimated`` (the 27), ``fixed`` (the 6 held at nominal), ``n_params``
        (identifiable count from a rank test at random poses), ``identifiable`` (bool),
        ``unidentifiable`` (names, if any), ``car_shift_x_mm``, ``joints`` (name and 1-based
        parent joint, 0 = the base, per joint: a tree robot's branches) and ``targets`` (1-based
        link, i.e. the joint that moves it, and offset [mm] per target). A prismatic joint's values
        in ``q_work_deg`` and ``joint_limits_deg`` are millimetres. ``pose``: what a 6-DoF probe adds.
    """
    rob = load_robot(robot)
    cell = load_cell(cell_path, robot=rob)
    rep = check_identifiability(rob, cell)
    lay = parameter_layout(rob)
    return {
        "robot": rob.name,
        "reach_mm": rob.reach,
        "q_work_deg": None if rob.q_work is None else q_to_file(rob, rob.q_work).round(6).tolist(),
        "joint_limits_deg": q_to_file(rob, np.stack([rob.lower, rob.upper], 1).T).T.round(6).tolist(),
        "parameters": list(lay.names),
        "estimated": lay.free_names,
        "fixed": [n for n in lay.names if n not in lay.free_names],
        "n_params": rep.rank,
        "identifiable": rep.identifiable,
        "unidentifiable": rep.unidentifiable,
        "car_shift_x_mm": rob.car_shift_x,
        "pose": pose_identifiability(rob, cell),
        "joints": [
            {"name": n, "parent": int(p) + 1} for n, p in zip(rob.joint_names, _parents(rob), strict=True)
        ],
        "targets": [
            {"link": int(f), "offset_mm": np.asarray(p, float).tolist()}
            for _, p, f in beam_targets(rob, cell)
        ],
    }


def _parents(rob: Robot) -> np.ndarray:
    return rob.chain.parents if rob.chain is not None else np.arange(rob.n_joints) - 1


def design(
    robot: str,
    *,
    options: DesignOptions | None = None,
    q_work_deg: Poses = None,
    q_work_file: str | Path | None = None,
    kpi_weights: Poses = None,
    given: MaybePath = None,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plot: str | Path | None = None,
    html: str | Path | None = None,
    **settings: Any,
) -> DesignReport:
    """A design for a robot in the default cell, with its files (``kpioed design``):
    :func:`kpioed_drake.design.run_design`.

    Args:
        robot: model name (``kr16``, ``notional-850-800``) or path to a robot file.
        options: a :class:`~kpioed_drake.design.DesignOptions` record (default: its defaults) ...
        **settings: ... with these of its fields replaced: ``criterion`` (``kpi``, ``param``,
            ``heuristic``), ``n``, ``sigma_mm`` [mm], ``collision``, ``solver``, ``seed``,
            ``starts``, ``start``, ``allow_infeasible``, ``certify``, ``extend``,
            ``kpi_aggregate``, ``target_var_mm2`` [mm^2], ``discriminate`` (``"A|B"``),
            ``condition_span``, ``measure`` (``pose``: a 6-DoF probe), ``sigma_deg``, ``kpi_orientation_mm``.
        q_work_deg, q_work_file, kpi_weights: the working poses [deg] and their weights.
        given: design CSV of poses already measured (their information held fixed).
        out, json_path, plot, html: the design CSV, the JSON record, a picture, a 3-D page.

    Returns:
        :class:`~kpioed_drake.design.DesignReport`.
    """
    poses = dict(q_work_deg=q_work_deg, q_work_file=q_work_file, kpi_weights=kpi_weights, given=given)
    files = dict(out=out, json_path=json_path, plot=plot, html=html)
    return run_design(robot, options_from(DesignOptions, options, **settings), **poses, **files)  # type: ignore[arg-type]


def next(  # noqa: A001 (the command's name)
    robot: str,
    data_path: str | Path,
    *,
    target_var_mm2: float,
    n: int = 5,
    sigma_mm: float = 0.02,
    seed: int = 0,
    certify: bool = True,
    max_plan: int = 60,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    data_format: MaybePath = None,
    plan: str | Path | None = None,
    force: bool = False,
    **orientation: Any,
) -> dict:
    """Online calibration, one step (``kpioed next``): :func:`kpioed_drake.online.workflow.next_file`.

    Calibrates on the data so far, evaluates tr(Cs)/3 at the estimate (a-posteriori when the fit
    rejects) and either stops (``done``: nothing written) or plans the poses still needed to reach
    the target (with the measured ones' information held fixed) and returns the ``n`` of them that
    help most now.

    Args:
        robot: model name or model file.
        data_path: the measurements so far.
        target_var_mm2: the TCP precision to reach, tr(Cs)/3 [mm^2].
        n: poses to design when not done.
        sigma_mm: the tracker's noise per coordinate [mm].
        seed: seed of the design's starts and the certificate's search.
        certify: add the certificate of the combined design.
        max_plan: most poses planned ahead (at least ``n``).
        out: design CSV of the next poses; json_path: the JSON record.
        data_format: format file of a measurement file of another layout.
        plan: design CSV carrying the plan between steps (read if it exists, then replaced by
            this step's plan; removed when done): a re-plan then never ends worse than the rest
            of the previous plan.
        force: go on with data that fails the plausibility checks, with a warning.
        **orientation: data with a 6-DoF probe's orientations: ``sigma_deg``, ``kpi_orientation_mm``,
            ``target_deg`` (:class:`~kpioed_drake.online.NextOptions`).

    Returns:
        The JSON record (``done``, ``n_measured``, ``kpi_avg_var_mm2``,
        ``predicted_kpi_avg_var_mm2``, ``n_planned``, ``min_more_poses``, ``bound_mm2``, ``efficiency``,
        ``next_q_deg``, ...) and ``summary``.
    """
    options = options_from(
        NextOptions,
        target_var_mm2=target_var_mm2,
        n=n,
        sigma_mm=sigma_mm,
        seed=seed,
        certify=certify,
        max_plan=max_plan,
        force=force,
        **orientation,
    )
    result, rob = next_file(
        robot, data_path, options, out=out, json_path=json_path, data_format=data_format, plan_path=plan
    )
    return {**result.to_dict(rob), "summary": result.summary()}


def calibrate(
    robot: str,
    data_path: str | Path | None = None,
    *,
    sigma_mm: float = 0.02,
    q_work_deg: str | None = None,
    extend: Sequence[str] = (),
    outlier_alpha: float = 0.01,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    cell_path: MaybePath = None,
    force: bool = False,
    data_format: MaybePath = None,
    strict: bool = False,
    sigma_deg: float = 0.01,
    planes: MaybePath = None,
    distances: MaybePath = None,
) -> CalibrationReport | contacts.ContactCalibrationReport:
    """Calibrate from a measurement file (``kpioed calibrate``):
    :func:`kpioed_drake.calibration.calibrate_file` with ``sigma_mm``, ``extend`` (as ``effects``),
    ``outlier_alpha``, ``force`` and ``strict`` as its
    :class:`~kpioed_drake.calibration.options.CalibrationOptions`.

    Args:
        robot: model name or YAML path; data_path: the measurement CSV.
        sigma_mm: noise standard deviation per coordinate [mm]; sigma_deg: a 6-DoF probe's
            orientation noise per tracker axis [deg] where the rows give none.
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        extend: effect texts (e.g. ``["joint_elasticity:2"]``, joints 1..n_joints): calibrate the
            geometry and these effects together (the extended model; ``out`` writes it with its
            ``effects:``); without it, the effects of an extended model file are re-estimated.
        outlier_alpha: family-wise false-alarm level of the outlier test, in [0, 1) (0: no test).
        out: calibrated robot model file (YAML; a URDF robot's ``.urdf`` plus sidecar) to write.
        json_path, plots_dir, html: the JSON report, the residual plots' folder, a 3-D page (Meshcat).
        cell_path: cell file (default ``models/cell.yaml``); force: go on with implausible data (warned).
        data_format: format file of a measurement file of another layout (docs/data-formats.md).
        strict: refuse poses that do not determine every parameter instead of holding the
            undetermined ones at nominal with a warning.
        planes, distances: plane-contact and distance files (docs/contacts.md), fitted with the points
            (``data_path`` optional): :func:`kpioed_drake.calibration.contacts.calibrate_contacts_file`.
    """
    if planes is not None or distances is not None or data_path is None:
        return contacts.contact_calibration(robot, data_path, planes, distances, locals())
    effects = tuple(extend or ())
    same = dict(
        sigma_mm=sigma_mm, sigma_deg=sigma_deg, outlier_alpha=outlier_alpha, force=force, strict=strict
    )
    options = CalibrationOptions(effects=effects, **same)  # type: ignore[arg-type]
    outputs = dict(out=out, json_path=json_path, plots_dir=plots_dir, html=html)
    return calibrate_file(
        robot,
        data_path,
        options,
        q_work_deg=q_work_deg,
        cell_path=cell_path,
        data_format=data_format,
        **outputs,
    )


def simulate(
    robot: str,
    design: str,
    out: str,
    *,
    sigma_mm: float = 0.02,
    seed: int = 0,
    effects: Sequence[str | Effect] = (),
    geometric_errors: bool = True,
    payload_kg: float = 0.0,
    truth_path: str | None = None,
    cell_path: MaybePath = None,
    n_targets: int | None = None,
    orientation_sigma_deg: float | None = None,
) -> tuple[pd.DataFrame, dict]:
    """Simulated laser-tracker data of a design file (``kpioed simulate``):
    :func:`kpioed_drake.simulation.simulate_file` with ``sigma_mm``, ``seed``, ``effects``,
    ``geometric_errors`` and ``n_targets`` as its
    :class:`~kpioed_drake.simulation.options.SimulationOptions`.

    Args:
        robot: model name or YAML path; design: design CSV; out: measurement CSV to write.
        sigma_mm: noise per coordinate [mm]; seed: seed of the true robot, tracker frame and noise.
        effects: non-geometric effects (e.g. ``["joint_elasticity:2"]``).
        geometric_errors: draw random geometric errors (False: the true robot is the nominal one).
        payload_kg: payload at the reflector [kg] (>= 0); truth_path: the true parameters' JSON.
        cell_path: cell file (default ``models/cell.yaml``).
        n_targets: targets measured at every pose (the first of the model's ``targets_mm``;
            default all): one row per pose and target, with a ``target`` column when several.
        orientation_sigma_deg: a 6-DoF probe's orientations too, noise per tracker axis [deg].

    Returns:
        (table, truth): the measurement table (pandas) and the truth dict.
    """
    options = SimulationOptions(
        sigma_mm=sigma_mm,
        seed=seed,
        effects=cast(tuple[str, ...], tuple(effects)),  # texts or Effect objects (SimulationOptions.effects)
        geometric_errors=geometric_errors,
        n_targets=n_targets,
        orientation_sigma_deg=orientation_sigma_deg,
    )
    return simulate_file(
        robot, design, out, options, payload_kg=payload_kg, truth_path=truth_path, cell_path=cell_path
    )


def diagnose(
    robot: str,
    data_path: str | Path,
    *,
    sigma_mm: float | None = None,
    json_path: MaybePath = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    force: bool = False,
    data_format: MaybePath = None,
    out: str | Path | None = None,
) -> DiagnosisReport:
    """Diagnose a measurement file (``kpioed diagnose``): :func:`kpioed_drake.diagnosis.diagnose_file`
    with ``sigma_mm`` [mm] and ``force`` as its :class:`~kpioed_drake.diagnosis.DiagnosisOptions`.

    Args:
        robot: model name or YAML path.
        data_path: the measurement CSV.
        sigma_mm: the known noise standard deviation per coordinate [mm]; None: measured on repeated
            poses, else the tracker's 0.02 mm, either checked against the residuals (the report's
            ``noise``).
        json_path: JSON report to write.
        plots_dir: folder for the residual pictures (PNG).
        html: 3-D page (Meshcat) of the residuals before and after the named extension.
        force: go on with implausible data, noted in the report.
        data_format: format file of a measurement file of another layout (docs/data-formats.md).
        out: the extended model file to write (the geometry with the named causes).
    """
    return diagnose_file(
        robot,
        data_path,
        DiagnosisOptions(sigma_mm=sigma_mm, force=force),
        json_path=json_path,
        plots_dir=plots_dir,
        html=html,
        data_format=data_format,
        out=out,
    )


def evaluate(
    robot: str,
    design: str,
    *,
    sigma_mm: float | None = None,
    q_work_deg: str | None = None,
    extend: Sequence[str] = (),
    json_path: str | Path | None = None,
    html: str | Path | None = None,
    cell_path: MaybePath = None,
    certify: bool = True,
) -> dict:
    """KPI variance, standard criterion, feasibility and certified efficiency of a design file
    (``kpioed evaluate``): :func:`kpioed_drake.design.evaluate_file`, whose docstring details the
    arguments and the returned record (mm^2, mm, deg)."""
    setup = dict(sigma_mm=sigma_mm, q_work_deg=q_work_deg, extend=extend, certify=certify)
    files = dict(json_path=json_path, html=html, cell_path=cell_path)
    return evaluate_file(robot, design, **setup, **files)  # type: ignore[arg-type]


def validate(
    robot: str,
    data_path: str | Path | None = None,
    *,
    data_format: MaybePath = None,
    tracker_frame: str | None = None,
    keep_tracker: bool | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    cell_path: MaybePath = None,
    force: bool = False,
    planes: MaybePath = None,
    distances: MaybePath = None,
    html: str | Path | None = None,
) -> ValidationReport | contacts.ContactValidationReport:
    """A model's prediction errors on measurements (``kpioed validate``), nothing fitted to the poses
    scored unless ``tracker_frame="in-sample"`` says so (``kept``: the model's tracker frame; ``cross``:
    registered on one half of the poses, scored on the other; ``html``: a 3-D page):
    :func:`kpioed_drake.calibration.validate.validate_file`, whose docstring details the arguments;
    with ``planes`` or ``distances`` (held-out contacts, docs/contacts.md) and ``data_path`` optional:
    :func:`kpioed_drake.calibration.contacts.validate_contacts_file`."""
    if planes is not None or distances is not None or data_path is None:
        return contacts.contact_validation(robot, data_path, planes, distances, locals())
    kw = dict(data_format=data_format, tracker_frame=tracker_frame, keep_tracker=keep_tracker, force=force)
    files = dict(json_path=json_path, plots_dir=plots_dir, cell_path=cell_path, html=html)
    return validate_file(robot, data_path, **kw, **files)  # type: ignore[arg-type]


def study(
    out_dir: str | Path,
    *,
    quick: bool = False,
    jobs: int | None = None,
    scheduler: Any = None,
    progress: bool = True,
    robots: list[str] | tuple[str, ...] | None = None,
    n: int = 60,
    heuristic_draws: int | None = None,
    seed: int = 0,
    figures: bool = True,
    variant: str = "default",
    bounds: bool = True,
) -> StudyReport:
    """Run (or resume) the paper's study (``kpioed study``) into ``out_dir``: Tables 6-8, the report
    and Figures 7-8 (:func:`kpioed_drake.study.workflow.run_study`, whose docstring details the
    arguments)."""
    run = dict(quick=quick, jobs=jobs, scheduler=scheduler, progress=progress, figures=figures)
    designs = dict(
        robots=robots, n=n, heuristic_draws=heuristic_draws, seed=seed, variant=variant, bounds=bounds
    )
    return run_study(out_dir, **run, **designs)  # type: ignore[arg-type]


def compensate(
    robot: str,
    *,
    program: str | Path | None = None,
    targets: str | Path | None = None,
    nominal: str | None = None,
    target: int = 1,
    angles: str = "model",
    out: str | Path,
    effects: EffectsArgument = (),
    allow_unreachable: bool = False,
    cell_path: MaybePath = None,
) -> CompensationReport:
    """The joint values with which a calibrated model reaches a nominal program's poses or given
    points (``kpioed compensate``): :func:`kpioed_drake.compensation.workflow.compensate_file`,
    whose docstring details the arguments."""
    return compensate_file(
        robot,
        program=program,
        targets=targets,
        out=out,
        nominal=nominal,
        target=target,
        angles=angles,
        effects=effects,
        allow_unreachable=allow_unreachable,
        cell_path=cell_path,
    )
