"""The approximate design with measured poses held fixed: its dual bound checked against designs and
the identity it rests on, the second start of a design with given poses, the certified fewest
poses of ``kpioed next`` and the plan carried from step to step."""

from __future__ import annotations

import numpy as np
import pytest

from kpioed_drake import api
from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.given import (
    fewest_certified,
    given_design,
    information_factor,
)
from kpioed_drake.design.approximate.search import pose_rows
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design, write_design
from kpioed_drake.online import start_bound
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate, table_csv_text

N_NEW = 20


@pytest.fixture(scope="module")
def setup():
    """kr16 at 1 mm, 10 heuristic poses measured, the certified design and the one with them."""
    problem = make_problem(load_robot("kr16"), sigma_mm=1.0)
    given = heuristic_design(problem, n=10, seed=7)
    approx = certificate.certified_design(problem, collision=True, seed=0)
    gd = given_design(problem, approx, given=given, n=N_NEW, collision=True)
    return problem, given, approx, gd


def test_information_factor_reproduces_the_information():
    F = np.random.default_rng(0).normal(size=(12, 5))
    M0 = F.T @ F
    R0 = information_factor(M0)
    np.testing.assert_allclose(R0.T @ R0, M0, rtol=0, atol=1e-12 * np.abs(M0).max())
    low = information_factor(F[:3].T @ F[:3])  # rank 3 of 5: the zero directions dropped
    assert low.shape == (3, 5)


def test_the_identity_behind_the_bound(setup):
    """tr(K^T M^-1 K) >= 2 tr(K^T Y) - tr(Y^T M Y) for any Y, with equality at Y = M^-1 K."""
    problem, given, _, _ = setup
    q = np.concatenate([given, heuristic_design(problem, n=N_NEW, seed=8)])
    F = pose_rows(problem, q).reshape(-1, problem.n_params)
    M, K = F.T @ F, kpi_factor(problem)
    value = problem.criteria(q)["kpi_avg_var_mm2"]
    X = np.linalg.solve(M, K)
    assert 2 * np.sum(K * X) - np.sum(X * (M @ X)) == pytest.approx(value, rel=1e-9)
    rng = np.random.default_rng(1)
    for _ in range(5):
        Y = X * (1 + 0.3 * rng.normal(size=X.shape))
        assert 2 * np.sum(K * Y) - np.sum(Y * (M @ Y)) <= value


@pytest.mark.slow
def test_the_bound_holds_for_designs_and_beats_the_bound_without_the_measured_poses(setup):
    problem, given, approx, gd = setup
    K = kpi_factor(problem)
    bound = gd.bound(K, N_NEW)
    for seed in (1, 2, 3):  # random feasible poses: far above the bound
        q = heuristic_design(problem, n=N_NEW, seed=seed)
        assert problem.criteria(np.concatenate([given, q]))["kpi_avg_var_mm2"] >= bound
    best = optimize_design(problem, criterion="kpi", n=N_NEW, seed=0, given=given)
    assert best.kpi_avg_var_mm2 >= bound
    assert best.kpi_avg_var_mm2 <= 1.05 * bound  # the optimised design is near it
    fixed = float(np.sum((pose_rows(problem, given) @ approx.Y) ** 2))
    loose = approx.dual / (approx.g_max * N_NEW + fixed)  # Y of the design without given poses
    assert bound > loose
    cert = certificate.certify(problem, best.q, collision=True, seed=0, given=given)
    assert loose < cert["bound_mm2"] <= best.kpi_avg_var_mm2


@pytest.mark.slow
def test_a_design_with_given_poses_solves_from_both_roundings(setup):
    problem, given, _, _ = setup
    res = optimize_design(problem, criterion="kpi", n=N_NEW, seed=0, given=given)
    assert len(res.start_values) == 2 and res.kpi_avg_var_mm2 == pytest.approx(min(res.start_values))
    more = optimize_design(problem, criterion="kpi", n=N_NEW, seed=0, given=given, starts=2)
    assert len(more.start_values) == 3  # the further start is heuristic


@pytest.mark.slow
def test_fewer_poses_than_certified_cannot_reach_the_target(setup):
    problem, given, _, gd = setup
    K = kpi_factor(problem)
    target = float(gd.bound(K, N_NEW))
    fewest = fewest_certified(problem, gd, target=target, n_max=60)
    assert fewest == N_NEW  # the bound at N_NEW is the target; at N_NEW - 1 it is above
    below = optimize_design(problem, criterion="kpi", n=fewest - 1, seed=0, given=given)
    assert below.kpi_avg_var_mm2 > target
    assert fewest_certified(problem, gd, target=0.0, n_max=60) == 61


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """10 heuristic poses of a simulated kr16 measured with 1 mm noise."""
    work = tmp_path_factory.mktemp("plan")
    robot = load_robot("kr16")
    q = heuristic_design(make_problem(robot, sigma_mm=1.0), n=10, seed=3)
    write_design(work / "given.csv", q)
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=1.0, seed=3))
    (work / "data.csv").write_text(table_csv_text(table))
    return work


@pytest.mark.slow
def test_next_plans_whole_batches_and_carries_its_plan(measured):
    """The plan is whole batches of at least the certified fewest poses; written to ``--plan``;
    the next step, started from it, ends no worse than the rest of it."""
    plan_file = measured / "plan.csv"
    rec = api.next("kr16", measured / "data.csv", target_var_mm2=0.3, n=5, sigma_mm=1.0, certify=False,
                   out=measured / "next.csv", plan=plan_file)  # fmt: skip
    h, fewest = rec["n_planned"], rec["min_more_poses"]
    assert h % 5 == 0 and fewest <= h < fewest + 5
    robot = load_robot("kr16")
    q_plan, q_next = read_design(plan_file, robot), read_design(measured / "next.csv", robot)
    assert q_plan.shape == (h, 6)
    assert all(np.any(np.all(np.isclose(q_plan, x, atol=1e-9), axis=1)) for x in q_next)
    # measure the next poses (noise free: the estimate changes little) and step again
    given = read_design(measured / "given.csv", robot)
    both = np.concatenate([given, q_next])
    table, _ = simulate(robot, both, SimulationOptions(sigma_mm=1.0, seed=3))
    (measured / "data2.csv").write_text(table_csv_text(table))
    problem = make_problem(robot, sigma_mm=1.0)
    rest = q_plan[~np.any(np.all(np.isclose(q_plan[:, None], q_next[None], atol=1e-9), axis=2), axis=1)]
    rest_value = problem.criteria(np.concatenate([both, rest]))["kpi_avg_var_mm2"]
    rec2 = api.next("kr16", measured / "data2.csv", target_var_mm2=0.3, n=5, sigma_mm=1.0, certify=False,
                    out=measured / "next2.csv", plan=plan_file)  # fmt: skip
    q_plan2 = read_design(plan_file, robot)
    if rec2["n_planned"] == len(rest):
        value2 = problem.criteria(np.concatenate([both, q_plan2]))["kpi_avg_var_mm2"]
        assert value2 <= rest_value * (1 + 1e-9)
    done = api.next("kr16", measured / "data2.csv", target_var_mm2=1e6, n=5, sigma_mm=1.0, certify=False,
                    out=measured / "next3.csv", plan=plan_file)  # fmt: skip
    assert done["done"] and not plan_file.exists() and not (measured / "next3.csv").exists()


@pytest.mark.slow
def test_start_bound_is_below_the_design_after_the_loops_start():
    """The study's bound on any continuation of a loop's start holds for the optimised one."""
    robot = load_robot("kr16")
    rec = start_bound(robot, seed=0, n_more=N_NEW, rounds=1)
    problem = make_problem(robot, sigma_mm=1.0)
    start = optimize_design(problem, criterion="heuristic", n=10, seed=0).q
    best = optimize_design(problem, criterion="kpi", n=N_NEW, seed=0, given=start)
    assert rec["bound_mm2"] <= rec["pool_mm2"] <= best.kpi_avg_var_mm2


def test_the_cone_program_is_the_approximate_design_with_measured_poses(setup):
    """Strong duality: the cone program's value equals the best weights (SLSQP, independent)."""
    from scipy.optimize import minimize

    from kpioed_drake.design.approximate.given import solve_given_pool
    from kpioed_drake.design.approximate.search import dual_values

    problem, given, _, _ = setup
    F = pose_rows(problem, heuristic_design(problem, n=40, seed=11))
    K = kpi_factor(problem)
    F0 = pose_rows(problem, given).reshape(-1, problem.n_params)
    M0 = F0.T @ F0
    Y = solve_given_pool(F, K, information_factor(M0), N_NEW)
    dual = 2 * np.sum(K * Y) - np.sum((F0 @ Y) ** 2) - N_NEW * dual_values(F, Y).max()
    G = F.transpose(0, 2, 1) @ F

    def value_and_grad(c):
        X = np.linalg.solve(M0 + np.einsum("i,ikl->kl", c, G), K)
        FX = F @ X  # (m, 3, 3)
        return float(np.sum(K * X)), -np.einsum("iac,iac->i", FX, FX)

    m = len(F)
    res = minimize(value_and_grad, np.full(m, N_NEW / m), jac=True, method="SLSQP",
                   bounds=[(0, None)] * m, constraints=[{"type": "eq", "fun": lambda c: c.sum() - N_NEW}],
                   options={"maxiter": 500, "ftol": 1e-14})  # fmt: skip
    assert dual <= res.fun * (1 + 1e-9)
    assert dual == pytest.approx(res.fun, rel=1e-6)  # measured 1e-8
