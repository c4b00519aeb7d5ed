"""Running many study tasks: on local processes, inline or on a Dask cluster, resumable.

Each finished task is written at once and atomically to ``DIR/tasks/<task_id>.json`` and its design to
``DIR/designs/<design_name>``; a study started again skips the tasks whose result file exists (a task
that recorded an error is run again), so a killed study resumes and gives the same tables. The workers
only compute; this process writes every file, so Dask workers need no shared disk.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import as_completed as pool_completed
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm.auto import tqdm

from kpioed_drake import parallel
from kpioed_drake.errors import InputError
from kpioed_drake.files.designs import write_design
from kpioed_drake.outputs import atomic_write_json
from kpioed_drake.study.tasks import BoundTask, Task, run_task

if TYPE_CHECKING:  # an optional dependency (extra "dask")
    from distributed import Client

OnDone = Callable[[Task, dict], None]

SCHEDULER_TIMEOUT_S = 10.0
"""How long to wait for a Dask scheduler to answer before giving up [s]."""


def _task_path(out_dir: Path, task: Task | BoundTask) -> Path:
    return out_dir / "tasks" / f"{task.task_id}.json"


def _load_done(out_dir: Path, task: Task) -> dict | None:
    """The stored row of a task finished without error, else None (missing, unreadable, another task's
    or failed: the task is run again and its file replaced)."""
    p = _task_path(out_dir, task)
    if not p.is_file():
        return None
    try:
        row = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # unreadable, not UTF-8, not JSON: run the task again
        return None
    if not isinstance(row, dict) or row.get("task_id") != task.task_id or row.get("error"):
        return None
    return row


def _save(out_dir: Path, task: Task, row: dict) -> None:
    """Write the design (if any) and then the row, each atomically."""
    if not row.get("error") and task.design_name is not None:
        write_design(out_dir / "designs" / task.design_name, np.deg2rad(np.asarray(row["q_deg"])))
    atomic_write_json(_task_path(out_dir, task), row)


def _execute_dask(todo: list[Task], scheduler, design_api, on_done: OnDone) -> None:
    # optional dependency (extra "dask"), imported only when a scheduler is given
    from distributed import Client, as_completed

    if isinstance(scheduler, Client):
        client = scheduler
    else:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(
                f"scheduler {scheduler}: no `dask scheduler` answered within {SCHEDULER_TIMEOUT_S:g} s "
                f"({type(exc).__name__}: {exc}); start one or leave scheduler out",
                fields=("scheduler",),
            ) from None
    try:
        futs = {
            client.submit(run_task, t, design_api, pure=False, key=f"kpioed-{t.task_id}"): t for t in todo
        }
        for fut in as_completed(futs):
            on_done(futs[fut], fut.result())
    finally:
        if client is not scheduler:
            client.close()


def _one_process_per_task() -> None:
    """In a study's worker process: no forked workers of its own (:mod:`kpioed_drake.parallel`); the
    study's workers fill the cores already."""
    os.environ[parallel.WORKERS_ENV] = "1"


def _execute_pool(todo: list[Task], jobs: int, design_api, on_done: OnDone) -> None:
    # one BLAS/OpenMP thread per worker process: the matrices are small and the workers fill the CPUs
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    spawn = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=spawn, initializer=_one_process_per_task) as ex:
        futs = {ex.submit(run_task, t, design_api): t for t in todo}
        try:
            for fut in pool_completed(futs):
                on_done(futs[fut], fut.result())
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def _execute(todo: list[Task], *, jobs: int, scheduler, design_api, on_done: OnDone) -> None:
    """Run the tasks on Dask (``scheduler``), inline (``jobs`` 1) or on ``jobs`` processes."""
    if not todo:
        return
    if scheduler is not None:
        _execute_dask(todo, scheduler, design_api, on_done)
    elif jobs <= 1:
        for t in todo:
            on_done(t, run_task(t, design_api))
    else:
        _execute_pool(todo, jobs, design_api, on_done)


def run_tasks(
    tasks: list[Task],
    out_dir: str | Path,
    *,
    jobs: int | None = None,
    scheduler: str | Client | None = None,
    progress: bool = True,
    design_api: str | object | None = None,
) -> tuple[list[dict], int, int]:
    """Run the tasks whose result file is missing (or recorded an error).

    Args:
        tasks: the study's tasks.
        out_dir: study folder (``tasks/`` and ``designs/`` are written inside).
        jobs: local worker processes (default: the number of CPUs); 1 runs inline.
        scheduler: Dask scheduler address or ``distributed.Client``: the tasks go there instead.
        progress: show a progress bar.
        design_api: stand-in for :mod:`kpioed_drake.design` (see :func:`run_task`).

    Returns:
        all rows in task order, the number of tasks run and the number skipped (already done).
    """
    out_dir = Path(out_dir)
    rows: dict[str, dict] = {}
    todo = []
    for t in tasks:
        done = _load_done(out_dir, t)
        if done is None:
            todo.append(t)
        else:
            rows[t.task_id] = done
    # the optimisations first: they are the long tasks
    todo.sort(key=lambda t: t.method == "heuristic")
    bar = None
    if progress and todo:
        bar = tqdm(total=len(todo), desc="study tasks", unit="task", smoothing=0.05)

    def on_done(task: Task, row: dict) -> None:
        _save(out_dir, task, row)
        rows[task.task_id] = row
        if bar is not None:
            bar.update(1)
            if row.get("error"):
                bar.write(f"{task.task_id}: {row['error']}")

    try:
        _execute(
            todo,
            jobs=jobs or os.cpu_count() or 1,
            scheduler=scheduler,
            design_api=design_api,
            on_done=on_done,
        )
    finally:
        if bar is not None:
            bar.close()
    return [rows[t.task_id] for t in tasks], len(todo), len(tasks) - len(todo)
