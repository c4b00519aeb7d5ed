"""The design workflows: ``kpioed design`` (:func:`run_design`) and ``make demo`` (:func:`demo`).

:func:`run_design` builds the problem of a robot in the default cell, computes the design
(:func:`~kpioed_drake.design.optimize.optimize_design`) and writes the design CSV (degrees), the
JSON record and a picture; with several working poses (``--q-work`` repeated or a CSV of
working poses), poses already measured (``--given``) or a target variance (``--target-var``,
:func:`~kpioed_drake.design.target.design_for_target`); and (unless ``--no-certify``) the
optimality certificate (:func:`~kpioed_drake.design.approximate.certificate.certify`) of the design.
:func:`demo` compares the heuristic, the standard (``param``) and the KPI design of one robot (default: the
KR 16) in the default cell.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_count, check_paths, check_positive, check_seed, require
from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.common import DESIGN_METHODS, SOLVERS, method_label
from kpioed_drake.design.discriminate.conditions import read_given_conditions
from kpioed_drake.design.discriminate.plan import plan_design
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.plots import plot_design_poses
from kpioed_drake.design.result import DesignError, DesignResult, json_record
from kpioed_drake.design.target import design_for_target
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.outputs import Outputs, atomic_write_json
from kpioed_drake.robot.models import Robot, load_robot
from kpioed_drake.scene3d import design_page
from kpioed_drake.tracker import csvio

WEIGHT_COLUMN = "weight"
"""Optional column of a working-pose CSV: the pose's weight in the mean KPI."""


def read_working_poses(path: str | Path, robot: Robot) -> tuple[np.ndarray, np.ndarray | None]:
    """Working poses (or samples of a working path) from a CSV: ``q1_deg`` .. ``q6_deg`` and an
    optional ``weight`` column.

    Returns:
        q_work (K, 6) [rad] and weights (K,) (None without the column).

    Raises:
        InputError: missing file or column, bad numbers, angles outside the limits.
    """
    q = csvio.read_design(path, robot)
    header, data = csvio.read_csv_table(path, csvio.q_columns(robot))
    if WEIGHT_COLUMN not in header:
        return q, None
    return q, csvio.parse_float_column(path, header, data, WEIGHT_COLUMN)


def _working_poses(robot: Robot, q_work_deg, q_work_file) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(6,) or (K, 6) working poses [rad] (None: the model's) and weights from the file, if any."""
    if q_work_file is not None:
        if q_work_deg is not None:
            raise InputError(
                "give the working poses either by q_work_deg or by q_work_file, not both",
                fields=("q_work_deg", "q_work_file"),
            )
        return read_working_poses(q_work_file, robot)
    if q_work_deg is None:
        return None, None
    if isinstance(q_work_deg, str):
        return csvio.parse_q_work(q_work_deg, robot), None
    if all(isinstance(v, str) for v in q_work_deg):
        return np.stack([csvio.parse_q_work(v, robot) for v in q_work_deg]), None
    q = np.asarray(q_work_deg, dtype=float)
    rows = [csvio.parse_q_work(",".join(repr(float(v)) for v in row), robot) for row in np.atleast_2d(q)]
    return (rows[0] if q.ndim == 1 else np.stack(rows)), None


def _check_discriminate(discriminate, condition_span, criterion, target_var_mm2, certify) -> None:
    """InputError where :func:`run_design`'s ``discriminate`` meets an argument it excludes."""
    if discriminate is not None:
        require(
            criterion == "kpi",
            f"discriminate replaces criterion (got {criterion!r})",
            fields=("discriminate", "criterion"),
        )
        require(
            target_var_mm2 is None and not certify,
            "discriminate takes no target_var_mm2 or certify",
            fields=("discriminate", "target_var_mm2", "certify"),
        )
    require(
        discriminate is not None or condition_span is None,
        "condition_span goes with discriminate",
        fields=("condition_span", "discriminate"),
    )


def run_design(
    robot_name: str,
    *,
    criterion: str = "kpi",
    n: int = 60,
    sigma_mm: float | None = None,
    q_work_deg=None,
    collision: bool = True,
    solver: str = "snopt",
    seed: int = 0,
    starts: int = 1,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    allow_infeasible: bool = False,
    plot: str | Path | None = None,
    extend=(),
    q_work_file: str | Path | None = None,
    kpi_weights=None,
    kpi_aggregate: str = "mean",
    given: str | Path | None = None,
    target_var_mm2: float | None = None,
    html: str | Path | None = None,
    start: str | None = None,
    certify: bool | None = None,
    discriminate: str | None = None,
    condition_span: str | None = None,
) -> DesignResult:
    """Compute a design for a robot in the default cell and write its files (what ``kpioed design`` runs).

    Args:
        robot_name: model name (``kr16``, ``notional-850-800``) or path to a robot YAML file.
        criterion, n, collision, solver, seed, starts, allow_infeasible, start: see
            :func:`optimize_design`.
        sigma_mm: measurement noise per coordinate [mm] (default: the cell's).
        q_work_deg: working pose [deg], a ``"q1,...,q6"`` string or 6 numbers (default: the model
            file's); several working poses (K KPIs, e.g. a working path sampled at K points): a
            list of K such strings or a (K, 6) array [deg].
        q_work_file: CSV of K working poses (``q1_deg`` .. ``q6_deg`` [deg], optional ``weight``),
            instead of ``q_work_deg``.
        kpi_weights: (K,) positive weights of the working poses (normalised to sum 1; default:
            the file's ``weight`` column, else equal).
        kpi_aggregate: ``mean`` (weighted mean of the K variances tr(Cs_k)/3) or ``max`` (the
            worst working pose, no weights).
        given: design CSV of poses already measured (sequential re-identification): their
            information is held fixed and ``n`` new poses are optimised; ``out`` gets the new
            poses, the values are those of the combined design and the JSON's ``given`` record has
            the given poses' own tr(Cs)/3.
        target_var_mm2: find the fewest poses whose design reaches tr(Cs)/3 <= this [mm^2]
            (:func:`~kpioed_drake.design.target.design_for_target`; ``n`` and ``allow_infeasible``
            are then not used: only successful, feasible designs count).
        out: design CSV (``q1_deg`` .. ``q6_deg`` plus per-pose ``incidence_deg`` and
            ``min_clearance_mm``), written atomically.
        json_path: JSON record of the run, written atomically (also when the design is rejected).
        plot: picture of the poses (.png, .pdf or .svg).
        html: self-contained 3-D page (Drake Meshcat) of the poses, their feasibility, the beams, the
            smallest clearances and the TCP's 95 % ellipsoid at the (first) working pose.
        extend: model extensions (e.g. ``["joint_elasticity:2"]``): the design then also estimates
            their parameters and its KPI variance includes them (:func:`problem.make_problem`).
        certify: add the optimality certificate of the design (``res.certificate``, in the JSON
            record ``bound_mm2``, ``efficiency``, ``design_beyond_search`` and ``certificate``):
            :func:`~kpioed_drake.design.approximate.certificate.certify` with this ``collision`` and ``seed``,
            a bound on tr(Cs)/3 whatever the criterion (with ``given``: of the combined design).
            None (default): certify unless ``discriminate``; False: ``bound_mm2`` and
            ``efficiency`` are null. Costs 4-13 s once per robot, cell and setup (then cached on
            disk, :mod:`~kpioed_drake.design.approximate.certcache`) and 1-4 s per design.
        discriminate: ``"A|B"``, two competing explanations (effects, e.g.
            ``"joint_scale:2=300|gear_cyclic:2:1"``): poses that tell them apart
            (:func:`~kpioed_drake.design.discriminate.design.discrimination_design`; instead of
            ``criterion``; ``given`` is the first data set). The JSON record's ``discrimination``
            has the assumed sizes and each test's non-centrality and power before and after. A
            pair that needs temperature or time gets a measurement plan
            (:func:`~kpioed_drake.design.discriminate.plan.plan_design`: each pose in two blocks; the CSV's
            ``block`` and ``temperature_offset_K`` / ``time_offset_s``; the record's ``plan``).
        condition_span: with ``discriminate``, the span of block 2 from block 1 (``"3K"``,
            ``"600s"``, ``"10min"``, ``"3K,600s"``; None: the span for power 0.8, rounded up;
            ``given``'s ``temperature_C`` / ``time_s`` columns, if any, are the first data's).

    Returns:
        :class:`DesignResult`.

    Raises:
        InputError: bad input. DesignError: solver failure or infeasible design.
    """
    _check_discriminate(discriminate, condition_span, criterion, target_var_mm2, certify)
    require(
        criterion in DESIGN_METHODS,
        f"criterion: expected one of {', '.join(DESIGN_METHODS)}, got {criterion!r}",
    )
    require(solver in SOLVERS, f"solver: expected one of {', '.join(SOLVERS)}, got {solver!r}")
    check_count("n", n)
    check_count("starts", starts)
    check_seed(seed)
    check_sigma(sigma_mm, allow_none=True)
    check_positive("target_var_mm2", target_var_mm2, allow_none=True)
    check_paths(robot=robot_name, inputs=[q_work_file, given], outputs=[out, json_path], plot=plot, html=html)
    robot = load_robot(robot_name)
    q_work, file_weights = _working_poses(robot, q_work_deg, q_work_file)
    problem = make_problem(
        robot,
        q_work=q_work,
        sigma_mm=sigma_mm,
        extend=extend,
        kpi_weights=file_weights if kpi_weights is None else kpi_weights,
        kpi_aggregate=kpi_aggregate,
    )
    q_given = None if given is None else csvio.read_design(given, robot)
    common = dict(
        criterion=criterion, collision=collision, solver=solver, seed=seed, starts=starts, start=start
    )
    try:
        if discriminate is not None:
            options = {k: v for k, v in common.items() if k != "criterion"}
            conds = read_given_conditions(given, len(q_given)) if given is not None else None
            res, problem = plan_design(
                problem,
                discriminate,
                n=n,
                given=q_given,
                given_conditions=conds,
                condition_span=condition_span,
                allow_infeasible=allow_infeasible,
                **options,
            )
            criterion = res.criterion
        elif target_var_mm2 is None:
            res = optimize_design(problem, n=n, allow_infeasible=allow_infeasible, given=q_given, **common)
        else:
            res = design_for_target(problem, target_var_mm2, given=q_given, **common)
    except DesignError as exc:
        if json_path is not None and exc.result is not None:
            atomic_write_json(json_path, json_record(exc.result, problem, error=str(exc)))
        raise
    if certify or (certify is None and discriminate is None):
        res.certificate = certificate.certify(problem, res.q, collision=collision, seed=seed, given=q_given)
    with Outputs() as staged:
        if out is not None:
            extra = {
                "incidence_deg": np.array([r["incidence_deg"] for r in res.reports]),
                "min_clearance_mm": np.array([r["min_clearance_mm"] for r in res.reports]),
                **(getattr(res, "plan_columns", None) or {}),  # a measurement plan's block and condition
            }
            staged.add_text(out, csvio.design_csv_text(res.q, extra, robot=problem.robot))
        if json_path is not None:
            staged.add_json(json_path, json_record(res, problem))
        if plot is not None:
            plot_design_poses(
                problem.robot,
                problem.cell,
                res.q,
                staged.folder(Path(plot).parent) / Path(plot).name,
                q_work=problem.q_works[0],
                infeasible=np.array([not r["feasible"] for r in res.reports]),
                title=f"{robot.name}: {criterion} design, {res.n} poses, "
                f"tr(Cs)/3 = {res.kpi_avg_var_mm2:.4g} mm^2",
            )
        if html is not None:
            staged.add_text(html, design_page(problem.robot, problem.cell, res.q, q_work=problem.q_works[0],
                                              Cs=first_kpi_covariance(problem, res.q)))  # fmt: skip
        staged.commit()
    return res


def first_kpi_covariance(problem, q) -> np.ndarray:
    """(3, 3) covariance Cs [mm^2] of the TCP at the first working pose for the design ``q``."""
    Cp, _ = problem.covariances(q)
    Js = problem.Js_each()[0]
    return Js @ Cp @ Js.T


def demo(out_dir: str | Path = "out/demo", *, robot: str = "kr16", n: int = 60, seed: int = 0) -> dict:
    """KPI design of ``robot`` in the default cell, compared with the heuristic and standard designs.

    Prints tr(Cs)/3 of the heuristic, the standard (``param``) and the KPI design (default start:
    the approximate design) with each one's efficiency (certificate of tr(Cs)/3), and writes
    ``<out_dir>/<robot>-kpi-design.csv``, ``.png`` and ``.html`` (a 3-D Meshcat page of the KPI
    design with the heuristic's confidence ellipsoid beside its own).

    Returns:
        {criterion: tr(Cs)/3 [mm^2]}.
    """
    out_dir = Path(out_dir)
    problem = make_problem(robot)
    print(f"{robot}: {n} poses, collision avoidance on, SNOPT; average TCP variance tr(Cs)/3 [mm^2]")
    results = {}
    for crit in ("heuristic", "param", "kpi"):
        res = optimize_design(problem, criterion=crit, n=n, seed=seed)
        results[crit] = res
        label = method_label(crit)
        extra = "" if crit == "heuristic" else f"  ({res.solve_s:.1f} s, {res.status})"
        eff = certificate.certify(problem, res.q, seed=seed)["efficiency"]  # its tr(Cs)/3's efficiency
        print(f"  {label:18s} {res.kpi_avg_var_mm2:.4f}  efficiency {eff:.3f}{extra}")
    h, p, k = (results[c].kpi_avg_var_mm2 for c in ("heuristic", "param", "kpi"))
    print(
        f"  KPI vs heuristic: {100 * (1 - k / h):.0f} % lower; vs standard: {100 * (1 - k / p):.0f} % lower"
    )
    kres, hres = results["kpi"], results["heuristic"]
    stem = out_dir / f"{robot}-kpi-design"
    page = design_page(
        problem.robot,
        problem.cell,
        kres.q,
        reports=None,
        q_work=problem.q_work,
        Cs=first_kpi_covariance(problem, kres.q),
        compare=("heuristic", hres.q, first_kpi_covariance(problem, hres.q)),
    )
    with Outputs() as staged:
        staged.add_text(stem.with_suffix(".csv"), csvio.design_csv_text(kres.q, robot=problem.robot))
        plot_design_poses(
            problem.robot,
            problem.cell,
            kres.q,
            staged.folder(out_dir) / f"{stem.name}.png",
            q_work=problem.q_work,
            title=f"{robot}: KPI design, {n} poses, tr(Cs)/3 = {k:.3f} mm^2",
        )
        staged.add_text(stem.with_suffix(".html"), page)
        staged.commit()
    print(f"  feasible (Drake check): {kres.feasible}; wrote {stem}.csv and {stem}.png")
    print(f"  3-D scene (open in a browser; no network needed): {stem}.html")
    return {c: r.kpi_avg_var_mm2 for c, r in results.items()}
