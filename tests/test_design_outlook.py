"""Tests of the paper's Outlook and Conclusion items of the design: several KPIs (working poses or a
sampled path, mean or worst), sequential designs given poses already measured, and the fewest poses
reaching a target tr(Cs)/3."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from fd import central_fd
from numpy.testing import assert_allclose

from kpioed_drake.cli import main
from kpioed_drake.design import (
    DesignObjective,
    DesignProgram,
    design_for_target,
    heuristic_design,
    optimize_design,
    read_working_poses,
    remove_poses,
)
from kpioed_drake.design import target as design_target
from kpioed_drake.design.exact import solve as design_solve
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import criteria
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design, write_design

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import reader_transitions as rt  # noqa: E402

PATH_OFFSETS_DEG = np.array([[0, 0, 0, 0, 0, 0], [20, 10, -10, 0, 15, 0], [-20, -5, 10, 0, -10, 30]])
"""A working path around kr16's q_work sampled at 3 points [deg] (within the joint limits)."""


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16", sigma_mm=1.0)


@pytest.fixture(scope="module")
def path(kr16):
    return kr16.q_work + np.deg2rad(PATH_OFFSETS_DEG)


# ----------------------------------------------------------------------------------------------
# Several KPIs
# ----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_one_working_pose_in_the_several_kpi_form_is_exactly_the_single_kpi(kr16):
    one = make_problem("kr16", sigma_mm=1.0, q_work=kr16.q_work[None, :], kpi_weights=[3.0])
    assert one.n_kpis == 1 and one.Js().shape == (3, 27)
    assert np.array_equal(one.Js(), kr16.Js()) and np.array_equal(one.scale, kr16.scale)
    a = optimize_design(kr16, n=15, seed=3)
    b = optimize_design(one, n=15, seed=3)
    assert np.array_equal(a.q, b.q) and a.kpi_avg_var_mm2 == b.kpi_avg_var_mm2
    assert b.kpi_vars_mm2 is None and "kpi_vars_mm2" not in b.summary()["values"]
    # K = 1 with the worst case is the single KPI too (no epigraph variable)
    worst = make_problem("kr16", sigma_mm=1.0, q_work=kr16.q_work, kpi_aggregate="max")
    assert not worst.worst_case and DesignProgram(worst, criterion="kpi", n=15, collision=True).t is None


def test_the_mean_kpi_is_the_weighted_mean_of_the_variances_and_the_stacked_criterion(kr16, path):
    w = np.array([1.0, 2.0, 5.0])
    prob = make_problem("kr16", sigma_mm=1.0, q_work=path, kpi_weights=w)
    assert_allclose(prob.weights, w / w.sum(), rtol=1e-15)
    q = heuristic_design(prob, n=30, seed=1)
    v = prob.kpi_variances(q)
    singles = [make_problem("kr16", sigma_mm=1.0, q_work=qw).criteria(q)["kpi_avg_var_mm2"] for qw in path]
    assert_allclose(v, singles, rtol=1e-12)
    assert_allclose(prob.criteria(q)["kpi_avg_var_mm2"], v @ prob.weights, rtol=1e-12)
    assert_allclose(DesignObjective(prob, "kpi").value(q), v @ prob.weights, rtol=1e-12)
    worst = make_problem("kr16", sigma_mm=1.0, q_work=path, kpi_aggregate="max")
    assert worst.criteria(q)["kpi_avg_var_mm2"] == pytest.approx(v.max(), rel=1e-12)
    assert DesignObjective(worst, "kpi").value(q) == pytest.approx(v.max(), rel=1e-12)


def test_several_working_poses_with_a_model_extension(path):
    ext = make_problem("kr16", sigma_mm=1.0, q_work=path, extend=["joint_elasticity:2"])
    assert ext.Js().shape == (9, 28) and ext.Js_each().shape == (3, 3, 28)
    q = heuristic_design(ext, n=30, seed=2)
    singles = [
        make_problem("kr16", sigma_mm=1.0, q_work=qw, extend=["joint_elasticity:2"]).criteria(q)
        for qw in path
    ]
    assert_allclose(ext.kpi_variances(q), [c["kpi_avg_var_mm2"] for c in singles], rtol=1e-12)
    # the extension parameter's scale: its TCP column's root mean square over the working poses
    cols = ext.Js_each()[:, :, 27]
    assert_allclose(ext.scale[27], np.sqrt(np.mean(np.sum(cols**2, axis=1))), rtol=1e-12)


def test_each_variance_and_its_gradient_match_central_differences(kr16, path):
    prob = make_problem("kr16", sigma_mm=1.0, q_work=path, kpi_aggregate="max")
    q = heuristic_design(prob, n=12, seed=4)
    obj = DesignObjective(prob, "kpi")
    v, g = obj.values_and_grads(q)
    fd = central_fd(lambda x: obj.values_and_grads(x)[0], q, 1e-6)
    assert g.shape == (3, 12, 6)
    assert_allclose(g, fd, rtol=1e-5, atol=1e-6 * np.abs(g).max())
    # kpi_each agrees with the kpi criterion of each single Jacobian
    F1 = prob.F1(q)
    vals, dF = criteria.kpi_each(F1, prob.Js_each())
    for k, J in enumerate(prob.Js_each()):
        vk, gk = criteria.resolve("kpi").evaluate(F1, J, prob.scale)
        assert_allclose([vals[k]], [vk], rtol=1e-12)
        assert_allclose(dF[k], gk, rtol=1e-10, atol=1e-14 * np.abs(gk).max())


def test_worst_case_of_two_equal_working_poses_reaches_the_single_kpi_optimum(kr16):
    """The epigraph form (t >= v_k) with K = 2 equal working poses is the single-KPI problem."""
    twice = make_problem("kr16", sigma_mm=1.0, q_work=np.stack([kr16.q_work] * 2), kpi_aggregate="max")
    dp = DesignProgram(twice, criterion="kpi", n=20, collision=True)
    assert dp.t is not None and dp.epigraph_binding.evaluator().num_outputs() == 2
    single = optimize_design(kr16, n=20, seed=0, start="heuristic")  # the worst case's default start
    worst = optimize_design(twice, n=20, seed=0)
    assert worst.start == "heuristic" and worst.success and worst.feasible
    assert_allclose(worst.kpi_vars_mm2, [worst.kpi_avg_var_mm2] * 2, rtol=1e-12)
    assert_allclose(worst.kpi_avg_var_mm2, single.kpi_avg_var_mm2, rtol=1e-4)


@pytest.mark.slow
def test_worst_case_design_of_a_path_balances_its_variances(kr16, path):
    mean_p = make_problem("kr16", sigma_mm=1.0, q_work=path)
    worst_p = make_problem("kr16", sigma_mm=1.0, q_work=path, kpi_aggregate="max")
    single = optimize_design(kr16, n=20, seed=0)
    worst = optimize_design(worst_p, n=20, seed=0)
    assert worst.success and worst.feasible
    v = worst_p.kpi_variances(worst.q)
    assert_allclose(worst.value, v.max(), rtol=1e-12)
    assert_allclose(worst.kpi_vars_mm2, v, rtol=1e-12)
    # the epigraph is active at more than one working pose (the worst case is balanced) ...
    assert np.sum(v > v.max() * (1 - 1e-4)) >= 2
    # ... and lower than the worst working pose of the single-KPI design
    assert v.max() < mean_p.kpi_variances(single.q).max()


def test_bad_working_poses_and_weights_are_input_errors(kr16, path):
    with pytest.raises(InputError, match="^kpi_weights"):
        make_problem("kr16", q_work=path, kpi_weights=[1, 2])
    with pytest.raises(InputError, match="^kpi_weights"):
        make_problem("kr16", q_work=path, kpi_weights=[1, -1, 1])
    with pytest.raises(InputError, match="no weights"):
        make_problem("kr16", q_work=path, kpi_weights=[1, 2, 3], kpi_aggregate="max")
    with pytest.raises(InputError, match="^kpi_aggregate"):
        make_problem("kr16", q_work=path, kpi_aggregate="median")
    with pytest.raises(InputError, match="q_work"):
        make_problem("kr16", q_work=np.zeros((2, 5)))


# ----------------------------------------------------------------------------------------------
# Sequential design: poses already measured held fixed
# ----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_given_poses_equal_the_design_with_their_information_fixed(kr16):
    given = heuristic_design(kr16, n=30, seed=0)
    res = optimize_design(kr16, n=10, seed=1, given=given, start="heuristic")
    assert res.success and res.feasible and res.q.shape == (10, 6)
    F = kr16.F1(given)
    M0 = F.T @ F
    # the same solve as the program with the given information fixed, from the same start
    setup = design_solve.SolveSetup(
        problem=kr16, criterion="kpi", collision=True, solver="snopt", pose_block=10, active_rows=4
    )
    direct, _ = design_solve.solve_checked(setup, heuristic_design(kr16, n=10, seed=1), fixed_information=M0)
    assert np.array_equal(direct.q, res.q) and direct.value == res.value
    # its value and gradient are those of the combined design (given rows appended)
    both = np.vstack([given, res.q])
    v, g = DesignObjective(kr16, "kpi").value_and_grad(both)
    vf, gf = DesignObjective(kr16, "kpi", fixed_information=M0).value_and_grad(res.q)
    assert_allclose(vf, v, rtol=1e-12)
    assert_allclose(gf, g[30:], rtol=1e-9, atol=1e-12 * np.abs(g).max())
    assert_allclose(res.kpi_avg_var_mm2, kr16.criteria(both)["kpi_avg_var_mm2"], rtol=1e-12)
    # the given poses are reported alone and not moved; the new poses help
    assert res.given["n_given"] == 30
    assert_allclose(np.deg2rad(res.given["given_q_deg"]), given, rtol=1e-14)
    alone = kr16.criteria(given)["kpi_avg_var_mm2"]
    assert_allclose(res.given["given_kpi_avg_var_mm2"], alone, rtol=1e-12)
    assert res.kpi_avg_var_mm2 < alone
    # fewer new poses than the minimum are fine with enough given poses
    assert optimize_design(kr16, n=1, seed=1, given=given).q.shape == (1, 6)
    with pytest.raises(InputError, match="at least 6 poses with the 3 given"):
        optimize_design(kr16, n=5, given=given[:3])


@pytest.mark.slow
def test_given_poses_with_block_sweeps_keep_their_information_fixed(kr16):
    given = heuristic_design(kr16, n=20, seed=5)
    res = optimize_design(kr16, n=16, seed=2, given=given, max_block=8, sweep_block=8)
    assert res.sweeps >= 1 and res.feasible
    assert_allclose(res.value, kr16.criteria(np.vstack([given, res.q]))["kpi_avg_var_mm2"], rtol=1e-12)
    assert res.value <= res.initial_values[0]


# ----------------------------------------------------------------------------------------------
# Fewest poses for a target variance
# ----------------------------------------------------------------------------------------------
def test_remove_poses_drops_the_pose_that_raises_the_kpi_least(kr16):
    q = heuristic_design(kr16, n=14, seed=3)
    kept = remove_poses(kr16, q, 13)
    each = [kr16.criteria(np.delete(q, i, axis=0))["kpi_avg_var_mm2"] for i in range(14)]
    assert np.array_equal(kept, np.delete(q, int(np.argmin(each)), axis=0))
    assert remove_poses(kr16, q, 10).shape == (10, 6)


def _target_search_returns(kr16, V, criterion):
    """The design of ``design_for_target(kr16, V)`` and how often control came back to
    design/target.py after leaving it (followed with sys.setprofile, numpy and stdlib frames
    belonging to the package frame under them)."""
    out = {}
    seq = rt.stays(
        lambda: out.setdefault(
            "res", design_for_target(kr16, V, criterion=criterion, collision=True, bound=False)
        )
    )
    assert seq[0] == design_target.__name__, seq[:3]
    return out["res"], seq.count(design_target.__name__) - 1


def test_target_search_leaves_its_module_once_per_design_tried(kr16):
    """One call per step of the search (its start and its solve) and one to check the request: the
    search comes back to design/target.py once per design tried, plus once."""
    res, returns = _target_search_returns(kr16, 1.3, "heuristic")
    assert returns == len(res.target["trail"]) + 1 == 7


@pytest.mark.slow
def test_target_search_of_about_20_optimised_poses_comes_back_at_most_8_times(kr16):
    res, returns = _target_search_returns(kr16, 0.2, "kpi")
    assert res.target["n_poses"] == 19 and returns == len(res.target["trail"]) + 1 <= 8


@pytest.mark.slow
def test_target_var_returns_the_smallest_n_that_reaches_it(kr16):
    V = 0.1
    res = design_for_target(kr16, V, bound=False)
    t = res.target
    n = t["n_poses"]
    assert res.n == n and res.success and res.feasible
    assert kr16.criteria(res.q)["kpi_avg_var_mm2"] <= V and t["kpi_avg_var_mm2"] <= V
    tried = {d["n_poses"]: d for d in t["trail"]}
    assert n > kr16.min_poses() and tried[n]["reached"]
    # N - 1 was solved in the same search and did not reach V; nothing smaller did
    assert not tried[n - 1]["reached"] and tried[n - 1]["kpi_avg_var_mm2"] > V
    assert all(d["n_poses"] >= n for d in t["trail"] if d["reached"])
    assert t["bound_mm2"] is None and "not computed" in t["bound_note"]


def test_target_var_of_the_heuristic_is_exact(kr16):
    """Heuristic designs are nested in N, so N - 1 poses computed on their own do not reach V."""
    V = 0.5
    res = design_for_target(kr16, V, criterion="heuristic", bound=False)
    n = res.target["n_poses"]
    assert res.kpi_avg_var_mm2 <= V
    assert optimize_design(kr16, criterion="heuristic", n=n - 1).kpi_avg_var_mm2 > V
    with pytest.raises(InputError, match="^target_var_mm2 must be a positive variance"):
        design_for_target(kr16, -1.0)


def test_target_var_with_given_poses_counts_the_new_ones(kr16):
    given = heuristic_design(kr16, n=30, seed=0)
    res = design_for_target(kr16, 0.3, given=given)
    n = res.target["n_poses"]
    tried = {d["n_poses"]: d for d in res.target["trail"]}
    assert res.q.shape == (n, 6) and res.kpi_avg_var_mm2 <= 0.3
    assert n == 1 or not tried[n - 1]["reached"]
    assert res.target["bound_mm2"] is None and "given poses" in res.target["bound_note"]
    with pytest.raises(InputError, match="already reach"):
        design_for_target(kr16, 10.0, given=given)


def test_target_var_reports_the_certificate_bound_or_why_it_is_missing(kr16, monkeypatch):
    """The bound of the design found, or why it is missing (the heuristic's search: the bound is
    reported the same way for every criterion)."""
    calls = []

    def fake_certify(problem, q, *, collision, seed):
        calls.append(len(q))
        return {"bound_mm2": 0.05, "efficiency": 0.5, "method": "fake"}

    monkeypatch.setattr(design_target, "certify", fake_certify)
    res = design_for_target(kr16, 0.5, criterion="heuristic")
    assert calls == [res.n] and res.target["bound_mm2"] == 0.05 and "fake" in res.target["bound_note"]

    def broken(*args, **kwargs):
        raise RuntimeError("no pool")

    monkeypatch.setattr(design_target, "certify", broken)
    res = design_for_target(kr16, 0.5, criterion="heuristic")
    assert res.target["bound_mm2"] is None and "no pool" in res.target["bound_note"]


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_cli_several_working_poses_from_a_file_and_repeated(
    tmp_path, capsys, kr16, path, quick_certificate, quick_start
):
    """The mean of 3 weighted working poses from a file, with its certificate (the smaller searches
    of the start and the certificate: the bound still rigorous), then the worst case of the same
    poses given as --q-work."""
    wp = tmp_path / "path.csv"
    write_design(wp, path, {"weight": np.array([1.0, 1.0, 2.0])})
    q_file, w_file = read_working_poses(wp, kr16.robot)
    assert_allclose(q_file, path, atol=1e-12) and list(w_file) == [1.0, 1.0, 2.0]
    out, js = tmp_path / "d.csv", tmp_path / "d.json"
    kr = "design --robot kr16 --criterion kpi --n 15 --sigma-mm 1"
    assert main(f"{kr} --q-work-file {wp} --out {out} --json {js}".split()) == 0
    rec = json.loads(js.read_text())
    assert rec["kpi_aggregate"] == "mean"
    assert_allclose(rec["kpi_weights"], [0.25, 0.25, 0.5], rtol=1e-12)
    assert np.shape(rec["q_work_deg"]) == (3, 6) and len(rec["values"]["kpi_vars_mm2"]) == 3
    assert_allclose(
        rec["values"]["kpi_avg_var_mm2"], np.dot(rec["values"]["kpi_vars_mm2"], rec["kpi_weights"]), rtol=1e-9
    )
    assert "KPI of 3 working poses" in capsys.readouterr().out
    # the certificate of the weighted mean: K stacks the 3 working poses (k, 9)
    assert 0.0 < rec["bound_mm2"] <= rec["values"]["kpi_avg_var_mm2"] and 0.0 < rec["efficiency"] <= 1.0
    deg = np.rad2deg(path)
    args = [f"--q-work={','.join(map(str, row))}" for row in deg]
    js2 = tmp_path / "m.json"
    base = f"{kr} --kpi-aggregate max --no-certify --out {out} --json {js2}"
    assert main(base.split() + args) == 0
    rec2 = json.loads(js2.read_text())
    assert rec2["kpi_aggregate"] == "max"
    assert_allclose(rec2["values"]["kpi_avg_var_mm2"], max(rec2["values"]["kpi_vars_mm2"]), rtol=1e-12)
    assert rec2["start"] == "heuristic" and rec2["efficiency"] is None
    assert main(base.split() + args + ["--kpi-weights", "1,2,3"]) == 2


@pytest.mark.slow
def test_cli_given_and_target_var(tmp_path, capsys, kr16):
    given = tmp_path / "given.csv"
    write_design(given, heuristic_design(kr16, n=30, seed=0))
    out, js = tmp_path / "next.csv", tmp_path / "next.json"
    cmd = f"design --robot kr16 --criterion kpi --n 10 --sigma-mm 1 --given {given} --out {out} --json {js}"
    assert main(cmd.split()) == 0
    assert read_design(out, kr16.robot).shape == (10, 6)
    rec = json.loads(js.read_text())
    assert rec["given"]["n_given"] == 30 and rec["n_poses"] == 10
    assert rec["values"]["kpi_avg_var_mm2"] < rec["given"]["given_kpi_avg_var_mm2"]
    assert "given poses alone" in capsys.readouterr().out
    js2 = tmp_path / "t.json"
    cmd = f"design --robot kr16 --criterion kpi --sigma-mm 1 --target-var 0.3 --given {given}"
    cmd += f" --out {out} --json {js2}"
    assert main(cmd.split()) == 0
    rec2 = json.loads(js2.read_text())
    assert rec2["target"]["n_poses"] == rec2["n_poses"] and rec2["values"]["kpi_avg_var_mm2"] <= 0.3
    assert "target tr(Cs)/3 <= 0.3" in capsys.readouterr().out
