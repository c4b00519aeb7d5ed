"""Independent tasks on both cores: worker processes forked from this one.

The package's hot loops are numpy on small arrays and SNOPT, single-threaded by design (one BLAS
thread, ``kpioed_drake/__init__.py``); where a job splits into independent pieces of equal kind (the
certificate search's SNOPT batches, a diagnosis step's candidate refits) the pieces run in
processes. Where a loop over the pieces may stop early (the first piece that settles a question),
:func:`ordered` hands the results over one at a time while the workers run ahead, and ends them
when the loop stops. Forked, not spawned: a worker inherits the loaded modules and the task's data (robot,
problem, arrays) without pickling them, and starts in milliseconds. Results come back in order,
so a run gives the same numbers with any number of workers.

``KPIOED_WORKERS`` sets the number of workers (1: none, the loop in this process); by default the
cores this process may run on, at most :data:`MAX_WORKERS`. Where ``fork`` is missing (Windows,
macOS's default ``spawn`` is not used) or inside a worker, the loop runs here. Workers ignore
SIGINT: Ctrl-C reaches the parent, which ends the command (``errors``); the workers end with it.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")

WORKERS_ENV = "KPIOED_WORKERS"
"""Environment variable: the worker processes of :func:`independent` (1: none)."""
MAX_WORKERS = 4
"""Most workers by default (the pieces of a step are few; more processes only add forks)."""

_TASKS: list[Callable[[Any], object]] = []  # the running call's task, inherited by its forked workers


def workers() -> int:
    """The worker processes :func:`independent` may use (module docstring)."""
    if "fork" not in mp.get_all_start_methods() or mp.current_process().daemon:
        return 1
    given = os.environ.get(WORKERS_ENV, "").strip()
    if given:
        try:
            return max(1, int(given))
        except ValueError:
            return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


def _quiet_worker() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run(arg: Any) -> object:
    return _TASKS[-1](arg)


@contextlib.contextmanager
def _forked(task: Callable[[Any], object], k: int) -> Iterator[Any]:
    """Within the block, ``k`` worker processes forked now that run ``task`` (by :func:`_run`), ended
    on leaving it; None for ``k`` <= 1 (the caller's loop runs here)."""
    if k <= 1:
        yield None
        return
    _TASKS.append(task)
    try:
        with mp.get_context("fork").Pool(k, initializer=_quiet_worker) as forked:
            yield forked
    finally:
        _TASKS.pop()


def independent(task: Callable[[int], T], n: int, *, parallel: bool = True) -> list[T]:
    """``[task(0), ..., task(n - 1)]``; with ``parallel`` and two tasks or more, in worker processes
    forked from this one (at most :func:`workers`, at most ``n``), each task whole in one worker, in
    order.

    ``task`` must be a function of the index alone whose result pickles (arrays, numbers); it sees
    this process's state as it was at the fork, and what it changes there stays in the worker.
    """
    with pool(task, parallel=parallel, most=n) as run:
        return run(range(n))


@contextlib.contextmanager
def pool(
    task: Callable[[Any], T], *, parallel: bool = True, most: int | None = None
) -> Iterator[Callable[[Sequence[Any]], list[T]]]:
    """Within the block, a function ``map(args) -> [task(a) for a in args]`` whose calls run in worker
    processes forked once, at entry (at most :func:`workers` and ``most``; none without ``parallel``
    or with one at most: the loop here).

    For a loop of many small rounds (batches of random poses checked for feasibility): the workers
    inherit ``task``'s data at the fork, and each round sends only its arguments (pickled).
    """
    k = min(workers(), most if most is not None else workers()) if parallel else 1
    with _forked(task, k) as forked:
        if forked is None:
            yield lambda args: [task(a) for a in args]
        else:
            yield lambda args: forked.map(_run, args, chunksize=1)


@contextlib.contextmanager
def ordered(task: Callable[[int], T], n: int, *, parallel: bool = True) -> Iterator[Iterator[T]]:
    """Within the block, an iterator over ``task(0), ..., task(n - 1)`` in order, each computed when
    the loop asks for it (in this process), or ahead of it in worker processes forked at entry (with
    ``parallel`` and two tasks or more; at most :func:`workers` and ``n``), which take the next
    task as they finish one. Leaving the block ends the workers, so a loop that stops at the first
    result that settles its question pays for that result and for those the workers had started.

    ``task`` as :func:`independent`'s; the results are those of the loop here with any number of
    workers.
    """
    k = min(workers(), n) if parallel else 1
    with _forked(task, k) as forked:
        yield (task(i) for i in range(n)) if forked is None else forked.imap(_run, range(n), chunksize=1)
