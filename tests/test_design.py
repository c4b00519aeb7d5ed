"""Tests of the optimum experimental design (kpioed_drake.design) and its command line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from fd import central_fd
from numpy.testing import assert_allclose
from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff

from kpioed_drake import api, design
from kpioed_drake.cli import main
from kpioed_drake.design import (
    DesignConstraints,
    DesignError,
    DesignObjective,
    DesignProgram,
    heuristic_design,
    incidence_rows,
    optimize_design,
)
from kpioed_drake.design.exact import solve as design_solve
from kpioed_drake.design.exact.constraints import restore_incidence
from kpioed_drake.design.settings import INCIDENCE_MARGIN_DEG
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design
from kpioed_drake.tracker.feasibility import TOL_DEG, FeasibilityChecker
from kpioed_drake.tracker.measurement import incidence_cosine


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16")


def _random_poses(problem, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(problem.robot.lower, problem.robot.upper, size=(n, 6))


# ----------------------------------------------------------------------------------------------
# Derivatives
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("criterion", ["kpi", "param", "d", "o1"])
def test_objective_gradient_matches_central_differences(kr16, criterion):
    q = _random_poses(kr16, 12, seed=1)
    obj = DesignObjective(kr16, criterion)
    value, grad = obj.value_and_grad(q)
    assert grad.shape == (12, 6)
    assert_allclose(value, obj.value(q), rtol=1e-12)
    fd = central_fd(obj.value, q, 1e-6)
    scale = np.max(np.abs(fd))
    assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * scale)


def test_incidence_gradient_matches_central_differences(kr16):
    q = _random_poses(kr16, 10, seed=2)
    c, dc = incidence_rows(kr16, q)
    assert_allclose(c + np.cos(kr16.cell.max_incidence), incidence_cosine(kr16.model, q), atol=1e-14)
    fd = central_fd(lambda x: incidence_rows(kr16, x)[0], q, 1e-6)  # (n, n, 6)
    assert_allclose(dc, np.einsum("kkj->kj", fd), rtol=1e-6, atol=1e-8)
    off = fd.copy()
    off[np.arange(10), np.arange(10)] = 0.0
    assert np.max(np.abs(off)) == 0.0  # each row depends only on its own pose


def test_constraint_gradient_matches_central_differences(kr16):
    q = heuristic_design(kr16, n=8, seed=3)
    cons = DesignConstraints(kr16, collision=True)
    v, J = cons.evaluate(q)
    assert v.shape == (8, cons.rows_per_pose) and J.shape == (8, cons.rows_per_pose, 6)
    assert cons.rows_per_pose == 1 + cons.clearance.n_rows
    fd = central_fd(lambda x: cons.evaluate(x)[0], q, 1e-6)  # (n, r, n, 6)
    own = np.stack([fd[k, :, k, :] for k in range(8)])
    assert_allclose(J[:, 0], own[:, 0], rtol=1e-6, atol=1e-8)  # incidence [1/rad]
    assert_allclose(J[:, 1:], own[:, 1:], rtol=1e-5, atol=1e-5)  # clearances [mm/rad]


def test_autodiff_path_returns_the_same_values_and_gradients(kr16):
    n = 10
    q = heuristic_design(kr16, n=n, seed=4)
    dp = DesignProgram(kr16, criterion="kpi", n=n, collision=True, cost_scale=2.0, active_rows=None)
    x = q.reshape(-1)
    xad = InitializeAutoDiff(x)
    # cost
    v, g = dp.objective.value_and_grad(q)
    c_float = dp.cost_binding.evaluator().Eval(x)
    c_ad = dp.cost_binding.evaluator().Eval(xad)
    assert_allclose(c_float[0], 2.0 * v, rtol=1e-13)
    assert_allclose(ExtractValue(c_ad).ravel(), [2.0 * v], rtol=1e-13)
    assert_allclose(ExtractGradient(c_ad).ravel(), 2.0 * g.ravel(), rtol=1e-13)
    # constraint: values scaled per row, block-diagonal gradient
    vals, J = dp.constraints.evaluate(q)
    s = dp.constraints.row_scale()
    y_float = dp.constraint_binding.evaluator().Eval(x)
    y_ad = dp.constraint_binding.evaluator().Eval(xad)
    assert_allclose(y_float, (vals * s).ravel(), rtol=1e-13)
    assert_allclose(ExtractValue(y_ad).ravel(), (vals * s).ravel(), rtol=1e-13)
    G = ExtractGradient(y_ad)
    r = dp.constraints.rows_per_pose
    expected = np.zeros((n, r, n, 6))
    for k in range(n):
        expected[k, :, k, :] = J[k] * s[:, None]
    assert_allclose(G, expected.reshape(n * r, 6 * n), rtol=1e-13, atol=0)
    # the same rows split into constraints of 3 poses each
    dpb = DesignProgram(kr16, criterion="kpi", n=n, collision=True, pose_block=3, active_rows=None)
    assert len(dpb.constraint_bindings) == 4
    yb = np.concatenate(
        [
            ExtractValue(bb.evaluator().Eval(xad[6 * k0 : 6 * (k0 + m)])).ravel()
            for bb, k0, m in zip(dpb.constraint_bindings, (0, 3, 6, 9), (3, 3, 3, 1))
        ]
    )
    assert_allclose(yb, (vals * s).ravel(), rtol=1e-13)
    G3 = ExtractGradient(dpb.constraint_bindings[1].evaluator().Eval(xad[18:36]))
    assert_allclose(G3, expected[3:6, :, 3:6, :].reshape(3 * r, 18), rtol=1e-13, atol=0)
    # declared sparsity pattern covers exactly the per-pose blocks
    pattern = dp.constraint_binding.evaluator().gradient_sparsity_pattern()
    assert len(pattern) == n * r * 6
    assert all(col // 6 == row // r for row, col in pattern)


def test_clearance_jacobian_of_selected_rows_equals_those_rows_of_the_full_jacobian(kr16):
    cm = DesignConstraints(kr16, collision=True).clearance
    q = heuristic_design(kr16, n=7, seed=11)
    v, J = cm.evaluate(q)
    rows = np.random.default_rng(2).integers(0, cm.n_rows, size=(7, 5))
    v2, Jr = cm.evaluate(q, rows=rows)
    assert_allclose(v2, v, rtol=0, atol=0)
    assert_allclose(Jr, np.take_along_axis(J, rows[:, :, None], axis=1), rtol=0, atol=0)


def test_active_rows_are_the_smallest_and_keep_their_slots():
    rng = np.random.default_rng(5)
    v = rng.uniform(0, 100, size=(50, 12))
    a = design.update_active_rows(v, None, 4)
    assert_allclose(np.take_along_axis(v, a, 1), np.sort(v, 1)[:, :4], rtol=0, atol=0)
    # move the values: the set is again the 4 smallest; rows still in it keep their position
    v2 = v + rng.normal(0, 15, size=v.shape)
    b = design.update_active_rows(v2, a, 4)
    assert_allclose(np.sort(np.take_along_axis(v2, b, 1), 1), np.sort(v2, 1)[:, :4], rtol=0, atol=0)
    stayed = (a[:, :, None] == b[:, None, :]).any(2)
    assert stayed.any() and (~stayed).any()  # both cases happen
    assert np.all(b[stayed] == a[stayed])
    assert np.all([len(set(r)) == 4 for r in b])  # no row twice
    with pytest.raises(ValueError):
        design.update_active_rows(v, None, 13)


def test_program_with_active_rows_passes_the_smallest_clearances_and_their_gradient(kr16):
    n, m = 9, 4
    q = heuristic_design(kr16, n=n, seed=6)
    dp = DesignProgram(kr16, criterion="kpi", n=n, collision=True, active_rows=m)
    assert dp.rows_per_pose == 1 + m
    vals, J = dp.constraints.evaluate(q)
    y = dp.constraint_binding.evaluator().Eval(InitializeAutoDiff(q.reshape(-1)))
    Y, G = ExtractValue(y).reshape(n, 1 + m), ExtractGradient(y).reshape(n, 1 + m, n, 6)
    s = dp.constraints.row_scale(1 + m)
    assert_allclose(Y[:, 0], vals[:, 0], rtol=1e-13)
    assert_allclose(Y[:, 1:] / s[1], np.sort(vals[:, 1:], axis=1)[:, :m], rtol=1e-13)
    active = dp.active
    assert active.shape == (n, m)
    for k in range(n):
        assert_allclose(G[k, :, k, :], J[k, np.r_[0, 1 + active[k]]] * s[:, None], rtol=1e-13, atol=0)
        others = np.delete(np.arange(n), k)
        assert np.all(G[k, :, others, :] == 0.0)
    # pose blocks hold their own slots and give the same rows
    dpb = DesignProgram(kr16, criterion="kpi", n=n, collision=True, active_rows=m, pose_block=4)
    yb = np.concatenate(
        [
            ExtractValue(b.evaluator().Eval(InitializeAutoDiff(q[k0 : k0 + 4].reshape(-1)))).ravel()
            for b, k0 in zip(dpb.constraint_bindings, (0, 4, 8), strict=True)
        ]
    )
    assert_allclose(yb, ExtractValue(y).ravel(), rtol=1e-13)
    assert np.array_equal(dpb.active, active)


def test_pose_blocks_compute_all_rows_once_and_never_reuse_rows_of_other_angles(kr16):
    n, m = 25, 4
    q = heuristic_design(kr16, n=n, seed=3)
    one = DesignProgram(kr16, criterion="kpi", n=n, collision=True, active_rows=m, pose_block=None)
    blk = DesignProgram(kr16, criterion="kpi", n=n, collision=True, active_rows=m, pose_block=10)
    assert len(one.constraint_bindings) == 1 and len(blk.constraint_bindings) == 3
    calls = []
    evaluate_active = blk.constraints.evaluate_active

    def counting(q, *args, **kwargs):
        calls.append(len(q))
        return evaluate_active(q, *args, **kwargs)

    blk.constraints.evaluate_active = counting
    xad = InitializeAutoDiff(q.reshape(-1))
    for dp in (one, blk):  # the solver evaluates the cost first
        dp.cost_binding.evaluator().Eval(xad)
    y = one.constraint_binding.evaluator().Eval(xad)
    Y, G = ExtractValue(y).reshape(n, 1 + m), ExtractGradient(y).reshape(n, 1 + m, n, 6)
    starts, sizes = (0, 10, 20), (10, 10, 5)
    for b, k0, nb in zip(blk.constraint_bindings, starts, sizes, strict=True):
        yb = b.evaluator().Eval(xad[6 * k0 : 6 * (k0 + nb)])
        assert_allclose(ExtractValue(yb).reshape(nb, 1 + m), Y[k0 : k0 + nb], rtol=0, atol=0)
        Gb = ExtractGradient(yb).reshape(nb, 1 + m, nb, 6)
        assert_allclose(Gb, G[k0 : k0 + nb, :, k0 : k0 + nb, :], rtol=0, atol=0)
    assert calls == [n]  # every pose's rows in one call, by the first block
    assert np.array_equal(blk.active, one.active)
    # a block evaluated at other angles than the cost's computes its own rows
    q2 = heuristic_design(kr16, n=10, seed=9)
    y2 = blk.constraint_bindings[1].evaluator().Eval(InitializeAutoDiff(q2.reshape(-1)))
    assert calls == [n, 10]
    vals, _ = blk.constraints.evaluate(q2)
    Y2 = ExtractValue(y2).reshape(10, 1 + m)
    s = blk.constraints.row_scale(1 + m)
    assert_allclose(Y2[:, 0], vals[:, 0], rtol=1e-13)
    assert_allclose(np.sort(Y2[:, 1:], axis=1) / s[1], np.sort(vals[:, 1:], axis=1)[:, :m], rtol=1e-13)
    # and the kept rows of the other poses are still those of q
    y0 = blk.constraint_bindings[0].evaluator().Eval(xad[:60])
    assert_allclose(ExtractValue(y0).reshape(10, 1 + m), Y[:10], rtol=0, atol=0)
    assert calls == [n, 10]


@pytest.mark.slow
def test_active_rows_and_all_rows_reach_feasible_designs_of_similar_value(kr16):
    kw = dict(criterion="kpi", n=20, seed=1, allow_infeasible=True)
    few = optimize_design(kr16, active_rows=4, **kw)
    full = optimize_design(kr16, active_rows=None, **kw)
    assert few.success and few.feasible and full.success and full.feasible
    # local optima from one start: within 10 % of each other
    assert abs(few.value / full.value - 1) < 0.10


# ----------------------------------------------------------------------------------------------
# Heuristic design
# ----------------------------------------------------------------------------------------------
def test_heuristic_design_is_seeded_feasible_and_batch_independent(kr16):
    q1 = heuristic_design(kr16, n=20, seed=7)
    q2 = heuristic_design(kr16, n=20, seed=7, batch=333)
    q3 = heuristic_design(kr16, n=20, seed=8)
    assert q1.shape == (20, 6)
    assert_allclose(q1, q2, rtol=0, atol=0)
    assert not np.allclose(q1, q3)
    assert np.all(q1 >= kr16.robot.lower) and np.all(q1 <= kr16.robot.upper)
    reports = FeasibilityChecker(kr16.robot, kr16.cell).check(q1)
    assert all(r.feasible for r in reports)
    assert min(r.min_clearance_mm for r in reports) >= design.HEURISTIC_MARGIN_MM - 1e-6


def test_heuristic_design_without_collision_checks_only_incidence(kr16):
    q = heuristic_design(kr16, n=40, seed=0, collision=False)
    c, _ = incidence_rows(kr16, q)
    assert np.all(c >= 0)


def test_heuristic_design_reports_when_it_finds_too_few_poses(kr16):
    with pytest.raises(InputError, match="feasible pose.* in 10 draws"):
        heuristic_design(kr16, n=60, seed=0, max_draws=10)


# ----------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------
def test_too_few_poses_is_an_input_error_naming_the_minimum(kr16):
    assert kr16.min_poses() == 9
    with pytest.raises(InputError, match="at least 9 poses"):
        optimize_design(kr16, criterion="kpi", n=8)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(criterion="e-optimal"), "unknown criterion"),
        (dict(solver="knitro"), "unknown solver"),
        (dict(starts=0), "starts"),
        (dict(q0=np.zeros((3, 6))), "q0"),
    ],
)
def test_bad_arguments_are_input_errors(kr16, kwargs, match):
    args = dict(criterion="kpi", n=12)
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        optimize_design(kr16, **args)


def test_q_work_outside_limits_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="outside"):
        design.run_design(
            "kr16",
            design.DesignOptions(criterion="heuristic", n=12),
            q_work_deg="0,0,0,0,179,0",
            out=tmp_path / "d.csv",
        )
    assert not (tmp_path / "d.csv").exists()


def test_cli_bad_input_exits_2(tmp_path, capsys):
    out = str(tmp_path / "d.csv")
    assert main(["design", "--robot", "kr16", "--criterion", "kpi", "--n", "5", "--out", out]) == 2
    assert "at least 9 poses" in capsys.readouterr().err
    assert main(f"design --robot kr16 --criterion heuristic --q-work 0,0,0,0,179,0 --out {out}".split()) == 2
    assert main(["design", "--robot", "no-such-robot", "--criterion", "kpi", "--out", out]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["design", "--robot", "kr16", "--criterion", "e-optimal", "--out", out])
    assert exc.value.code == 2
    assert not (tmp_path / "d.csv").exists()


# ----------------------------------------------------------------------------------------------
# Optimised designs
# ----------------------------------------------------------------------------------------------
def test_snopt_stops_looser_only_beyond_a_six_joint_solve():
    def tol(n, nj):
        return design_solve.solver_options("snopt", n, n_joints=nj)["Major optimality tolerance"]

    # six joints: one solve, sweep blocks
    assert tol(60, 6) == tol(30, 6) == design_solve.OPTIMALITY_TOLERANCE
    # the 18-joint twin's 40 poses: 720 variables
    assert tol(40, 18) == design_solve.LARGE_OPTIMALITY_TOLERANCE > design_solve.OPTIMALITY_TOLERANCE
    assert design_solve.solver_options("snopt", 40, n_joints=18)["Superbasics limit"] >= 18 * 40


def test_solver_failure_raises_design_error_and_cli_exits_3(kr16, tmp_path, monkeypatch, capsys):
    orig = design_solve.solver_options

    def one_iteration(solver, n, **kw):
        opts = orig(solver, n, **kw)
        opts["Major iterations limit"] = 1
        return opts

    monkeypatch.setattr(design_solve, "solver_options", one_iteration)
    with pytest.raises(DesignError, match="failed") as exc:  # the heuristic start: no start search
        optimize_design(kr16, criterion="kpi", n=12, start="heuristic")
    assert exc.value.result is not None and not exc.value.result.success
    res = optimize_design(kr16, criterion="kpi", n=12, start="heuristic", allow_infeasible=True)
    assert not res.success and "snopt info" in res.status

    out, js = tmp_path / "d.csv", tmp_path / "d.json"
    code = main(
        f"design --robot kr16 --criterion kpi --n 12 --start heuristic --out {out} --json {js}".split()
    )
    assert code == 3
    assert not out.exists()
    rec = json.loads(js.read_text())
    assert rec["success"] is False and "error" in rec


def test_cli_writes_a_design_that_evaluate_reads(tmp_path, capsys):
    out, js, png = tmp_path / "kpi.csv", tmp_path / "kpi.json", tmp_path / "kpi.png"
    cmd = f"design --robot kr16 --criterion kpi --n 15 --seed 1 --no-certify --out {out} --json {js}"
    code = main([*cmd.split(), "--plot", str(png)])  # the certificate: tests/test_design_start.py
    assert code == 0
    text = capsys.readouterr().out
    assert "tr(Cs)/3" in text and "15/15 poses feasible" in text
    rec = json.loads(js.read_text())
    keys = "criterion values solver status solve_s n_evals feasible poses n_colliding_poses".split()
    assert set(keys) <= set(rec)
    assert rec["criterion"] == "kpi" and rec["feasible"] is True and len(rec["poses"]) == 15
    problem = make_problem("kr16")
    q = read_design(out, problem.robot)
    assert q.shape == (15, 6)
    ev = api.evaluate("kr16", str(out), certify=False)  # the certificate: test_design_start
    assert_allclose(ev["kpi_avg_var_mm2"], rec["values"]["kpi_avg_var_mm2"], rtol=1e-4)
    assert ev["feasible"]
    assert png.stat().st_size > 10_000
    # the optimum improves on its heuristic start
    assert rec["values"]["kpi_avg_var_mm2"] < rec["initial_values"][0]


def test_heuristic_cli_with_json(tmp_path, capsys):
    out, js = tmp_path / "h.csv", tmp_path / "h.json"
    assert main(f"design --robot kr16 --criterion heuristic --n 20 --out {out} --json {js}".split()) == 0
    rec = json.loads(js.read_text())
    assert rec["solver"] == "none" and rec["n_poses"] == 20 and rec["feasible"]


def _study(robot: str, n: int, seed: int = 0) -> dict:
    problem = make_problem(robot)
    checker = FeasibilityChecker(problem.robot, problem.cell)
    out = {}
    for crit in ("heuristic", "param", "d", "o1", "kpi"):
        res = optimize_design(problem, criterion=crit, n=n, seed=seed)
        assert res.success and res.feasible, (robot, crit, res.status)
        reports = checker.check(res.q)  # independent check, all constraints
        assert all(r.feasible for r in reports), (robot, crit)
        out[crit] = res
    return out


def _assert_study_ordering(results: dict) -> None:
    kpi = {c: r.kpi_avg_var_mm2 for c, r in results.items()}
    assert kpi["kpi"] < kpi["param"], kpi
    for crit in ("param", "d", "o1", "kpi"):
        assert kpi[crit] < kpi["heuristic"], (crit, kpi)
    # each optimiser is best in its own criterion among the optimised designs it is compared with
    p_param, p_kpi = results["param"].param_crit, results["kpi"].param_crit
    assert p_param <= p_kpi, (p_param, p_kpi)


@pytest.mark.parametrize(
    "robot",
    [
        pytest.param("kr16", marks=pytest.mark.slow),
        pytest.param("kr300", marks=pytest.mark.slow),
        "notional-850-800",
    ],
)
def test_reduced_study(robot):
    _assert_study_ordering(_study(robot, n=30))


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["kr500", "notional-650-1000", "notional-1100-1000"])
def test_reduced_study_slow(robot):
    _assert_study_ordering(_study(robot, n=30))


@pytest.mark.slow
def test_design_without_collision_avoidance_reports_collisions(kr16):
    res = optimize_design(kr16, criterion="kpi", n=30, collision=False, seed=0)
    assert res.success and res.feasible  # joint limits and incidence hold
    assert res.n_infeasible_poses == 0
    # the count equals an independent query: Drake's signed distances (and the beam distances)
    # of every pose, below the checker's tolerance
    checker = FeasibilityChecker(kr16.robot, kr16.cell)
    clearances = [min(checker.clearances(qi).values()) for qi in res.q]
    n_col = sum(c < -checker.tol_mm for c in clearances)
    assert res.n_colliding_poses == n_col
    assert n_col > 0  # without collision avoidance the KPI optimum moves poses into collision
    colliding = {
        r["index"] for r in res.reports if any(f["check"] in ("collision", "beam") for f in r["failures"])
    }
    assert colliding == {k for k, c in enumerate(clearances) if c < -checker.tol_mm}


def test_fixed_information_equals_the_design_with_those_poses_added(kr16):
    q = heuristic_design(kr16, n=20, seed=7)
    block, rest = q[:8], q[8:]
    F = kr16.F1(rest)
    for crit in design.CRITERIA:
        v, g = DesignObjective(kr16, crit).value_and_grad(np.vstack([block, rest]))
        vb, gb = DesignObjective(kr16, crit, fixed_information=F.T @ F).value_and_grad(block)
        assert_allclose(vb, v, rtol=1e-12, err_msg=crit)
        assert_allclose(gb, g[:8], rtol=1e-9, atol=1e-12 * np.abs(g).max(), err_msg=crit)


@pytest.mark.slow
def test_block_sweeps_keep_the_design_feasible_and_reach_a_value_like_one_solve(kr16):
    kw = dict(criterion="kpi", n=24, seed=2, allow_infeasible=True, start="heuristic")  # a poor start
    swept = optimize_design(kr16, max_block=12, sweep_block=8, **kw)
    one = optimize_design(kr16, max_block=None, **kw)
    assert one.sweeps == 0 and "sweeps" not in one.status
    assert swept.sweeps >= 2 and "over 3 blocks of <= 8 poses" in swept.status
    assert swept.success and swept.feasible
    assert swept.value < 0.5 * swept.initial_values[0]
    assert_allclose(swept.value, DesignObjective(kr16, "kpi").value(swept.q), rtol=1e-12)
    assert swept.summary()["sweeps"] == swept.sweeps
    # local optima from one start: within 10 % of each other
    assert abs(swept.value / one.value - 1) < 0.10
    with pytest.raises(InputError, match="max_block"):
        optimize_design(kr16, max_block=0, **kw)
    with pytest.raises(InputError, match="sweep_block"):
        optimize_design(kr16, sweep_block=0, **kw)


def test_check_accepts_what_the_solver_tolerance_allows_and_no_more(kr16):
    """The independent check's angle tolerance is not tighter than SNOPT's: an incidence 5e-6 deg
    beyond the limit (1e-7 on the cos row allows 1.1e-5 deg at 30 deg) is feasible, 1e-3 deg is not."""
    q = _random_poses(kr16, 1, 3)[0]
    inc = FeasibilityChecker(kr16.robot, kr16.cell).incidence_deg(q)
    solver_slack_deg = np.rad2deg(1e-7 / np.sin(kr16.cell.max_incidence))
    assert solver_slack_deg < TOL_DEG
    for beyond, ok in [(5e-6, True), (1e-3, False)]:
        cell = dataclasses.replace(kr16.cell, max_incidence=np.deg2rad(inc - beyond))
        rep = FeasibilityChecker(kr16.robot, cell).check_pose(q, collision=False)
        assert rep.feasible is ok


def test_restore_incidence_pulls_back_solver_overshoots_only(kr16):
    """A pose beyond the incidence limit by a solver's tolerance (1e-3 deg) is moved back inside the
    optimiser's bound; a feasible pose and one 0.1 deg beyond (a real failure) are not touched."""
    q = _random_poses(kr16, 3, 4)
    inc = FeasibilityChecker(kr16.robot, kr16.cell).incidence_deg(q[0])
    problem = dataclasses.replace(
        kr16, cell=dataclasses.replace(kr16.cell, max_incidence=np.deg2rad(inc - 1e-3))
    )
    checker = FeasibilityChecker(problem.robot, problem.cell)
    assert not checker.check_pose(q[0], collision=False).feasible
    out = restore_incidence(problem, q[:1])
    assert checker.check_pose(out[0], collision=False).feasible
    assert (
        checker.incidence_deg(out[0]) <= np.rad2deg(problem.cell.max_incidence) - 0.9 * INCIDENCE_MARGIN_DEG
    )
    assert 0 < np.max(np.abs(out[0] - q[0])) < np.deg2rad(0.01)
    far = dataclasses.replace(kr16, cell=dataclasses.replace(kr16.cell, max_incidence=np.deg2rad(inc - 0.1)))
    assert np.array_equal(restore_incidence(far, q[:1]), q[:1])
    ok = [p for p in q if checker.check_pose(p, collision=False).feasible]
    assert ok and np.array_equal(restore_incidence(problem, np.array(ok)), np.array(ok))
