"""The approximate-design start of the optimiser and the certificate in the design and evaluate
outputs (issue 14): ``start=``, ``--start``, ``--certify``, ``certify=``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.design import START_METHODS, approximate_start, check_design, optimize_design, resolve_start
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design


@pytest.fixture(scope="module")
def kr16():
    return make_problem("kr16")


def _run(capsys, *argv):
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.slow
def test_approximate_start_is_feasible_and_no_worse_than_the_heuristic_start(kr16):
    n = 30
    heuristic = optimize_design(kr16, n=n, seed=0, start="heuristic")
    approx = optimize_design(kr16, n=n, seed=0, start="approximate")
    assert heuristic.start == "heuristic" and approx.start == "approximate"
    assert approx.feasible and approx.success
    _, n_bad, _ = check_design(kr16, approx.q)
    assert n_bad == 0
    assert approx.kpi_avg_var_mm2 <= heuristic.kpi_avg_var_mm2
    # the start itself is the rounded approximate design of the same seed
    q0 = approximate_start(kr16, n=n, seed=0)
    assert approx.initial_values[0] == pytest.approx(kr16.criteria(q0)["kpi_avg_var_mm2"], rel=1e-12)
    assert approx.start_s > 0.0
    assert approx.summary()["start"] == "approximate"
    # a caller's q0 is recorded as such
    assert optimize_design(kr16, n=n, seed=0, q0=q0).start == "q0"


def test_default_start_and_bad_start_values(kr16):
    assert resolve_start(None, "kpi") in START_METHODS
    assert resolve_start(None, "param") == "heuristic"
    assert resolve_start(None, "kpi", given=np.zeros((3, 6))) == "approximate"
    assert resolve_start("approximate", "kpi") == "approximate"
    with pytest.raises(InputError, match="unknown start"):
        optimize_design(kr16, n=20, start="random")
    with pytest.raises(InputError, match="criterion 'kpi'"):
        optimize_design(kr16, n=20, criterion="param", start="approximate")
    with pytest.raises(InputError, match="start"):
        api.design("kr16", n=20, start="approx")


def test_bad_start_on_the_command_line(capsys, tmp_path):
    out = str(tmp_path / "d.csv")
    for options, message in (
        (["--criterion", "kpi", "--start", "best"], "--start"),
        (["--criterion", "param", "--start", "approximate", "--n", "20"], "criterion 'kpi'"),
    ):
        code, _, err = _run(capsys, "design", "--robot", "kr16", *options, "--out", out)
        assert code == 2 and message in err
    assert not (tmp_path / "d.csv").exists()


@pytest.mark.slow
def test_design_and_evaluate_certify(capsys, tmp_path, quick_certificate):
    out, js = tmp_path / "d.csv", tmp_path / "d.json"
    code, text, _ = _run(
        capsys, "design", "--robot", "kr16", "--criterion", "kpi", "--n", "20", "--certify",
        "--start", "heuristic", "--out", str(out), "--json", str(js),
    )  # fmt: skip
    assert code == 0
    assert "lower bound for any 20-pose design:" in text and "efficiency" in text
    rec = json.loads(js.read_text())
    assert rec["start"] in START_METHODS
    for key in ("bound_mm2", "efficiency", "design_beyond_search", "certificate"):
        assert key in rec
    assert 0.0 < rec["efficiency"] <= 1.0
    assert rec["bound_mm2"] <= rec["values"]["kpi_avg_var_mm2"]
    assert rec["certificate"]["value_mm2"] == pytest.approx(rec["values"]["kpi_avg_var_mm2"], rel=1e-12)
    assert rec["certificate"]["n_poses"] == 20 and rec["design_beyond_search"] > 0

    # evaluate the written design: the same search (same problem and seed), the same search bound
    d = api.evaluate("kr16", out, certify=True)
    assert 0.0 < d["efficiency"] <= 1.0 and d["bound_mm2"] <= d["kpi_avg_var_mm2"]
    assert d["certificate"]["search_bound_mm2"] == pytest.approx(
        rec["certificate"]["search_bound_mm2"], rel=1e-9
    )
    assert d["certificate"]["value_mm2"] == pytest.approx(d["kpi_avg_var_mm2"], rel=1e-9)
    code, text, _ = _run(capsys, "evaluate", "--robot", "kr16", "--design", str(out), "--certify")
    assert code == 0 and "lower bound for any 20-pose design:" in text
    # with --no-certify the fields are there, null
    plain = api.evaluate("kr16", out, certify=False)
    assert all(plain[k] is None for k in ("bound_mm2", "efficiency", "design_beyond_search", "certificate"))
    code, text, _ = _run(capsys, "evaluate", "--robot", "kr16", "--design", str(out), "--no-certify")
    assert code == 0 and "lower bound" not in text


@pytest.fixture
def cache(monkeypatch, tmp_path):
    """The certificate's disk cache in a fresh folder."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("KPIOED_CACHE", str(folder))
    return folder


@pytest.mark.slow
def test_every_design_record_has_its_bound_and_efficiency(
    capsys, tmp_path, quick_certificate, quick_start, cache
):
    for crit in ("heuristic", "param", "kpi"):
        js = tmp_path / f"{crit}.json"
        res = api.design("kr16", criterion=crit, n=20, json_path=js)
        rec = json.loads(js.read_text())
        value = rec["values"]["kpi_avg_var_mm2"]
        assert 0.0 < rec["efficiency"] <= 1.0 and 0.0 < rec["bound_mm2"] <= value
        assert rec["efficiency"] == pytest.approx(rec["bound_mm2"] / value, rel=1e-12)
        assert res.certificate["n_given"] == 0
    assert rec["start"] == "approximate"  # the kpi criterion's default start
    assert len(list(cache.glob("certificate-*.npz"))) == 1  # one search per setup, for every criterion
    # the command line: the summary line and the JSON by default; --no-certify: null fields
    js = tmp_path / "cli.json"
    code, text, _ = _run(capsys, "design", "--robot", "kr16", "--criterion", "param", "--n", "20",
                         "--json", str(js), "--out", str(tmp_path / "d.csv"))  # fmt: skip
    assert code == 0 and "lower bound for any 20-pose design:" in text and "not of the design's" in text
    assert 0.0 < json.loads(js.read_text())["efficiency"] <= 1.0
    code, text, _ = _run(capsys, "design", "--robot", "kr16", "--criterion", "heuristic", "--n", "20",
                         "--no-certify", "--json", str(js), "--out", str(tmp_path / "d.csv"))  # fmt: skip
    rec = json.loads(js.read_text())
    assert code == 0 and "lower bound" not in text
    assert rec["bound_mm2"] is None and rec["efficiency"] is None and rec["certificate"] is None


@pytest.mark.slow
def test_design_with_given_poses_has_the_bound_of_the_combined_design(
    tmp_path, kr16, quick_certificate, cache
):
    given = tmp_path / "given.csv"
    q_given = approximate_start(kr16, n=20, seed=3)
    write_design(given, q_given)
    js = tmp_path / "d.json"
    res = api.design("kr16", criterion="kpi", n=5, given=given, json_path=js)
    rec = json.loads(js.read_text())
    assert res.start == "approximate" and rec["certificate"]["n_given"] == 20
    # the start chosen with the measured information against the paper's heuristic start
    heur = api.design("kr16", criterion="kpi", n=5, given=given, start="heuristic", certify=False)
    assert res.initial_values[0] < heur.initial_values[0]
    combined = rec["values"]["kpi_avg_var_mm2"]
    assert combined == pytest.approx(
        kr16.criteria(np.concatenate([q_given, res.q]))["kpi_avg_var_mm2"], rel=1e-6
    )
    assert 0.0 < rec["bound_mm2"] <= combined and 0.0 < rec["efficiency"] <= 1.0
