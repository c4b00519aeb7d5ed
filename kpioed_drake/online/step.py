"""One step of online calibration: calibrate on the data so far, evaluate the TCP variance at the
estimate with the noise the data show, then stop or design the next poses.

The variance is the KPI's tr(Cs)/3 (paper eq. 19, 24e) of the calibration, a-posteriori (times
chi2/dof) when the goodness-of-fit test rejects: the guarantee must hold for the real spread. The
next poses are planned to the target: the KPI design (paper eq. 24 with the measured poses'
information held fixed, section 3.1) of the poses still needed at that noise (the fewest the
certified bound does not exclude, in whole batches), with collision avoidance
(:func:`design_problem`: the constraints on the model file's kinematics), of which the ``n`` that
lower tr(Cs)/3 most are measured next (a batch designed alone would be greedy: the last rounds
could not make up for it); the previous step's plan, when given, is continued if that is better.
The certificate (a lower bound on tr(Cs)/3 of any combined design of as many poses) says how far
from the best they are.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_count, check_paths, check_positive, check_seed
from kpioed_drake.calibration.common import CalibrationOptions, read_inputs
from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.calibration.robust import pose_groups
from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.given import fewest_certified, given_design
from kpioed_drake.design.approximate.sequential import fewest_new_poses, most_useful
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.result import DesignError
from kpioed_drake.effects import model_effects
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.files import designs
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.tracker.data import Measurements


@dataclasses.dataclass(frozen=True)
class NextOptions:
    """The settings of one online step (:func:`next_poses`)."""

    target_var_mm2: float = 0.1
    """The TCP precision to reach: tr(Cs)/3 at the working pose [mm^2]."""
    n: int = 5
    """Poses to design when the precision is not reached yet."""
    sigma_mm: float = 0.02
    """The tracker's noise per coordinate [mm]; the a-posteriori noise replaces it when the fit
    rejects."""
    collision: bool = True
    """Avoid collisions of the robot, the cell and the laser beam."""
    seed: int = 0
    """Seed of the design's starts and of the certificate's search."""
    certify: bool = True
    """Add the certificate of the combined design (``bound_mm2``, ``efficiency``)."""
    max_plan: int = 60
    """Most poses planned ahead: the step designs the poses still needed to reach the target (at
    least ``n``, at most this many) and returns the ``n`` of them that help most now; ``n`` may not
    exceed it."""
    force: bool = False
    """Go on with data that fails the plausibility checks (warned in the summary)."""

    def __post_init__(self):
        check_positive("target_var_mm2", self.target_var_mm2)
        check_count("n", self.n)
        check_count("max_plan", self.max_plan)
        if self.n > self.max_plan:
            raise InputError(
                f"n {self.n}: expected at most max_plan ({self.max_plan}), the most poses a step plans ahead",
                fields=("n", "max_plan"),
            )
        check_sigma(self.sigma_mm)
        check_seed(self.seed)


@dataclasses.dataclass
class NextResult:
    """Outcome of one step.

    Attributes:
        done: the precision is reached (``kpi_avg_var_mm2 <= target_var_mm2``): stop measuring.
        n_measured: poses measured so far (distinct joint values).
        kpi_avg_var_mm2: tr(Cs)/3 now [mm^2] (a-posteriori when the fit rejects).
        aposteriori: whether the a-posteriori noise was used.
        sigma_used_mm: the noise the variance and the design use [mm].
        target_var_mm2: the precision asked for [mm^2].
        q_next: (n, n_joints) the next poses [rad] (empty when done).
        predicted_kpi_avg_var_mm2: tr(Cs)/3 of the measured and the next poses together [mm^2].
        n_planned: poses the step planned ahead (the next ones are the most useful of them).
        q_plan: (n_planned, n_joints) the planned poses [rad] (the next ones among them): the
            ``plan`` of the following step.
        min_more_poses: fewest more poses with which the target can be reached at all: with
            fewer, the dual bound of the design with the measured information
            (:func:`~kpioed_drake.design.approximate.given.fewest_certified`) exceeds it, for any
            feasible poses the search reached (nominal kinematics, the noise used); 0 when done,
            ``max_plan + 1`` when not even ``max_plan`` can.
        certificate: the certificate of the combined design (None when done or not asked).
        report: the calibration on the data so far.
    """

    done: bool
    n_measured: int
    kpi_avg_var_mm2: float
    aposteriori: bool
    sigma_used_mm: float
    target_var_mm2: float
    q_next: np.ndarray
    predicted_kpi_avg_var_mm2: float | None
    n_planned: int
    q_plan: np.ndarray
    min_more_poses: int
    certificate: dict | None
    report: CalibrationReport

    def to_dict(self, robot: Robot) -> dict:
        """The JSON record (mm, deg)."""
        cert = self.certificate or {}
        return {
            "done": self.done,
            "n_measured": self.n_measured,
            "kpi_avg_var_mm2": self.kpi_avg_var_mm2,
            "target_var_mm2": self.target_var_mm2,
            "aposteriori": self.aposteriori,
            "sigma_used_mm": self.sigma_used_mm,
            "chi2_per_dof": self.report.chi2_per_dof,
            "kpi_mm": np.asarray(self.report.kpi).tolist(),
            "kpi_cov_mm2": (
                self.report.kpi_cov * (self.sigma_used_mm / self.report.result.sigma) ** 2
            ).tolist(),
            "predicted_kpi_avg_var_mm2": self.predicted_kpi_avg_var_mm2,
            "bound_mm2": cert.get("bound_mm2"),
            "efficiency": cert.get("efficiency"),
            "n_next": int(len(self.q_next)),
            "n_planned": self.n_planned,
            "min_more_poses": self.min_more_poses,
            "next_q_deg": q_to_file(robot, self.q_next).tolist() if len(self.q_next) else [],
        }

    def summary(self) -> str:
        """A short human-readable summary."""
        post = " (a-posteriori: the fit rejects)" if self.aposteriori else ""
        head = (
            f"{self.n_measured} poses measured: tr(Cs)/3 = {self.kpi_avg_var_mm2:.4g} mm^2{post}, "
            f"target {self.target_var_mm2:g} mm^2"
        )
        forced = [f"  warning: {w}" for w in self.report.warnings if w.startswith("forced:")]
        if self.done:
            return "\n".join([head, *forced, "  done: the precision is reached; nothing to measure"])
        lines = [
            head,
            *forced,
            f"  next {len(self.q_next)} poses: combined tr(Cs)/3 = {self.predicted_kpi_avg_var_mm2:.4g} mm^2",
            f"  planned {self.n_planned} more; at least {self.min_more_poses} more are needed "
            "(with fewer, the certified bound exceeds the target)",
        ]
        if self.certificate is not None:
            c = self.certificate
            lines.append(f"  bound {c['bound_mm2']:.4g} mm^2, efficiency {c['efficiency']:.3f}")
        return "\n".join(lines)


def design_problem(robot: Robot, sigma_mm: float, cell: Cell | None) -> Problem:
    """The problem the next poses are designed in: the robot's model file (its kinematics place the
    collision and beam constraints, as the feasibility check does) with the noise the data show.

    The estimate enters through the measured poses' information and the noise; the design's own
    kinematics stay nominal because the constraints are planned on them: a design optimised on a
    first estimate's kinematics (from ten poses, some parameters tens of millimetres off) sits on
    constraint boundaries the nominal check then finds violated.
    """
    problem = make_problem(robot, sigma_mm=sigma_mm)
    return problem if cell is None else dataclasses.replace(problem, cell=cell)


def measured_poses(data: Measurements) -> np.ndarray:
    """(m, n_joints) the distinct poses of the data (a pose's targets share one) [rad]."""
    groups = pose_groups(data)
    first = np.array([np.flatnonzero(groups == g)[0] for g in range(groups.max() + 1)])
    return data.q[first]


def next_poses(
    robot: Robot,
    data: Measurements,
    options: NextOptions | None = None,
    *,
    cell: Cell | None = None,
    plan: np.ndarray | None = None,
) -> NextResult:
    """One online step on the data so far (module docstring).

    Args:
        robot: the nominal model (or an extended model file: its effects are estimated too).
        data: the measurements so far.
        options: :class:`NextOptions`.
        cell: the measuring cell (default ``models/cell.yaml``).
        plan: (H, n_joints) [rad] the previous step's plan (:attr:`NextResult.q_plan`), or None:
            its poses not measured yet start one more design of the new plan, kept if better, so
            that a re-plan is never worse than the rest of the plan it replaces (the estimate and
            the noise aside).

    Raises:
        InputError: no poses yet, too few to calibrate, bad data.
    """
    opts = options or NextOptions()
    if data.n == 0:
        raise InputError(f"{data.source}: no poses measured yet: start with a design (kpioed design)")
    cal_opts = CalibrationOptions(
        sigma_mm=opts.sigma_mm, effects=tuple(model_effects(robot)), force=opts.force
    )
    report = calibrate(robot, data, cal_opts, cell=cell)
    scale = report.chi2_per_dof if report.rejects else 1.0
    var_now = float(np.trace(report.kpi_cov) / 3.0 * scale)
    sigma_used = opts.sigma_mm * float(np.sqrt(scale))
    q_given = measured_poses(data)
    base = dict(
        done=var_now <= opts.target_var_mm2,
        n_measured=len(q_given),
        kpi_avg_var_mm2=var_now,
        aposteriori=bool(report.rejects),
        sigma_used_mm=sigma_used,
        target_var_mm2=opts.target_var_mm2,
        report=report,
    )
    if base["done"]:
        return NextResult(
            q_next=np.zeros((0, robot.n_joints)),
            predicted_kpi_avg_var_mm2=None,
            n_planned=0,
            q_plan=np.zeros((0, robot.n_joints)),
            min_more_poses=0,
            certificate=None,
            **base,
        )
    problem = design_problem(robot, sigma_used, cell)
    q_next, predicted, q_plan, fewest = _design(problem, opts, q_given, plan)
    cert = None
    if opts.certify:
        cert = certificate.certify(problem, q_next, collision=opts.collision, seed=opts.seed, given=q_given)
    return NextResult(
        q_next=q_next,
        predicted_kpi_avg_var_mm2=predicted,
        n_planned=len(q_plan),
        q_plan=q_plan,
        min_more_poses=max(1, fewest),  # not done yet: the measured poses alone do not reach it
        certificate=cert,
        **base,
    )


RETRY_SEEDS = 3
"""Seeds tried for the next poses before a solver failure is reported (the design is one local
optimisation from one start per seed: the approximate design's candidates first, then heuristic
poses of the next seeds, which need no new certified search)."""


TIGHTEN_STEPS = 3
"""Most cone programs solved for the fewest count itself (:func:`plan_size`): the ``Y`` solved for
the greedy count bounds fewer poses more loosely than one solved for them."""


def plan_size(problem: Problem, opts: NextOptions, q_given: np.ndarray) -> tuple[int, int]:
    """Poses the step plans ahead, and the fewest more poses the certified bound does not exclude.

    The plan is the best design of the poses of as few batches of ``opts.n`` as could reach the
    target (the poses the following steps measure if it is reached as soon as it can be): the
    fewest poses whose bound
    (:func:`~kpioed_drake.design.approximate.given.fewest_certified`) is at most the target, with
    the approximate design with the measured information solved for the greedy count (the fewest
    poses that reach the target when added greedily from the certified design's candidates,
    :func:`~kpioed_drake.design.approximate.sequential.fewest_new_poses`), rounded up to whole
    batches; at most ``opts.max_plan``. A plan of the greedy count is a design for more poses than
    needed, and its most useful poses are not those of the smallest design that reaches the
    target (docs/online.md).

    Returns:
        (poses planned, fewest more poses: 0 .. ``max_plan + 1``).
    """
    approx = certificate.certified_design(problem, collision=opts.collision, seed=opts.seed)
    top = opts.max_plan  # at least opts.n (NextOptions)
    greedy = fewest_new_poses(problem, approx, given=q_given, target=opts.target_var_mm2, n_max=top)
    gd = given_design(
        problem, approx, given=q_given, n=int(np.clip(greedy, opts.n, top)), collision=opts.collision
    )
    fewest = fewest_certified(problem, gd, target=opts.target_var_mm2, n_max=top)
    for _ in range(TIGHTEN_STEPS):  # the Y solved for the count itself may exclude it
        if fewest == 0 or fewest > top:
            break
        at = given_design(problem, approx, given=q_given, n=fewest, collision=opts.collision, rounds=1)
        if at.bound(kpi_factor(problem), fewest) <= opts.target_var_mm2:
            break
        fewest = max(fewest, fewest_certified(problem, at, target=opts.target_var_mm2, n_max=top))
    rounds = -(-fewest // opts.n)  # whole batches: 19 poses still take four batches of five
    return int(np.clip(rounds * opts.n, opts.n, top)), fewest


def _design(
    problem: Problem, opts: NextOptions, q_given: np.ndarray, previous: np.ndarray | None
) -> tuple[np.ndarray, float, np.ndarray, int]:
    """The next poses: the KPI design of the planned number of poses with ``q_given`` held fixed
    (a solver failure retried with the next seeds; also from the rest of the ``previous`` plan),
    and of it the ``opts.n`` that lower tr(Cs)/3 most first (all of it when the plan is ``opts.n``
    poses: then it is ``design --given``).

    Returns:
        (q_next (n, n_joints) [rad], tr(Cs)/3 of the measured and next poses [mm^2], the plan
        (h, n_joints) [rad], the fewest more poses the bound does not exclude).
    """
    h, fewest = plan_size(problem, opts, q_given)
    for k in range(RETRY_SEEDS):
        try:
            plan = optimize_design(  # a retry starts from heuristic poses: no new certified search
                problem,
                criterion="kpi",
                n=h,
                collision=opts.collision,
                seed=opts.seed + k,
                given=q_given,
                start=None if k == 0 else "heuristic",
            )
            break
        except DesignError:
            if k == RETRY_SEEDS - 1:
                raise
    plan = _continued(problem, opts, q_given, previous, plan)
    if h == opts.n:
        return plan.q, float(plan.kpi_avg_var_mm2), plan.q, fewest
    q_next = plan.q[most_useful(problem, plan.q, given=q_given, n=opts.n)]
    value = float(problem.criteria(np.concatenate([q_given, q_next]))["kpi_avg_var_mm2"])
    return q_next, value, plan.q, fewest


PLAN_MEASURED_TOL = 1e-6
"""A planned pose within this of a measured one (every joint) [rad, mm] was measured."""


def _continued(problem: Problem, opts: NextOptions, q_given: np.ndarray, previous, plan):
    """``plan``, or the design of as many poses started from the ``previous`` plan's poses not
    measured yet (its most useful ones if more) if that one is better; ``plan`` too when
    fewer of them are left than planned now or that design fails."""
    if previous is None or len(previous) == 0:
        return plan
    measured = np.all(np.abs(previous[:, None, :] - q_given[None, :, :]) <= PLAN_MEASURED_TOL, axis=2)
    rest = previous[~measured.any(axis=1)]
    h = len(plan.q)
    if len(rest) < h:
        return plan
    if len(rest) > h:
        rest = rest[most_useful(problem, rest, given=q_given, n=h)]
    try:
        alt = optimize_design(
            problem, criterion="kpi", n=h, collision=opts.collision, seed=opts.seed, given=q_given, q0=rest
        )
    except DesignError:
        return plan
    return alt if alt.kpi_avg_var_mm2 < plan.kpi_avg_var_mm2 else plan


def next_file(
    robot: str,
    data_path: str | Path,
    options: NextOptions | None = None,
    *,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    data_format: str | Path | None = None,
    cell_path=None,
    plan_path: str | Path | None = None,
) -> tuple[NextResult, Robot]:
    """``kpioed next``: one step on a measurement file; ``out`` gets the next poses (a design CSV,
    nothing written when done), ``json_path`` the record; written after all succeeded.
    ``plan_path``: a design CSV carrying the plan from step to step: read if it exists (the
    previous plan, :func:`next_poses`), then replaced by this step's plan (removed when done).

    Returns:
        (result, robot).
    """
    check_paths(robot=robot, inputs=[data_path, data_format], outputs=[out, json_path, plan_path])
    rob, cell, data = read_inputs(
        robot, data_path, data_format, cell_path=cell_path, outputs=[out, json_path, plan_path]
    )
    previous = None
    if plan_path is not None and Path(plan_path).is_file():
        previous = designs.read_design(plan_path, rob)
    result = next_poses(rob, data, options, cell=cell, plan=previous)
    with Outputs() as staged:
        if out is not None and not result.done:
            staged.add_text(out, designs.design_csv_text(result.q_next, robot=rob))
        if plan_path is not None and not result.done:
            staged.add_text(plan_path, designs.design_csv_text(result.q_plan, robot=rob))
        if json_path is not None:
            staged.add_json(json_path, result.to_dict(rob))
        staged.commit()
    if plan_path is not None and result.done:
        Path(plan_path).unlink(missing_ok=True)
    return result, rob
