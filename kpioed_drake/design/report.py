"""The result of a design run: :class:`DesignReport`, its JSON record and its printed summary."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from kpioed_drake.design.approximate.certificate import certificate_fields, certificate_line
from kpioed_drake.errors import InputError, SolverError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.outputs import jsonable
from kpioed_drake.robot.jointmap import q_to_file


@dataclasses.dataclass
class DesignReport:
    """An experimental design and how it was obtained.

    Joint angles are in radians here and in degrees in :meth:`summary`; ``reports`` give
    clearances [mm] and angles [deg].
    """

    q: np.ndarray
    """(n, 6) measurement poses [rad]."""
    criterion: str
    """The design method: ``heuristic``, ``kpi``, ``param``, ``d`` or ``o1``."""
    value: float
    """The criterion's value at ``q`` (for ``heuristic``: tr(Cs)/3 [mm^2]) [criterion units]."""
    kpi_avg_var_mm2: float
    """tr(Cs)/3 of the design, the TCP's average variance at ``q_work`` [mm^2]; several working
    poses: their weighted mean or the largest (``problem.kpi_aggregate``); with ``given`` poses,
    of the combined design."""
    param_crit: float
    """SPEC's scaled tr(Cp) of the design [mm^2] (with ``given`` poses, of the combined design)."""
    solver: str
    """``snopt``, ``ipopt`` or ``none`` (heuristic)."""
    status: str
    """The solver's status text (e.g. ``"snopt info 1: optimality conditions satisfied"``; with
    block sweeps a summary of the sweeps)."""
    success: bool
    """The solver reported success (always True for the heuristic)."""
    solve_s: float
    """Wall time of all solver calls [s] (all starts; with block sweeps, of the sweeps including
    the checks of the block results)."""
    n_evals: int
    """Cost evaluations counted in our callback (all starts)."""
    feasible: bool
    """Every pose passes the independent check of the constraints that were imposed (joint limits
    and incidence; and clearances when ``collision`` is True)."""
    n_infeasible_poses: int
    """Poses failing those checks."""
    n_colliding_poses: int
    """Poses with a collision or beam failure in the full check (reported also when the design was
    made without collision avoidance)."""
    reports: list[dict]
    """Per pose, :meth:`~kpioed_drake.tracker.feasibility.PoseReport.as_dict` of the full check."""
    start_values: list[float]
    """The criterion's value reached from each start (NaN where the solve failed)."""
    initial_values: list[float] = dataclasses.field(default_factory=list)
    """The criterion's value at each starting design."""
    collision: bool = True
    """Whether collision avoidance was imposed."""
    robot: str = ""
    """Robot name."""
    seed: int = 0
    """Seed of the first start (start k uses ``seed + k``)."""
    best_start: int = 0
    """Index of the start that was kept."""
    constraint_evals: int = 0
    """Constraint evaluations (all starts)."""
    all_rows_retries: int = 0
    """Solves with each pose's smallest clearance rows that failed or were infeasible and were
    repeated with all rows (times and evaluations include both solves)."""
    sweeps: int = 0
    """Block sweeps of the kept start (0: one solve over all poses; see ``max_block`` of
    :func:`~kpioed_drake.design.optimize.optimize_design`)."""
    kpi_vars_mm2: list[float] | None = None
    """Several working poses: tr(Cs_k)/3 at each, (K,) [mm^2] (None: one working pose)."""
    given: dict | None = None
    """Poses already measured whose information was held fixed (``given`` of
    :func:`~kpioed_drake.design.optimize.optimize_design`): ``n_given``, the given poses' own
    ``given_kpi_avg_var_mm2`` [mm^2] and ``given_param_crit`` [mm^2] (NaN if they alone do not
    determine the parameters) and ``given_q_deg`` (m, 6) [deg]. None: no given poses."""
    start: str = "heuristic"
    """How the kept start was made: ``heuristic``, ``approximate`` (the rounded approximate
    design) or ``q0`` (given by the caller)."""
    start_s: float = 0.0
    """Wall time of making the starts [s] (not in ``solve_s``; for ``approximate`` the column
    generation and the rounding; in the printed summary, not in the JSON record)."""
    polish: dict | None = None
    """The final exchange on the exact criterion (:func:`~kpioed_drake.design.polish.polish_design`):
    ``rounds`` kept, ``value_before`` tr(Cs)/3 [mm^2] of the optimiser's result before it, ``solve_s``
    and ``n_evals`` of its solves (included in the result's). None: not run."""
    certificate: dict | None = None
    """The optimality certificate (:func:`~kpioed_drake.design.approximate.certificate.certify`): a lower
    bound ``bound_mm2`` on tr(Cs)/3 of any design of n poses, the ``efficiency`` bound / value and how
    the bound was found. None: not asked for."""
    tcp: dict | None = None
    """The TCP's position and orientation precision at the working poses
    (:func:`tcp_record`; set by ``kpioed design``). None: not computed."""
    target: dict | None = None
    """The search for the fewest poses reaching a target variance
    (:func:`~kpioed_drake.design.target.design_for_target`): ``target_var_mm2``, ``n_poses``,
    ``kpi_avg_var_mm2``, ``bound_mm2``, ``bound_note``, ``search_s`` and the ``trail`` of designs
    tried. None: no search."""

    @property
    def n(self) -> int:
        """Number of poses."""
        return int(self.q.shape[0])

    def summary(self) -> dict:
        """JSON-ready record (angles in degrees); ``given``, ``target``, ``tcp``, ``values.kpi_vars_mm2``
        only when set; the certificate's fields
        (:func:`~kpioed_drake.design.approximate.certificate.certificate_fields`) always (null when not
        computed)."""
        out: dict[str, Any] = {
            "robot": self.robot,
            "criterion": self.criterion,
            "n_poses": self.n,
            "collision_avoidance": self.collision,
            "values": {
                "criterion_value": self.value,
                "kpi_avg_var_mm2": self.kpi_avg_var_mm2,
                "param_crit": self.param_crit,
            },
            "solver": self.solver,
            "status": self.status,
            "success": self.success,
            "solve_s": self.solve_s,
            "n_evals": self.n_evals,
            "constraint_evals": self.constraint_evals,
            "all_rows_retries": self.all_rows_retries,
            "sweeps": self.sweeps,
            "seed": self.seed,
            "start": self.start,
            "starts": len(self.start_values) if self.start_values else 1,
            "best_start": self.best_start,
            "polish": self.polish,
            "start_values": self.start_values,
            "initial_values": self.initial_values,
            "feasible": self.feasible,
            "n_infeasible_poses": self.n_infeasible_poses,
            "n_colliding_poses": self.n_colliding_poses,
            "poses": [
                {"q_deg": np.rad2deg(qi).tolist(), **rep}
                for qi, rep in zip(self.q, self.reports, strict=True)
            ],
        }
        if self.kpi_vars_mm2 is not None:
            out["values"]["kpi_vars_mm2"] = self.kpi_vars_mm2
        for key in ("given", "target", "tcp"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        out.update(certificate_fields(self.certificate))
        return out


class DesignError(SolverError):
    """The optimiser failed or returned an infeasible design (the CLI exits with status 3).

    Attributes:
        result: the :class:`DesignReport` that was rejected (None if there is none).
        fields: the API parameters the message names (as :class:`~kpioed_drake.errors.InputError`).
    """

    def __init__(self, message: str, result: DesignReport | None = None, *, fields=()):
        super().__init__(message, fields=fields)
        self.result = result


def json_record(res: DesignReport, problem: Problem, *, error: str | None = None) -> dict:
    """The JSON record of a run (``kpioed design --json``): :meth:`DesignReport.summary` with the
    working pose [deg] ((K, 6) and ``kpi_weights``, ``kpi_aggregate`` for several), the noise [mm]
    and, for a rejected design, the error message; NaN as null."""
    rec = res.summary()
    for pose, qi in zip(rec["poses"], res.q, strict=True):  # a prismatic joint's value in mm
        pose["q_deg"] = q_to_file(problem.robot, qi).tolist()
    rec["q_work_deg"] = q_to_file(problem.robot, problem.q_work).tolist()
    if problem.n_kpis > 1:
        rec["kpi_weights"] = problem.weights.tolist()
        rec["kpi_aggregate"] = problem.kpi_aggregate
    rec["sigma_mm"] = problem.sigma
    if error is not None:
        rec["error"] = error
    return jsonable(rec)


def tcp_record(problem: Problem, q: np.ndarray) -> dict:
    """The TCP's precision of the design ``q`` (n, 6) [rad] (with any given poses): ``measure``,
    ``sigma_deg`` (pose measurements' orientation noise [deg], else None), ``kpi_orientation_mm``
    (L), ``position_var_mm2`` tr(C_pos)/3 [mm^2], ``orientation_var_deg2`` tr(C_rot)/3 [deg^2] and
    ``orientation_rms_deg`` its root [deg] (several working poses: the weighted mean, or the largest
    with ``kpi_aggregate == "max"``; NaN where the poses do not determine the parameters; the
    orientation NaN with extensions). With point measurements the flange's rotation that one
    reflector cannot see is held by the gauge (theta6, alpha6): the orientation's variance is the
    rest's."""
    try:
        each = problem.tcp_variances(q)
        pos, rot = (float(v.max() if problem.worst_case else v @ problem.weights) for v in each)
    except InputError:
        pos, rot = float("nan"), float("nan")
    return {
        "measure": problem.measure,
        "sigma_deg": None if problem.sigma_rot is None else float(np.rad2deg(problem.sigma_rot)),
        "kpi_orientation_mm": problem.kpi_orientation_mm,
        "position_var_mm2": float(pos),
        "orientation_var_deg2": float(rot),
        "orientation_rms_deg": float(np.sqrt(rot)),
    }


def tcp_line(tcp: dict) -> str:
    """One line of a printed summary: the TCP's position and orientation variances."""
    how = "points" if tcp["measure"] == "point" else f"poses, orientation noise {tcp['sigma_deg']:.3g} deg"
    line = (
        f"  TCP: position tr(C)/3 = {tcp['position_var_mm2']:.4g} mm^2, orientation tr(C)/3 = "
        f"{tcp['orientation_var_deg2']:.4g} deg^2 ({tcp['orientation_rms_deg']:.3g} deg RMS per axis); "
        f"measured {how}"
    )
    if tcp["kpi_orientation_mm"]:
        line += f"; KPI tr(Cs)/3 = position + ({tcp['kpi_orientation_mm']:g} mm x angle [rad])^2"
    return line


def format_summary(res: DesignReport) -> str:
    """A few human-readable lines about a design."""
    ca = "with" if res.collision else "without"
    lines = [
        f"{res.robot}: {res.criterion} design, {res.n} poses, {ca} collision avoidance",
        f"  tr(Cs)/3 = {res.kpi_avg_var_mm2:.4g} mm^2   scaled tr(Cp) = {res.param_crit:.4g} mm^2",
    ]
    if res.kpi_vars_mm2 is not None:
        each = ", ".join(f"{v:.4g}" for v in res.kpi_vars_mm2)
        lines[1] += f"   (KPI of {len(res.kpi_vars_mm2)} working poses: {each} mm^2)"
    if res.tcp is not None:
        lines.append(tcp_line(res.tcp))
    if res.given is not None:
        g = res.given
        lines.insert(1, f"  {res.n} new poses added to {g['n_given']} given poses (values: combined design)")
        lines.append(f"  given poses alone: tr(Cs)/3 = {g['given_kpi_avg_var_mm2']:.4g} mm^2")
    if res.target is not None:
        t = res.target
        bound = "none" if t["bound_mm2"] is None else f"{t['bound_mm2']:.4g} mm^2"
        lines.append(
            f"  target tr(Cs)/3 <= {t['target_var_mm2']:.4g} mm^2: fewest poses {t['n_poses']} "
            f"({len(t['trail'])} designs tried, {t['search_s']:.1f} s); "
            f"lower bound for {t['n_poses']} poses {bound}"
        )
    if res.criterion != "heuristic":
        start = res.initial_values[res.best_start] if res.initial_values else float("nan")
        label = "start" if res.target is not None else f"{res.start} start"  # the search warm-starts
        lines.append(f"  {res.criterion} criterion = {res.value:.6g} ({label} {start:.6g})")
        lines.append(
            f"  solver {res.solver}: {res.status}; {res.solve_s:.2f} s, {res.n_evals} cost evaluations"
        )
        if res.start == "approximate":
            lines.append(f"  approximate start (column generation, rounding, exchange): {res.start_s:.2f} s")
        if res.polish and res.polish["rounds"]:
            p = res.polish
            lines.append(
                f"  final exchange: {p['rounds']} round(s), {p['value_before']:.6g} -> {res.value:.6g} "
                f"({p['solve_s']:.2f} s)"
            )
        if res.all_rows_retries:
            lines.append("  (solved again with all clearance rows after the reduced rows failed)")
    if res.certificate is not None:
        of = "" if res.criterion == "kpi" else " (of tr(Cs)/3, not of the design's criterion)"
        lines.append("  " + certificate_line(res.certificate) + of)
    n_ok = res.n - res.n_infeasible_poses
    lines.append(
        f"  independent check: {n_ok}/{res.n} poses feasible; {res.n_colliding_poses} pose(s) collide"
    )
    return "\n".join(lines)
