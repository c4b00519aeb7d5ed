"""Every command is a Python function: the ``kpioed`` subprocess gives what the direct API call gives.

As pydrake tests its scripts: each command runs once as a subprocess (``python -m
kpioed_drake.cli``) and once through :mod:`kpioed_drake.api` with the same arguments, and their
outputs (files or JSON on stdout) must be equal (timings aside).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from kpioed_drake import api
from kpioed_drake.outputs import json_text

REPO = Path(__file__).resolve().parents[1]
DESIGN = REPO / "studies" / "results" / "designs" / "kr16_kpi_ca.csv"
TIMINGS = {"solve_s", "wall_s", "time_s"}


def _cli(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    res = subprocess.run(
        [sys.executable, "-m", "kpioed_drake.cli", *map(str, argv)], cwd=cwd, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    return res


def _plain(data):
    """As JSON would carry it, timings removed."""
    data = json.loads(json_text(data)) if not isinstance(data, str) else json.loads(data)

    def drop(o):
        if isinstance(o, dict):
            return {k: drop(v) for k, v in o.items() if k not in TIMINGS}
        if isinstance(o, list):
            return [drop(v) for v in o]
        return o

    return drop(data)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("api")
    _cli("simulate", "--robot", "kr16", "--design", DESIGN, "--seed", 4, "--out", d / "data.csv", cwd=d)
    _cli("simulate", "--robot", "kr16", "--design", DESIGN, "--seed", 5, "--effect", "joint_elasticity:3",
         "--out", d / "data_el.csv", cwd=d)  # fmt: skip
    return d


def test_info(work):
    out = _cli("info", "--robot", "kr16", "--json", cwd=work).stdout
    assert _plain(out) == _plain(api.info("kr16"))


@pytest.mark.slow
def test_evaluate(work):
    _cli(
        "evaluate",
        "--robot",
        "kr16",
        "--design",
        DESIGN,
        "--sigma-mm",
        0.5,
        "--json",
        work / "e.json",
        cwd=work,
    )
    direct = api.evaluate("kr16", DESIGN, sigma_mm=0.5)
    assert _plain((work / "e.json").read_text()) == _plain(direct)


@pytest.mark.slow
def test_design(work):
    """Without the certificate (a search of its own for seed 3; the certificate's fields from both
    sides: test_evaluate): every other field and the CSV byte for byte."""
    args = dict(criterion="kpi", n=20, seed=3, certify=False)
    _cli("design", "--robot", "kr16", "--criterion", "kpi", "--n", 20, "--seed", 3, "--no-certify",
         "--out", work / "d1.csv", "--json", work / "d1.json", cwd=work)  # fmt: skip
    res = api.design("kr16", out=work / "d2.csv", json_path=work / "d2.json", **args)
    assert (work / "d1.csv").read_bytes() == (work / "d2.csv").read_bytes()
    assert _plain((work / "d1.json").read_text()) == _plain((work / "d2.json").read_text())
    assert res.n == 20 and res.feasible


def test_simulate(work):
    api.simulate("kr16", DESIGN, work / "s2.csv", seed=4)
    assert (work / "data.csv").read_bytes() == (work / "s2.csv").read_bytes()


def test_calibrate(work):
    out = _cli("calibrate", "--robot", "kr16", work / "data.csv", "--json", cwd=work).stdout
    direct = api.calibrate("kr16", work / "data.csv")
    assert _plain(out) == _plain(direct.to_dict())
    out = _cli("calibrate", "--robot", "kr16", work / "data_el.csv", "--extend", "joint_elasticity:3",
               "--json", cwd=work).stdout  # fmt: skip
    direct = api.calibrate("kr16", work / "data_el.csv", extend=["joint_elasticity:3"])
    assert _plain(out) == _plain(direct.to_dict())
    assert [e["name"] for e in direct.to_dict()["effects"]] == ["joint_elasticity:3"]


def test_diagnose(work):
    out = _cli("diagnose", "--robot", "kr16", work / "data_el.csv", "--json", cwd=work).stdout
    direct = api.diagnose("kr16", work / "data_el.csv")
    assert _plain(out) == _plain(direct.to_json())
    assert [c["effect"] for c in direct.causes] == ["joint_elasticity"]


@pytest.mark.slow
def test_study(work):
    argv = ["--robots", "kr16", "--n", "20", "--heuristic-draws", "1", "--jobs", "1", "--no-progress"]
    _cli("study", *argv, "--out", work / "st1", cwd=work)
    api.study(work / "st2", robots=["kr16"], n=20, heuristic_draws=1, jobs=1, progress=False)
    for name in ("table6.csv", "table7.csv", "table8.csv"):
        assert (work / "st1" / name).read_text() == (work / "st2" / name).read_text()
    a = pd.read_csv(work / "st1" / "results.csv").drop(columns=["solve_s"])
    b = pd.read_csv(work / "st2" / "results.csv").drop(columns=["solve_s"])
    pd.testing.assert_frame_equal(a, b)
