"""Faults: corrupted study task files, studies in which every task fails, and Ctrl-C (issue 15)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from test_study import FAKE

from kpioed_drake import study
from kpioed_drake.cli import main
from kpioed_drake.errors import EXIT_INTERRUPTED, EXIT_SOLVER, SolverError

ROBOTS = ["kr16"]
KW = dict(robots=ROBOTS, n=30, heuristic_draws=2, progress=False, design_api=FAKE, figures=False, jobs=1)


@pytest.fixture(scope="module")
def full_study(tmp_path_factory):
    d = tmp_path_factory.mktemp("full")
    return d, study.run_study(d, **KW)


@pytest.mark.parametrize("content", [b"[]", b"{}", b"null", b"\xff\xfe{\x00", b'{"task_id": "other"}', b"{"])
def test_corrupted_task_file_is_redone(tmp_path, full_study, content):
    full_dir, full = full_study
    study.run_study(tmp_path, **KW)
    task = study.make_tasks(ROBOTS, n=30, heuristic_draws=2)[0]
    (tmp_path / "tasks" / f"{task.task_id}.json").write_bytes(content)
    resumed = study.run_study(tmp_path, **KW)
    assert resumed.n_run == 1 and resumed.n_skipped == full.n_tasks - 1
    row = json.loads((tmp_path / "tasks" / f"{task.task_id}.json").read_text())
    assert row["task_id"] == task.task_id and row["error"] is None
    for k in (6, 7, 8):
        pd.testing.assert_frame_equal(
            pd.read_csv(full_dir / f"table{k}.csv", index_col=0),
            pd.read_csv(tmp_path / f"table{k}.csv", index_col=0),
        )


class _Failing:
    @staticmethod
    def heuristic_design(problem, **kw):
        raise RuntimeError("no feasible pose")

    optimize_design = heuristic_design


def test_study_where_every_task_fails(tmp_path, capsys):
    n_tasks = len(study.make_tasks(ROBOTS, n=30, heuristic_draws=2))
    with pytest.raises(SolverError, match=f"all {n_tasks} study tasks failed"):
        study.run_study(tmp_path, **{**KW, "design_api": _Failing()})
    rows = [json.loads(p.read_text()) for p in (tmp_path / "tasks").glob("*.json")]
    assert len(rows) == n_tasks and all("no feasible pose" in r["error"] for r in rows)  # kept for a look


def test_cli_study_all_failing_exit_status(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("kpioed_drake.study.tasks._design_api", lambda api: _Failing())
    code = main(["study", "--robots", "kr16", "--n", "30", "--heuristic-draws", "1", "--jobs", "1",
                 "--no-progress", "--out", str(tmp_path / "st")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == EXIT_SOLVER and "study tasks failed" in err and "Traceback" not in err


def _interrupt(argv: list[str], wait_s: float, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.Popen(
        [sys.executable, "-m", "kpioed_drake.cli", *argv],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(wait_s)
    assert proc.poll() is None, "the command ended before the interrupt"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


IN_SNOPT = "test: the solver starts"
"""Printed to stderr by :data:`ANNOUNCE_SOLVE` when the design's first solve starts."""
ANNOUNCE_SOLVE = f"""
import sys
from kpioed_drake.cli import main
from kpioed_drake.design.exact import solve

make_solver = solve.make_solver


def announce(*args, **kwargs):
    print({IN_SNOPT!r}, file=sys.stderr, flush=True)
    return make_solver(*args, **kwargs)


solve.make_solver = announce
sys.exit(main(sys.argv[1:]))
"""
"""The command line, saying on stderr when the solver is about to start (nothing else changed)."""


def _interrupt_in_solver(argv: list[str], cwd: Path, *, after_s: float = 1.0) -> subprocess.CompletedProcess:
    """Ctrl-C ``after_s`` after the first solve started (whatever the machine's load before it)."""
    cmd = [sys.executable, "-c", ANNOUNCE_SOLVE, *argv]
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    while IN_SNOPT not in "".join(lines):
        line = proc.stderr.readline()
        assert line or proc.poll() is None, f"ended before the solver started: {''.join(lines)}"
        lines.append(line)
    time.sleep(after_s)
    assert proc.poll() is None, "the command ended before the interrupt"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "".join(lines) + err)


def test_ctrl_c_during_design(tmp_path):
    """SNOPT swallows the KeyboardInterrupt raised in our callback; the command still stops, 130
    (the interrupt comes 1 s into the first of 200 solves)."""
    out = tmp_path / "d.csv"
    argv = ["design", "--robot", "kr16", "--criterion", "kpi", "--start", "heuristic", "--starts", "200"]
    res = _interrupt_in_solver([*argv, "--no-certify", "--out", str(out)], tmp_path)
    assert res.returncode == EXIT_INTERRUPTED, res.stderr
    assert "interrupted" in res.stderr and "Traceback" not in res.stderr
    assert not out.exists()


@pytest.mark.slow
def test_ctrl_c_during_study_keeps_finished_tasks(tmp_path):
    """Ctrl-C stops the study with 130; finished tasks stay on disk and a new run resumes them."""
    out = tmp_path / "st"
    argv = "study --robots kr16,kr300,notional-850-800 --heuristic-draws 3 --jobs 1 --no-progress".split()
    argv += ["--out", str(out)]
    res = _interrupt(argv, 12.0, tmp_path)
    assert res.returncode == EXIT_INTERRUPTED, res.stderr
    assert "Traceback" not in res.stderr
    kept = sorted(p.name for p in (out / "tasks").glob("*.json"))
    rows = [json.loads((out / "tasks" / name).read_text()) for name in kept]
    assert kept and all(r["error"] is None for r in rows)  # an interrupted task is not recorded as failed
    assert not (out / "table6.csv").exists()
    cmd = [sys.executable, "-m", "kpioed_drake.cli", *argv]
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert f"{len(kept)} resumed" in again.stdout and "0 failed" in again.stdout


def test_failing_plots_leave_no_model_file(tmp_path, capsys, monkeypatch):
    """calibrate computes every output before writing any: a plotting failure writes nothing."""
    design = Path(__file__).resolve().parents[1] / "studies/results/designs/kr16_kpi_ca.csv"
    data = tmp_path / "data.csv"
    assert main(["simulate", "--robot", "kr16", "--design", str(design), "--out", str(data)]) == 0

    def broken(report, folder):
        raise RuntimeError("the plotting library broke")

    monkeypatch.setattr("kpioed_drake.calibration.workflow.plot_calibration", broken)
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["calibrate", "--robot", "kr16", str(data), "--out", str(tmp_path / "model.yaml"),
            "--json", str(tmp_path / "r.json"), "--plots", str(tmp_path / "plots")]  # fmt: skip
    assert main(argv) == 1
    assert "internal error: RuntimeError: the plotting library broke" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
