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

Data with a 6-DoF probe's orientations (:func:`tcp_precision`): the fit uses them, the KPI is
``v_pos + L^2 v_rot`` (the TCP orientation's variance per axis [rad^2] weighted by L [mm],
``NextOptions.orientation_weight_mm``) and the next poses are pose measurements in the problem of
``design --measure pose`` (:func:`design_problem`) at the median of the fit's orientation noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.kpi import orientation_covariance
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.calibration.robust import pose_groups
from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.given import fewest_certified, given_design
from kpioed_drake.design.approximate.sequential import fewest_new_poses, most_useful
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.report import DesignError
from kpioed_drake.effects import model_effects
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.online.options import NextOptions
from kpioed_drake.online.report import NextReport
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.tracker.data import Measurements


def design_problem(
    robot: Robot,
    sigma_mm: float,
    cell: Cell | None,
    *,
    sigma_deg: float | None = None,
    kpi_orientation_mm: float = 0.0,
) -> Problem:
    """The problem the next poses are designed in: the robot's model file (its kinematics place the
    collision and beam constraints, as the feasibility check does) with the noise the data show;
    with ``sigma_deg`` (data with a 6-DoF probe's orientations) pose measurements at that
    orientation noise [deg] and the KPI's orientation weight ``kpi_orientation_mm`` [mm]
    (``design --measure pose``'s problem).

    The estimate enters through the measured poses' information and the noise; the design's own
    kinematics stay nominal because the constraints are planned on them: a design optimised on a
    first estimate's kinematics (from ten poses, some parameters tens of millimetres off) sits on
    constraint boundaries the nominal check then finds violated.
    """
    pose = {} if sigma_deg is None else dict(measure="pose", sigma_deg=sigma_deg)
    problem = make_problem(robot, sigma_mm=sigma_mm, kpi_orientation_mm=kpi_orientation_mm, **pose)
    return problem if cell is None else dataclasses.replace(problem, cell=cell)


def tcp_precision(report: CalibrationReport, opts: NextOptions, scale: float) -> dict:
    """The step's precision at the estimate, each variance times ``scale`` (chi2/dof when the fit
    rejects, else 1): ``kpi_avg_var_mm2``, the KPI (tr(Cs)/3 of the position, with orientations
    plus ``L^2`` times the orientation's, ``L = opts.orientation_weight_mm``); with orientations
    also ``position_var_mm2``, ``orientation_std_deg`` (RMS per axis), ``kpi_orientation_mm`` (L),
    ``target_deg`` and ``sigma_deg_used`` (the orientation noise of the next poses' design [deg]).

    Raises:
        InputError: an orientation target or weight for data without orientations.
    """
    v_pos = float(np.trace(report.kpi_cov) / 3.0 * scale)
    sigma_rot = report.result.sigma_rot
    if sigma_rot is None:
        if opts.with_orientation:
            raise InputError(
                f"{report.data.path}: the data hold no orientations (a 6-DoF probe's): an orientation "
                "target or weight needs them",
                fields=("target_deg", "kpi_orientation_mm"),
            )
        return {"kpi_avg_var_mm2": v_pos}
    v_rot = float(np.trace(orientation_covariance(report.result, report.q_work)) / 3.0 * scale)
    L = opts.orientation_weight_mm
    return {
        "kpi_avg_var_mm2": v_pos + L**2 * v_rot,
        "position_var_mm2": v_pos,
        "orientation_std_deg": float(np.rad2deg(np.sqrt(v_rot))),
        "kpi_orientation_mm": L,
        "target_deg": opts.target_deg,
        "sigma_deg_used": float(np.rad2deg(np.median(sigma_rot)) * np.sqrt(scale)),
    }


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
) -> NextReport:
    """One online step on the data so far (module docstring).

    Args:
        robot: the nominal model (or an extended model file: its effects are estimated too).
        data: the measurements so far.
        options: :class:`NextOptions`.
        cell: the measuring cell (default ``models/cell.yaml``).
        plan: (H, n_joints) [rad] the previous step's plan (:attr:`NextReport.q_plan`), or None:
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
        sigma_mm=opts.sigma_mm,
        effects=tuple(model_effects(robot)),
        force=opts.force,
        sigma_deg=opts.sigma_deg,
    )
    report = calibrate(robot, data, cal_opts, cell=cell)
    scale = report.chi2_per_dof if report.rejects else 1.0
    precision = tcp_precision(report, opts, scale)
    var_now = precision["kpi_avg_var_mm2"]
    sigma_used = opts.sigma_mm * float(np.sqrt(scale))
    q_given = measured_poses(data)
    base = dict(
        done=var_now <= opts.target_var_mm2,
        n_measured=len(q_given),
        aposteriori=bool(report.rejects),
        sigma_used_mm=sigma_used,
        target_var_mm2=opts.target_var_mm2,
        report=report,
        **precision,
    )
    if base["done"]:
        return NextReport(
            q_next=np.zeros((0, robot.n_joints)),
            predicted_kpi_avg_var_mm2=None,
            n_planned=0,
            q_plan=np.zeros((0, robot.n_joints)),
            min_more_poses=0,
            certificate=None,
            **base,
        )
    orientation = {k: precision[k] for k in ("kpi_orientation_mm",) if k in precision}
    problem = design_problem(
        robot, sigma_used, cell, sigma_deg=precision.get("sigma_deg_used"), **orientation
    )
    q_next, predicted, q_plan, fewest = _design(problem, opts, q_given, plan)
    cert = None
    if opts.certify:
        cert = certificate.certify(problem, q_next, collision=opts.collision, seed=opts.seed, given=q_given)
    return NextReport(
        q_next=q_next,
        predicted_kpi_avg_var_mm2=predicted,
        n_planned=len(q_plan),
        q_plan=q_plan,
        min_more_poses=max(1, fewest),  # not done yet: the measured poses alone do not reach it
        certificate=cert,
        predicted_orientation_std_deg=_predicted_orientation(problem, q_given, q_next),
        **base,
    )


def _predicted_orientation(problem: Problem, q_given: np.ndarray, q_next: np.ndarray) -> float | None:
    """The TCP orientation's RMS standard deviation per axis [deg] of the measured and the next
    poses together (pose measurements; None for points)."""
    if problem.measure != "pose":
        return None
    return float(np.sqrt(problem.tcp_variances(np.concatenate([q_given, q_next]))[1][0]))


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
