"""The closed loop of online calibration on a simulated robot: measure a start design, then
:func:`~kpioed_drake.online.step.next_poses` and measure its poses, until it says done.

The true robot (random geometric errors, a random tracker frame: :func:`kpioed_drake.simulation.simulate`
with one seed) stays the same over the rounds; each round measures only its new poses (fresh
noise). When the loop stops, the true TCP at the working pose is compared with the estimate: the
squared Mahalanobis distance under the reported covariance is chi^2(3) if the guarantee holds, so
the true TCP lies within the reported 95 % ellipsoid in 95 % of the runs.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
from scipy.stats import chi2

from kpioed_drake.design.approximate.certificate import certified_design
from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.given import bound_of, given_design
from kpioed_drake.design.approximate.search import dual_values
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.online.options import NextOptions
from kpioed_drake.online.step import next_poses
from kpioed_drake.robot.models import Robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import kpi_jacobian

ELLIPSOID_95 = float(chi2.ppf(0.95, 3))
"""chi^2(3) quantile of the 95 % confidence ellipsoid of the TCP."""


def loop_start(robot: Robot, *, seed: int, n_start: int, sigma_mm: float) -> tuple[Problem, np.ndarray]:
    """The loop's problem (the model file, noise ``sigma_mm``) and its start: ``n_start`` heuristic
    poses (n_start, n_joints) [rad] of ``seed``, the same in :func:`closed_loop` and
    :func:`start_bound`."""
    problem = make_problem(robot, sigma_mm=sigma_mm)
    return problem, optimize_design(problem, criterion="heuristic", n=n_start, seed=seed).q


def closed_loop(
    robot: Robot,
    *,
    seed: int,
    target_var_mm2: float = 0.1,
    sigma_mm: float = 1.0,
    n_start: int = 10,
    n_step: int = 5,
    max_poses: int = 150,
) -> dict:
    """Run the loop on a simulated ``robot`` (module docstring).

    Returns:
        ``{"seed", "n_poses": poses measured when it stopped, "done", "rounds",
        "kpi_avg_var_mm2": the reported tr(Cs)/3 at the stop [mm^2], "mahalanobis2": of the true
        TCP, "inside_95": within the reported 95 % ellipsoid, "error_mm": |estimate - truth| [mm],
        "aposteriori", "certified_min_poses": the start's poses plus the first step's
        ``min_more_poses`` (fewer poses in all provably cannot reach the target after that start)}``.
    """
    problem, q = loop_start(robot, seed=seed, n_start=n_start, sigma_mm=sigma_mm)
    opts = NextOptions(target_var_mm2=target_var_mm2, n=n_step, sigma_mm=sigma_mm, seed=seed, certify=False)
    sim = SimulationOptions(sigma_mm=sigma_mm, seed=seed)
    table, truth = simulate(robot, q, sim)
    rounds, fewest, plan = 0, None, None
    while True:
        data = Measurements.from_table(table, robot)
        step = next_poses(robot, data, opts, cell=problem.cell, plan=plan)
        plan = step.q_plan
        if fewest is None:
            fewest = len(q) + step.min_more_poses
        if step.done or len(q) >= max_poses:
            break
        q = np.concatenate([q, step.q_next])
        more, _ = simulate(robot, q, dataclasses.replace(sim, seed=seed))  # the same truth, fresh noise
        table = pd.concat([table, more.iloc[-len(step.q_next) :]], ignore_index=True)
        rounds += 1
    report = step.report
    scale = report.chi2_per_dof if step.aposteriori else 1.0
    cov = report.kpi_cov * scale
    s_true = kpi_jacobian(truth["model"], report.q_work)[0]
    e = np.asarray(report.kpi) - s_true
    d2 = float(e @ np.linalg.solve(cov, e))
    return {
        "seed": int(seed),
        "n_poses": int(len(q)),
        "done": bool(step.done),
        "rounds": rounds,
        "kpi_avg_var_mm2": step.kpi_avg_var_mm2,
        "mahalanobis2": d2,
        "inside_95": bool(d2 <= ELLIPSOID_95),
        "error_mm": float(np.linalg.norm(e)),
        "aposteriori": bool(step.aposteriori),
        "certified_min_poses": int(fewest),
    }


def start_bound(
    robot: Robot, *, seed: int, n_more: int, sigma_mm: float = 1.0, n_start: int = 10, rounds: int = 6
) -> dict:
    """How well any ``n_more`` poses can do after the loop's start (:func:`closed_loop`, ``seed``):
    the approximate design of ``n_more`` poses with the start's information held fixed
    (:func:`~kpioed_drake.design.approximate.given.given_design`, ``rounds`` of column generation)
    at the nominal model.

    Returns:
        ``{"seed", "bound_mm2": lower bound on tr(Cs)/3 of the start and any n_more feasible poses
        (rigorous for the poses the search reached), "pool_mm2": the approximate optimum over its
        candidates (what weights, not poses, reach), "n_candidates"}``.
    """
    problem, q = loop_start(robot, seed=seed, n_start=n_start, sigma_mm=sigma_mm)
    approx = certified_design(problem, collision=True, seed=seed)
    gd = given_design(problem, approx, given=q, n=n_more, collision=True, rounds=rounds)
    K = kpi_factor(problem)
    pool_g = float(dual_values(gd.F, gd.Y).max())
    return {
        "seed": int(seed),
        "bound_mm2": float(gd.bound(K, n_more)),
        "pool_mm2": float(bound_of(K, gd.Y, gd.fixed, pool_g, n_more)),
        "n_candidates": int(len(gd.q)),
    }
