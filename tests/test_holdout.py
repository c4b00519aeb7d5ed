"""The cheap parts of the diagnosis's fits (issue 12, item 9) give the numbers of the expensive ones.

- ``FitProblem.holdout``: each fold's refit is one Gauss-Newton step from the fit on all poses;
  compared here with full Levenberg-Marquardt refits of every fold.
- ``estimate`` stops when the Gauss-Newton step predicts a cost decrease below ``tol``; compared
  with the same fit run to a tolerance a thousand times tighter.
- ``fit.independent``: a step's independent fits in forked worker processes (issue 46); the
  diagnosis with them gives the report of the loop in one process, number for number.
- ``FitProblem.holdout`` takes the fit's own Jacobian at its solution (the estimator's last) instead
  of evaluating it again: the same held-out residuals, bit for bit.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from kpioed_drake import diagnosis as D
from kpioed_drake import parallel
from kpioed_drake.diagnosis import fit as ft
from kpioed_drake.diagnosis.fit import FitProblem
from kpioed_drake.effects import parse_effect
from kpioed_drake.estimation import estimator
from kpioed_drake.robot import models
from kpioed_drake.study.synthetic import synthetic_case

SIGMA = 0.02


@pytest.fixture(scope="module")
def problem():
    robot = models.load_robot("kr16")
    case = synthetic_case(robot, np.random.default_rng(7), ["joint_elasticity:2"], n_poses=120, sigma=SIGMA)
    return FitProblem(robot, case.data, SIGMA)


def refit_holdout(prob: FitProblem, full, k: int = 5) -> np.ndarray:
    """Held-out residuals with every fold refitted to convergence (the expensive reference)."""
    n = prob.data.n
    out = np.empty((n, 3))
    for test in prob.folds(k):
        train = np.setdiff1d(np.arange(n), test)
        out[test] = prob.fit(full.effects, start=full, idx=train).residuals[test]
    return out


@pytest.mark.parametrize("effects", [[], ["joint_elasticity:2"], ["joint_elasticity:2", "gear_cyclic:3:1"]])
def test_one_step_holdout_equals_refits(problem, effects):
    base = problem.fit([])
    full = problem.fit([parse_effect(e) for e in effects], start=base) if effects else base
    cheap, exact = problem.holdout(full), refit_holdout(problem, full)
    assert np.max(np.abs(cheap - exact)) < 1e-3 * SIGMA
    rms = lambda r: np.sqrt(np.mean(r**2))  # noqa: E731
    assert abs(rms(cheap) - rms(exact)) < 1e-5 * rms(exact)
    assert rms(cheap) > rms(full.residuals)  # held out is worse than fitted: it is not the fit itself


@pytest.mark.parametrize("idx", [None, np.arange(100)])
def test_holdout_with_the_fits_own_jacobian_is_the_same(problem, idx):
    """The weighted residuals and Jacobian the holdout steps from: the fit's own (its rows, weights
    and sigma) equal those evaluated again at its solution, and so do the held-out residuals."""
    full = problem.fit([parse_effect("joint_elasticity:2"), parse_effect("gear_cyclic:3:1")], idx=idx)
    again = dataclasses.replace(full, q=full.q.copy())  # not the problem's poses: evaluated again
    r_own, J_own = problem._weighted_solution(full)
    r_new, J_new = problem._weighted_solution(again)
    assert J_own.shape == (full.n_used, 3, full.J.shape[1])
    np.testing.assert_array_equal(J_own, J_new)
    np.testing.assert_allclose(r_own, r_new, rtol=0, atol=1e-12)
    np.testing.assert_allclose(problem.holdout(full), problem.holdout(again), rtol=0, atol=1e-12)


def test_predicted_decrease_stop_is_converged(problem):
    data = problem.data
    model = problem.nominal
    fast = estimator.estimate(model, data.q, data.eta, sigma=SIGMA)
    tight = estimator.estimate(model, data.q, data.eta, sigma=SIGMA, tol=1e-13)
    assert fast.converged and fast.iterations < 10
    assert abs(fast.cost - tight.cost) <= 1e-9 * tight.cost
    dz = (fast.model.p[fast.free] - tight.model.p[tight.free]) / tight.std
    assert np.max(np.abs(dz)) < 1e-3  # parameter differences far below their standard deviations


def test_independent_keeps_the_order_and_the_loop(monkeypatch):
    monkeypatch.setenv(parallel.WORKERS_ENV, "2")
    square = lambda i: (i * i, parallel.mp.current_process().daemon)  # noqa: E731
    forked = ft.independent(square, 5, size=ft.PARALLEL_MIN_ENTRIES)
    assert [v for v, _ in forked] == [0, 1, 4, 9, 16] and all(d for _, d in forked)  # in workers
    assert ft.independent(square, 5, size=ft.PARALLEL_MIN_ENTRIES - 1) == [(i * i, False) for i in range(5)]
    monkeypatch.setenv(parallel.WORKERS_ENV, "1")
    assert ft.independent(square, 5, size=ft.PARALLEL_MIN_ENTRIES) == [(i * i, False) for i in range(5)]


def test_diagnosis_with_workers_equals_the_loop(monkeypatch):
    """Every step's refits, the causes' alternatives and the unexplained rest's candidates in two
    workers: the same report (named causes, statistics, alternatives, notes) as in one process."""
    robot = models.load_robot("kr16")
    rng = np.random.default_rng(21)
    case = synthetic_case(robot, rng, ["joint_elasticity:2=4e-7", "gear_cyclic:4:2=0.012,-0.008"], n_poses=70)
    opts = D.DiagnosisOptions(sigma_mm=SIGMA)
    monkeypatch.setenv(parallel.WORKERS_ENV, "1")
    loop = D.diagnose(robot, case.data, opts)
    monkeypatch.setenv(parallel.WORKERS_ENV, "2")
    monkeypatch.setattr(ft, "PARALLEL_MIN_ENTRIES", 0)
    calls = []
    real = parallel.mp.get_context
    monkeypatch.setattr(parallel.mp, "get_context", lambda m: calls.append(m) or real(m))
    forked = D.diagnose(robot, case.data, opts)
    assert calls and set(calls) == {"fork"}  # the workers did run
    assert loop.cause_names == forked.cause_names and loop.cause_names
    assert json.dumps(forked.to_json(), sort_keys=True) == json.dumps(loop.to_json(), sort_keys=True)
