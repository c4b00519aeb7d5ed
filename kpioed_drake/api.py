"""The Python API: one documented function per ``kpioed`` command, and the only entry the CLI calls.

Example::

    from kpioed_drake import api
    print(api.info("kr16")["n_params"])                      # 27
    report = api.evaluate("kr16", "design.csv")               # the design's KPI variance
    print(report["kpi_avg_var_mm2"], report["feasible"])

Every function checks its arguments and its output paths before any work (an output may not
overwrite an input, name a folder, or be named twice) and raises
:class:`~kpioed_drake.errors.InputError` with a message naming the argument, file, row or field.
Outputs are written only after everything succeeded, each atomically. Units follow the files:
millimetres and degrees in and out.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from kpioed_drake import calibration, diagnosis, simulation, validation
from kpioed_drake import study as study_pkg
from kpioed_drake.design import DESIGN_METHODS, SOLVERS, DesignResult, run_design
from kpioed_drake.design.certificate import certificate_fields
from kpioed_drake.design.certificate import certify as certify_design
from kpioed_drake.designio import parse_q_work, read_design
from kpioed_drake.errors import InputError
from kpioed_drake.feasibility import FeasibilityChecker, summarize
from kpioed_drake.identifiability import check_identifiability
from kpioed_drake.models import load_cell, load_robot, robot_path
from kpioed_drake.outputs import Outputs, check_output_paths
from kpioed_drake.parameters import parameter_layout
from kpioed_drake.problem import make_problem
from kpioed_drake.scene3d import design_page

PICTURE_SUFFIXES = (".png", ".pdf", ".svg")
HTML_SUFFIXES = (".html", ".htm")


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


def _seed(seed) -> None:
    _require(
        isinstance(seed, int | np.integer) and seed >= 0, f"seed: expected an integer >= 0, got {seed!r}"
    )


def _positive(name: str, value, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    ok = isinstance(value, int | float | np.number) and math.isfinite(value) and value > 0
    _require(ok, f"{name}: expected a finite number > 0, got {value!r}")


def _robot_file(robot: str) -> str | None:
    """The robot's file when the user named one (an input that no output may overwrite)."""
    path = robot_path(robot)
    return str(path) if Path(robot).suffix in (".yaml", ".yml") else None


def _suffixes(**paths) -> dict:
    kinds = {"plot": PICTURE_SUFFIXES, "html": HTML_SUFFIXES}
    return {p: kinds[k] for k, p in paths.items() if p}


def info(robot: str, *, cell_path=None) -> dict:
    """What the tool knows about a robot (``kpioed info``).

    Returns:
        dict with ``robot``, ``reach_mm``, ``q_work_deg``, ``joint_limits_deg``, ``parameters``
        (all 33 names), ``estimated`` (the 27), ``fixed`` (the 6 held at nominal), ``n_params``
        (identifiable count from a rank test at random poses), ``identifiable`` (bool),
        ``unidentifiable`` (names, if any) and ``car_shift_x_mm``.
    """
    rob = load_robot(robot)
    rep = check_identifiability(rob, load_cell(cell_path, robot=rob))
    lay = parameter_layout(rob)
    return {
        "robot": rob.name,
        "reach_mm": rob.reach,
        "q_work_deg": None if rob.q_work is None else np.rad2deg(rob.q_work).round(6).tolist(),
        "joint_limits_deg": np.rad2deg(np.stack([rob.lower, rob.upper], 1)).round(6).tolist(),
        "parameters": list(lay.names),
        "estimated": lay.free_names,
        "fixed": [n for n in lay.names if n not in lay.free_names],
        "n_params": rep.rank,
        "identifiable": rep.identifiable,
        "unidentifiable": rep.unidentifiable,
        "car_shift_x_mm": rob.car_shift_x,
    }


def evaluate(
    robot: str,
    design: str | Path,
    *,
    sigma_mm: float | None = None,
    q_work_deg: str | None = None,
    extend=(),
    json_path: str | Path | None = None,
    html: str | Path | None = None,
    cell_path=None,
    certify: bool = False,
) -> dict:
    """KPI variance, standard criterion and feasibility of a design file (``kpioed evaluate``).

    Args:
        robot: model name or path of a model YAML file.
        design: CSV with columns ``q1_deg`` ... ``q6_deg``.
        sigma_mm: measurement noise per coordinate [mm] (default: the cell's).
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        extend: model extensions (``"joint_elasticity:2"``, ``"gear_cyclic:4:2"``) whose parameters
            are estimated too; the KPI variance then includes them.
        json_path: write the returned dict as JSON.
        html: write a 3-D page (Meshcat) of the poses, their feasibility and the KPI ellipsoid.
        certify: add ``bound_mm2`` (lower bound on tr(Cs)/3 of any design of as many poses avoiding
            collisions), ``efficiency``, ``design_beyond_search``, ``certificate`` (:func:`certify`).

    Returns:
        dict with ``kpi_avg_var_mm2`` (tr(Cs)/3), ``kpi_cov_mm2`` (3x3), ``param_crit`` (scaled
        tr(Cp)), ``n_params``, ``n_poses``, ``feasible`` and ``poses`` (per-pose feasibility);
        with ``certify`` the certificate's fields.
    """
    _positive("sigma_mm", sigma_mm, allow_none=True)
    check_output_paths(
        inputs=[design, _robot_file(robot)], outputs=[json_path, html], suffixes=_suffixes(html=html)
    )
    rob = load_robot(robot)
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    prob = make_problem(rob, cell_path=cell_path, q_work=qw, sigma_mm=sigma_mm, extend=extend)
    q = read_design(design, rob)
    if len(q) < prob.min_poses():
        raise InputError(
            f"{design}: {len(q)} poses cannot determine {prob.n_params} parameters "
            f"(3 coordinates per pose: at least {prob.min_poses()} poses are needed)"
        )
    Cp, Cs = prob.covariances(q)
    reports = FeasibilityChecker(prob.robot, prob.cell).check(q)
    result = {
        "robot": rob.name,
        "n_poses": int(len(q)),
        "n_params": prob.n_params,
        "extensions": [e.name for e in prob.extensions],
        "sigma_mm": prob.sigma,
        "q_work_deg": np.rad2deg(prob.q_work).round(6).tolist(),
        "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
        "kpi_cov_mm2": Cs.tolist(),
        "param_crit": float(np.sum(np.diag(Cp) * prob.scale**2)),
        "feasible": all(r.feasible for r in reports),
        "feasibility": summarize(reports),
        "poses": [r.as_dict() for r in reports],
    }
    if certify:
        result.update(certificate_fields(certify_design(prob, q, collision=True)))
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, result)
        if html:
            page = design_page(prob.robot, prob.cell, q, reports=reports, q_work=prob.q_work, Cs=Cs)
            staged.add_text(html, page)
        staged.commit()
    return result


def design(
    robot: str,
    *,
    criterion: str = "kpi",
    n: int = 60,
    collision: bool = True,
    solver: str = "snopt",
    seed: int = 0,
    starts: int = 1,
    sigma_mm: float | None = None,
    q_work_deg=None,
    q_work_file: str | Path | None = None,
    kpi_weights=None,
    kpi_aggregate: str = "mean",
    given: str | Path | None = None,
    target_var_mm2: float | None = None,
    extend=(),
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plot: str | Path | None = None,
    html: str | Path | None = None,
    allow_infeasible: bool = False,
    start: str | None = None,
    certify: bool = False,
) -> DesignResult:
    """Optimum experimental design of measurement poses (``kpioed design``, paper eq. 24).

    Args:
        robot: model name or YAML path.
        criterion: one of :data:`~kpioed_drake.design.DESIGN_METHODS` (``kpi``, ``param``, ``d``,
            ``o1`` or ``heuristic``).
        n: number of poses; collision: collision and laser-beam clearance (paper "CA");
            solver: ``snopt`` or ``ipopt``; seed: seed of the heuristic start; starts: number of
            starts (the best is kept).
        sigma_mm: noise per coordinate [mm] (default: the cell's).
        q_work_deg: working pose [deg] (``"q1,...,q6"`` or 6 numbers), or K of them (a list of
            strings or a (K, 6) array) for several KPIs; q_work_file: a CSV of working poses
            (``q1_deg`` .. ``q6_deg``, optional ``weight``) instead.
        kpi_weights: (K,) weights of the working poses; kpi_aggregate: ``mean`` (weighted mean of
            the K tr(Cs_k)/3) or ``max`` (the worst).
        given: design CSV of poses already measured: ``n`` new poses are added to them (their
            information held fixed; paper 3.1, re-identification after a work cycle).
        target_var_mm2: find the fewest poses whose design reaches tr(Cs)/3 <= this [mm^2].
        extend: model extensions estimated with the geometry.
        out, json_path, plot, html: design CSV, JSON record, picture (.png/.pdf/.svg) and 3-D page.
        allow_infeasible: return (and write) a failed or infeasible design instead of raising.
        start: ``heuristic``, ``approximate`` (``kpi`` only) or None (default); certify: add the
            optimality certificate (:func:`~kpioed_drake.design.certify`).

    Returns:
        :class:`~kpioed_drake.design.DesignResult`.

    Raises:
        InputError: bad input. DesignError: solver failure or infeasible design (exit status 3).
    """
    _require(
        criterion in DESIGN_METHODS,
        f"criterion: expected one of {', '.join(DESIGN_METHODS)}, got {criterion!r}",
    )
    _require(solver in SOLVERS, f"solver: expected one of {', '.join(SOLVERS)}, got {solver!r}")
    _require(isinstance(n, int | np.integer) and n >= 1, f"n: expected a number of poses >= 1, got {n!r}")
    _require(
        isinstance(starts, int | np.integer) and starts >= 1,
        f"starts: expected an integer >= 1, got {starts!r}",
    )
    _seed(seed)
    _positive("sigma_mm", sigma_mm, allow_none=True)
    _positive("target_var_mm2", target_var_mm2, allow_none=True)
    check_output_paths(
        inputs=[_robot_file(robot), q_work_file, given],
        outputs=[out, json_path, plot, html],
        suffixes=_suffixes(plot=plot, html=html),
    )
    return run_design(
        robot,
        criterion=criterion,
        n=n,
        collision=collision,
        solver=solver,
        seed=seed,
        starts=starts,
        sigma_mm=sigma_mm,
        q_work_deg=q_work_deg,
        q_work_file=q_work_file,
        kpi_weights=kpi_weights,
        kpi_aggregate=kpi_aggregate,
        given=given,
        target_var_mm2=target_var_mm2,
        extend=extend,
        out=out,
        json_path=json_path,
        plot=plot,
        html=html,
        allow_infeasible=allow_infeasible,
        start=start,
        certify=certify,
    )


def simulate(
    robot: str,
    design: str | Path,
    out: str | Path,
    *,
    sigma_mm: float = 0.02,
    seed: int = 0,
    effects=(),
    geometric_errors: bool = True,
    payload_kg: float = 0.0,
    truth_path: str | Path | None = None,
):
    """Simulated laser-tracker data of a design (``kpioed simulate``).

    Args:
        robot: model name or YAML path; design: design CSV; out: measurement CSV to write.
        sigma_mm: noise per coordinate [mm]; seed: seed of the true robot, tracker frame and noise.
        effects: non-geometric effects (e.g. ``["joint_elasticity:2"]``).
        geometric_errors: draw random geometric errors (False: the true robot is the nominal one).
        payload_kg: payload at the reflector [kg] (>= 0).
        truth_path: also write the true parameters as JSON.

    Returns:
        (table, truth): the measurement table (pandas) and the truth dict.
    """
    _positive("sigma_mm", sigma_mm)
    _seed(seed)
    ok = isinstance(payload_kg, int | float | np.number) and math.isfinite(payload_kg) and payload_kg >= 0
    _require(ok, f"payload_kg: expected a finite number >= 0, got {payload_kg!r}")
    check_output_paths(inputs=[design, _robot_file(robot)], outputs=[out, truth_path])
    return simulation.simulate_file(
        robot,
        design,
        out,
        sigma_mm=sigma_mm,
        seed=seed,
        effects=effects,
        geometric_errors=geometric_errors,
        payload_kg=payload_kg,
        truth_path=truth_path,
    )


def calibrate(
    robot: str,
    data: str | Path,
    *,
    sigma_mm: float = 0.02,
    q_work_deg: str | None = None,
    extend=(),
    outlier_alpha: float = 0.01,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    force: bool = False,
    data_format: str | Path | None = None,
):
    """Calibrate the robot's parameters from measured data (``kpioed calibrate``).

    Args:
        robot: model name or YAML path; data: measurement CSV (SPEC format).
        sigma_mm: noise per coordinate [mm]; q_work_deg: ``"q1,...,q6"`` [deg] working pose.
        extend: effects fitted with the geometry (then only ``json_path`` is written).
        outlier_alpha: family-wise false-alarm level of the outlier test, in [0, 1) (0: no test).
        out: calibrated robot model (YAML); json_path: JSON report; plots_dir: residual plots;
            html: 3-D page of measured vs predicted points.
        force: go on with data that fails the plausibility checks (:mod:`kpioed_drake.plausibility`).
        data_format: format file of a measurement file of another layout (docs/data-formats.md).

    Returns:
        :class:`~kpioed_drake.calibration.CalibrationReport`, or with ``extend`` a JSON-ready dict.
    """
    _positive("sigma_mm", sigma_mm)
    ok = isinstance(outlier_alpha, int | float) and 0 <= outlier_alpha < 1
    _require(ok, f"outlier_alpha: expected a number in [0, 1), got {outlier_alpha!r}")
    check_output_paths(
        inputs=[data, _robot_file(robot), data_format],
        outputs=[out, json_path, html],
        folders=[plots_dir],
        suffixes=_suffixes(html=html),
    )
    return calibration.calibrate_file(
        robot,
        data,
        sigma_mm=sigma_mm,
        q_work_deg=q_work_deg,
        extend=extend,
        outlier_alpha=outlier_alpha,
        out=out,
        json_path=json_path,
        plots_dir=plots_dir,
        html=html,
        force=force,
        data_format=data_format,
    )


def diagnose(
    robot: str,
    data: str | Path,
    *,
    sigma_mm: float = 0.02,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
    html: str | Path | None = None,
    force: bool = False,
    data_format: str | Path | None = None,
):
    """Model-discrepancy diagnosis (``kpioed diagnose``): does the model explain the data, what is missing?

    Args:
        robot: model name or YAML path; data: measurement CSV.
        sigma_mm: the known noise per coordinate [mm].
        json_path, plots_dir, html: JSON report, residual pictures, 3-D page before/after.
        force: go on with data that fails the plausibility checks (:mod:`kpioed_drake.plausibility`).
        data_format: format file of a measurement file of another layout (docs/data-formats.md).

    Returns:
        :class:`~kpioed_drake.diagnosis.DiagnosisReport`.
    """
    _positive("sigma_mm", sigma_mm)
    check_output_paths(
        inputs=[data, _robot_file(robot), data_format],
        outputs=[json_path, html],
        folders=[plots_dir],
        suffixes=_suffixes(html=html),
    )
    return diagnosis.diagnose_file(
        robot,
        data,
        sigma_mm=sigma_mm,
        json_path=json_path,
        plots_dir=plots_dir,
        html=html,
        force=force,
        data_format=data_format,
    )


def study(
    out_dir: str | Path,
    *,
    quick: bool = False,
    robots=None,
    n: int = 60,
    heuristic_draws: int | None = None,
    seed: int = 0,
    jobs: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    variant: str = "default",
):
    """The paper's studies, Tables 6-8 and Figures 7-8 (``kpioed study``; resumable).

    Args:
        out_dir: output folder (results.csv, tables, report.md, designs/, tasks/).
        quick: the KUKA robots and 6 notional robots, 3 heuristic draws.
        robots: robot names (default: the study's).
        n: poses per design; heuristic_draws: seeded heuristic draws (default 10, quick 3);
        seed: first seed; jobs: local worker processes; scheduler: Dask scheduler address.
        progress: show a progress bar; variant: problem variant (``study.VARIANTS``).

    Returns:
        :class:`~kpioed_drake.study.StudyResult`.
    """
    _seed(seed)
    _require(isinstance(n, int | np.integer) and n >= 1, f"n: expected a number of poses >= 1, got {n!r}")
    if heuristic_draws is not None:
        ok = isinstance(heuristic_draws, int | np.integer) and heuristic_draws >= 1
        _require(ok, f"heuristic_draws: expected an integer >= 1, got {heuristic_draws!r}")
    if jobs is not None:
        _require(
            isinstance(jobs, int | np.integer) and jobs >= 1, f"jobs: expected an integer >= 1, got {jobs!r}"
        )
    if robots is not None:
        _require(len(robots) > 0, "robots: expected at least one robot name")
    _require(not Path(out_dir).is_file(), f"{out_dir}: is a file; expected a folder for the study")
    return study_pkg.run_study(
        out_dir,
        quick=quick,
        jobs=jobs,
        scheduler=scheduler,
        progress=progress,
        robots=robots,
        n=n,
        heuristic_draws=heuristic_draws,
        seed=seed,
        variant=variant,
    )


def validate(
    robot: str,
    data: str | Path,
    *,
    data_format: str | Path | None = None,
    keep_tracker: bool = False,
    json_path: str | Path | None = None,
    plots_dir: str | Path | None = None,
):
    """Prediction errors of a (calibrated) model on fresh measurements (``kpioed validate``).

    Only the tracker frame is re-registered (rigid, 6 DoF), unless ``keep_tracker``.

    Args:
        robot: model name or YAML path (e.g. written by ``kpioed calibrate --out``).
        data: measurement file (SPEC layout, or another layout with ``data_format``).
        data_format: format file (``docs/data-formats.md``).
        keep_tracker: use the model's tracker pose instead of re-registering it.
        json_path: JSON report (``n_poses``, ``rms_mm``, ``mean_error_mm``, ``p95_error_mm``,
            ``max_error_mm``, ``errors_mm``); plots_dir: folder for the error plot.

    Returns:
        :class:`~kpioed_drake.validation.ValidationResult`.
    """
    _require(isinstance(keep_tracker, bool), f"keep_tracker: expected True or False, got {keep_tracker!r}")
    check_output_paths(
        inputs=[data, _robot_file(robot), data_format], outputs=[json_path], folders=[plots_dir]
    )
    return validation.validate_file(
        robot,
        data,
        data_format=data_format,
        keep_tracker=keep_tracker,
        json_path=json_path,
        plots_dir=plots_dir,
    )
