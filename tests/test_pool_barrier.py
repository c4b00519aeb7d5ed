"""The pool's cone program by the structured barrier method, checked against Clarabel (an independent
solver of the same program) and against the optimality conditions of the equivalence theorem."""

from __future__ import annotations

import numpy as np
import pytest

from kpioed_drake.design.approximate import barrier, certcache, pool
from kpioed_drake.design.approximate.design import kpi_factor
from kpioed_drake.design.approximate.search import dual_values, pose_rows
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.estimation.problem import make_problem


@pytest.fixture(scope="module", params=["kr16", "models/robots/humanoid18.urdf"], ids=["kr16", "twin"])
def rows(request):
    """(F, K) of 300 random feasible poses (seeded) of kr16 and of the 18-joint twin (two targets)."""
    problem = certcache.unit_noise(make_problem(request.param))
    q = heuristic_design(problem, n=300, seed=7, margin_mm=0.0, max_draws=10**7)
    return pose_rows(problem, q), kpi_factor(problem)


@pytest.mark.parametrize("m", [40, 300])
def test_barrier_meets_clarabel_on_the_same_pool(rows, m):
    F, K = rows[0][:m], rows[1]
    ours = pool.solve_pool(F, K)
    ref = pool._clarabel(F, K, tol=pool.CONE_TOL)
    assert ours.dual <= ours.phi * (1.0 + 1e-12)  # the bound below the design it bounds
    assert 1.0 - ours.dual / ours.phi < 1e-9  # measured 1e-13 to 3e-11
    assert ours.phi == pytest.approx(ref.phi, rel=1e-9)
    assert ours.dual == pytest.approx(ref.dual, rel=1e-9)
    np.testing.assert_allclose(ours.w, ref.w, atol=1e-6)
    assert ours.w.sum() == pytest.approx(1.0, abs=1e-12) and np.all(ours.w >= 0.0)


def test_weights_meet_the_equivalence_theorem(rows):
    """At the optimum ``max_i d(x_i, w) = Phi(w)`` over the pool, with equality on the support."""
    F, K = rows
    sol = pool.solve_pool(F, K)
    phi, X = pool.l_criterion(F, sol.w, K)
    d = dual_values(F, X)
    assert d.max() == pytest.approx(phi, rel=1e-7)
    np.testing.assert_allclose(d[sol.w > 1e-4], phi, rtol=1e-7)


def test_polish_lowers_the_criterion_of_the_barrier_multipliers(rows):
    F, K = rows
    bar = barrier._Barrier(F, K)
    w0 = np.full(len(F), 1.0 / len(F))
    w = barrier.polish_weights(F, K, w0)
    assert pool.l_criterion(F, w, K)[0] <= pool.l_criterion(F, w0, K)[0]
    assert w.sum() == pytest.approx(1.0, abs=1e-12) and np.all(w >= 0.0)
    assert bar.m == len(F)


def test_a_failing_barrier_falls_back_to_clarabel(rows, monkeypatch):
    F, K = rows[0][:40], rows[1]

    def fail(*args, **kwargs):
        raise FloatingPointError("no path")

    monkeypatch.setattr(pool, "barrier_dual", fail)
    ours, ref = pool.solve_pool(F, K), pool._clarabel(F, K, tol=pool.CONE_TOL)
    assert ours.phi == ref.phi and np.array_equal(ours.w, ref.w)


def test_a_kpi_the_pool_does_not_see_has_no_barrier_path(rows):
    F, K = rows
    with pytest.raises(FloatingPointError):
        barrier.barrier_dual(F, np.zeros_like(K), rtol=1e-11)
