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

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_paths
from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.discriminate.conditions import read_given_conditions
from kpioed_drake.design.discriminate.plan import plan_design
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.options import DesignOptions
from kpioed_drake.design.plots import plot_design_poses
from kpioed_drake.design.report import DesignError, DesignReport, json_record, tcp_record
from kpioed_drake.design.settings import method_label
from kpioed_drake.design.starts import resolve_start
from kpioed_drake.design.target import design_for_target
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.files import designs
from kpioed_drake.files.tables import read_joint_table
from kpioed_drake.outputs import Outputs, atomic_write_json
from kpioed_drake.robot.models import Robot, load_robot
from kpioed_drake.scene3d import design_page

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
    table = read_joint_table(path, robot, optional=(WEIGHT_COLUMN,), empty=designs.NO_POSES)
    return table.q, table.values.get(WEIGHT_COLUMN)


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
        return designs.parse_q_work(q_work_deg, robot), None
    if all(isinstance(v, str) for v in q_work_deg):
        return np.stack([designs.parse_q_work(v, robot) for v in q_work_deg]), None
    q = np.asarray(q_work_deg, dtype=float)
    rows = [designs.parse_q_work(",".join(repr(float(v)) for v in row), robot) for row in np.atleast_2d(q)]
    return (rows[0] if q.ndim == 1 else np.stack(rows)), None


def run_design(
    robot_name: str,
    options: DesignOptions | None = None,
    *,
    q_work_deg: str | Sequence | np.ndarray | None = None,
    q_work_file: str | Path | None = None,
    kpi_weights: str | Sequence | np.ndarray | None = None,
    given: str | Path | None = None,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    plot: str | Path | None = None,
    html: str | Path | None = None,
) -> DesignReport:
    """Compute a design for a robot in the default cell and write its files (what ``kpioed design``
    runs): load the robot and the pose files once, build the problem, design, certify, write.

    Args:
        robot_name: model name (``kr16``, ``notional-850-800``) or path to a robot YAML file.
        options: :class:`~kpioed_drake.design.options.DesignOptions` (criterion, size, solver,
            target variance, discrimination, certificate).
        q_work_deg: working pose [deg], a ``"q1,...,q6"`` string or 6 numbers (default: the model
            file's); several working poses (K KPIs, e.g. a working path sampled at K points): a
            list of K such strings or a (K, 6) array [deg].
        q_work_file: CSV of K working poses (``q1_deg`` .. ``q6_deg`` [deg], optional ``weight``),
            instead of ``q_work_deg``.
        kpi_weights: (K,) positive weights of the working poses (normalised to sum 1; default:
            the file's ``weight`` column, else equal).
        given: design CSV of poses already measured (sequential re-identification): their
            information is held fixed and ``n`` new poses are optimised; ``out`` gets the new
            poses, the values are those of the combined design and the JSON's ``given`` record has
            the given poses' own tr(Cs)/3. With ``discriminate`` the first data set (its
            ``temperature_C`` / ``time_s`` columns, if any, the first data's conditions).
        out: design CSV (``q1_deg`` .. ``q6_deg`` plus per-pose ``incidence_deg`` and
            ``min_clearance_mm``; a measurement plan's ``block`` and condition offsets), written
            atomically.
        json_path: JSON record of the run, written atomically (also when the design is rejected).
        plot: picture of the poses (.png, .pdf or .svg).
        html: self-contained 3-D page (Drake Meshcat) of the poses, their feasibility, the beams, the
            smallest clearances and the TCP's 95 % ellipsoid at the (first) working pose.

    Returns:
        :class:`DesignReport` (``certificate``: the bound on tr(Cs)/3 and the efficiency,
        :func:`~kpioed_drake.design.approximate.certificate.certify`, of the combined design).

    Raises:
        InputError: bad input. DesignError: solver failure or infeasible design.
    """
    opts = options or DesignOptions()
    check_paths(robot=robot_name, inputs=[q_work_file, given], outputs=[out, json_path], plot=plot, html=html)
    robot = load_robot(robot_name)
    q_work, file_weights = _working_poses(robot, q_work_deg, q_work_file)
    problem = make_problem(
        robot,
        q_work=q_work,
        sigma_mm=opts.sigma_mm,
        extend=opts.extend,
        kpi_weights=file_weights if kpi_weights is None else kpi_weights,
        kpi_aggregate=opts.kpi_aggregate,
        measure=opts.measure,
        sigma_deg=opts.sigma_deg,
        kpi_orientation_mm=opts.kpi_orientation_mm,
    )
    q_given = None if given is None else designs.read_design(given, robot)
    try:
        res, problem = _compute(problem, opts, q_given, given)
    except DesignError as exc:
        if json_path is not None and exc.result is not None:
            atomic_write_json(json_path, json_record(exc.result, problem, error=str(exc)))
        raise
    if opts.certified:
        res.certificate = certificate.certify(
            problem, res.q, collision=opts.collision, seed=opts.seed, given=q_given
        )
    if opts.discriminate is None:  # (a plan's problem is that of its explanations)
        res.tcp = tcp_record(problem, res.q if q_given is None else np.concatenate([q_given, res.q]))
    _write(res, problem, out=out, json_path=json_path, plot=plot, html=html)
    return res


def _common(problem, opts: DesignOptions, q_given) -> dict:
    """The settings every mode passes on; for a certified fixed-size or target KPI design from the
    approximate start, the certified approximate design to start from (the certificate's search,
    paid once for the bound as well, starts the optimiser nearer the optimum: docs/design.md)."""
    common = dict(
        collision=opts.collision, solver=opts.solver, seed=opts.seed, starts=opts.starts, start=opts.start
    )
    if opts.discriminate is None and opts.certified and q_given is None and opts.criterion == "kpi":
        if not problem.worst_case and resolve_start(opts.start, opts.criterion) == "approximate":
            common["approx"] = certificate.certified_design(problem, collision=opts.collision, seed=opts.seed)
    return common


def _plan(problem, opts: DesignOptions, q_given, given, common: dict):
    """A discrimination plan (poses and conditions that tell two explanations apart)."""
    conds = read_given_conditions(given, len(q_given)) if given is not None else None
    return plan_design(
        problem,
        opts.discriminate,
        n=opts.n,
        given=q_given,
        given_conditions=conds,
        condition_span=opts.condition_span,
        allow_infeasible=opts.allow_infeasible,
        **common,
    )


def _target(problem, opts: DesignOptions, q_given, given, common: dict):
    """The fewest poses reaching the target tr(Cs)/3."""
    res = design_for_target(problem, opts.target_var_mm2, given=q_given, criterion=opts.criterion, **common)
    return res, problem


def _fixed(problem, opts: DesignOptions, q_given, given, common: dict):
    """A design of ``opts.n`` poses."""
    res = optimize_design(
        problem,
        n=opts.n,
        allow_infeasible=opts.allow_infeasible,
        given=q_given,
        criterion=opts.criterion,
        **common,
    )
    return res, problem


MODES = {"discriminate": _plan, "target": _target, "fixed": _fixed}
"""The modes of :func:`run_design`: a discrimination plan, the fewest poses for a target, n poses."""


def _compute(problem, opts: DesignOptions, q_given, given) -> tuple[DesignReport, object]:
    """The design of ``opts`` by its mode (:data:`MODES`) and its problem (a plan's, with the
    conditions it adds)."""
    mode = (
        "discriminate"
        if opts.discriminate is not None
        else "fixed"
        if opts.target_var_mm2 is None
        else "target"
    )
    return MODES[mode](problem, opts, q_given, given, _common(problem, opts, q_given))


def _write(res: DesignReport, problem, *, out, json_path, plot, html) -> None:
    """Stage the design's files and write them after all succeeded."""
    with Outputs() as staged:
        if out is not None:
            extra = {
                "incidence_deg": np.array([r["incidence_deg"] for r in res.reports]),
                "min_clearance_mm": np.array([r["min_clearance_mm"] for r in res.reports]),
                **(getattr(res, "plan_columns", None) or {}),  # a measurement plan's block and condition
            }
            staged.add_text(out, designs.design_csv_text(res.q, extra, robot=problem.robot))
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
                title=f"{problem.robot.name}: {res.criterion} design, {res.n} poses, "
                f"tr(Cs)/3 = {res.kpi_avg_var_mm2:.4g} mm^2",
            )
        if html is not None:
            staged.add_text(html, design_page(problem.robot, problem.cell, res.q, q_work=problem.q_works[0],
                                              Cs=first_kpi_covariance(problem, res.q)))  # fmt: skip
        staged.commit()


def first_kpi_covariance(problem: Problem, q: np.ndarray) -> np.ndarray:
    """(3, 3) covariance Cs [mm^2] of the TCP at the first working pose for the design ``q``."""
    Cp, _ = problem.covariances(q)
    Js = problem.Js_each()[0][:3]  # the position rows (the orientation's follow with kpi_orientation_mm)
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
        staged.add_text(stem.with_suffix(".csv"), designs.design_csv_text(kres.q, robot=problem.robot))
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
