"""`kpioed info` / `kpioed evaluate`: results and clear errors on bad input (exit status 2)."""

import json

import numpy as np
import pytest

from kpioed_drake.cli import main
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_robot


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    robot = load_robot("kr16")
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.lower, robot.upper, size=(30, 6))
    path = tmp_path_factory.mktemp("d") / "design.csv"
    write_design(path, q)
    return path, q


def _run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_info_json(capsys):
    code, out, _ = _run(capsys, "info", "--robot", "kr16", "--json")
    d = json.loads(out)
    assert code == 0 and d["n_params"] == 27 and len(d["estimated"]) == 27
    assert abs(d["reach_mm"] - 1611) < 1


def test_evaluate_matches_library(capsys, design_file, tmp_path):
    path, q = design_file
    js = tmp_path / "r.json"
    # the certificate: tests/test_design_start.py
    ev = ["evaluate", "--robot", "kr16", "--design", str(path), "--no-certify"]
    code, out, _ = _run(capsys, *ev, "--json", str(js))
    assert code == 0 and "tr(Cs)/3" in out
    d = json.loads(js.read_text())
    prob = make_problem("kr16")
    crit = prob.criteria(np.deg2rad(np.round(np.rad2deg(q), 6)))
    assert d["kpi_avg_var_mm2"] == pytest.approx(crit["kpi_avg_var_mm2"], rel=1e-6)
    assert d["param_crit"] == pytest.approx(crit["param_crit"], rel=1e-6)
    assert d["n_params"] == 27 and len(d["poses"]) == 30
    assert isinstance(d["feasible"], bool)
    # noise scales the covariance quadratically
    code, out, _ = _run(capsys, *ev, "--sigma-mm", "0.1", "--json", "-")
    assert json.loads(out)["kpi_avg_var_mm2"] == pytest.approx(0.01 * d["kpi_avg_var_mm2"], rel=1e-9)


def test_q_work_override_changes_kpi(capsys, design_file):
    path, _ = design_file
    ev = ["evaluate", "--robot", "kr16", "--design", str(path), "--no-certify", "--json", "-"]
    base = json.loads(_run(capsys, *ev)[1])
    other = json.loads(_run(capsys, *ev, "--q-work", "0,-90,90,0,30,0")[1])
    assert other["q_work_deg"] == [0, -90, 90, 0, 30, 0]
    assert other["kpi_avg_var_mm2"] != pytest.approx(base["kpi_avg_var_mm2"], rel=1e-3)


HEADER = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
ROW = "10,-40,60,5,20,0\n"


@pytest.mark.parametrize(
    "content, message",
    [
        ("", "empty"),
        (HEADER.replace("q3_deg", "q3_dg") + ROW * 12, "missing column 'q3_deg'.*q3_dg"),
        (HEADER.replace(",q6_deg", "") + "10,-40,60,5,20\n" * 12, "missing column 'q6_deg'"),
        (HEADER + ROW * 3 + "10,-40,abc,5,20,0\n" + ROW * 8, "row 5, column 'q3_deg'.*'abc' is not a number"),
        (HEADER + ROW * 3 + "10,-40,nan,5,20,0\n" + ROW * 8, "row 5, column 'q3_deg'.*not a finite"),
        (
            HEADER + ROW * 2 + "10,-40,160,5,20,0\n" + ROW * 9,
            "row 4, column 'q3_deg'.*outside the joint range",
        ),
        (HEADER + ROW * 5, "5 poses cannot determine 27 parameters.*at least 9"),
        (HEADER + "0.1,-0.5,1.2,0.1,0.3,0.2\n0.2,-0.4,1.0,0.3,0.2,0.1\n" * 6, "look like radians"),
        (HEADER.strip() + ",q1_deg\n" + "10,-40,60,5,20,0,1\n" * 12, "'q1_deg' appears more than once"),
        (HEADER + ROW * 10 + "1,2\n", "row 12: 2 fields"),
    ],
)
def test_evaluate_bad_design_file(capsys, tmp_path, content, message):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    code, out, err = _run(capsys, "evaluate", "--robot", "kr16", "--design", str(bad))
    assert code == 2
    assert err.startswith("kpioed: error: ") and str(bad) in err
    assert len(err.strip().splitlines()) == 1
    import re

    assert re.search(message, err), err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["evaluate", "--robot", "kr17", "--design", "x.csv"], "unknown robot 'kr17'"),
        (["evaluate", "--robot", "kr16", "--design", "/nonexistent/d.csv"], "file not found"),
        (["evaluate", "--robot", "kr16", "--design", "{design}", "--q-work", "0,0,0"], "--q-work"),
        (["evaluate", "--robot", "kr16", "--design", "{design}", "--q-work", "0,-90,170,0,0,0"], "outside"),
        (["evaluate", "--robot", "kr16", "--design", "{design}", "--sigma-mm", "-1"], "sigma"),
        (["info"], "--robot"),
    ],
)
def test_bad_arguments(capsys, design_file, argv, message):
    argv = [a.replace("{design}", str(design_file[0])) for a in argv]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_row_numbers_count_file_lines_with_blank_lines(capsys, tmp_path):
    bad = tmp_path / "blank.csv"
    bad.write_text(HEADER + ROW * 3 + "\n\n" + "10,-40,abc,5,20,0\n" + ROW * 8)
    code, _, err = _run(capsys, "evaluate", "--robot", "kr16", "--design", str(bad))
    assert code == 2 and "row 7, column 'q3_deg'" in err
