"""Independent tasks in forked workers: the same results, in order, with any number of workers."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from kpioed_drake import parallel
from kpioed_drake.design.approximate import search
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.estimation.problem import make_problem


def test_results_in_order(monkeypatch):
    monkeypatch.setenv(parallel.WORKERS_ENV, "2")
    data = np.arange(10.0)
    assert parallel.independent(lambda i: float(data[i] ** 2), 10) == [float(i * i) for i in range(10)]


def test_one_worker_runs_here(monkeypatch):
    monkeypatch.setenv(parallel.WORKERS_ENV, "1")
    seen = []
    parallel.independent(seen.append, 3)  # in this process: the list is changed here
    assert seen == [0, 1, 2]


@pytest.mark.parametrize("value", ["0", "-3", "many"])
def test_bad_worker_counts_mean_one(monkeypatch, value):
    monkeypatch.setenv(parallel.WORKERS_ENV, value)
    assert parallel.workers() == 1


@pytest.mark.parametrize("robot", ["kr16", "models/robots/humanoid18.urdf"])
def test_search_batches_same_with_two_workers(monkeypatch, robot):
    """The certificate search's local maxima: bitwise the same poses in worker processes as here
    (8 starts per solve on six joints, 2 on the 18-joint twin)."""
    problem = make_problem(robot)
    q0 = heuristic_design(problem, n=2 * search.search_batch(problem.robot.n_joints) + 3, seed=4)
    Y = np.random.default_rng(4).normal(size=(problem.n_params, 3))
    out = {}
    for k in ("1", "2"):
        monkeypatch.setenv(parallel.WORKERS_ENV, k)
        out[k] = search.maximize_dual(problem, q0, Y, collision=False)
    for a, b in zip(out["1"], out["2"], strict=True):
        assert_array_equal(a, b)


def test_heuristic_pool_same_with_two_workers(monkeypatch):
    """A pool of random feasible poses: bitwise the same with workers checking batches side by side."""
    problem = make_problem("kr16")
    out = {}
    for k in ("1", "2"):
        monkeypatch.setenv(parallel.WORKERS_ENV, k)
        out[k] = heuristic_design(problem, n=1200, seed=3, batch=256)
    assert_array_equal(out["1"], out["2"])


def test_pool_maps_in_order(monkeypatch):
    monkeypatch.setenv(parallel.WORKERS_ENV, "2")
    base = np.arange(6.0)
    with parallel.pool(lambda x: float(base[x] + 1.0)) as run:
        assert run([5, 0, 3]) == [6.0, 1.0, 4.0]
        assert run([1]) == [2.0]


def test_ordered_runs_ahead_in_order_and_stops(monkeypatch):
    """``parallel.ordered``: the results in order from two workers; a loop that stops early ends them."""
    monkeypatch.setenv(parallel.WORKERS_ENV, "2")
    data = np.arange(8.0)
    with parallel.ordered(
        lambda i: (float(data[i] ** 2), parallel.mp.current_process().daemon), 8
    ) as results:
        got = [next(results) for _ in range(3)]  # the rest is never asked for
    assert [v for v, _ in got] == [0.0, 1.0, 4.0] and all(daemon for _, daemon in got)
    with parallel.ordered(lambda i: float(data[i]), 8) as results:
        assert list(results) == list(data)


def test_ordered_in_one_process_runs_only_what_the_loop_asks(monkeypatch):
    monkeypatch.setenv(parallel.WORKERS_ENV, "1")
    seen = []
    with parallel.ordered(lambda i: seen.append(i) or i, 5) as results:
        for i in results:
            if i == 2:
                break
    assert seen == [0, 1, 2]
