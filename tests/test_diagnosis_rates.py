"""The rate study's harness (studies/diagnosis_rates.py): a quick run writes one file per finished
case, a second run resumes (reads them back, computes nothing), the summary counts what is on disk,
and the harder harness (masses +-30 % off the file, a changing payload, near-threshold sizes)
keeps every other draw of a case the same when the effect is rescaled."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from kpioed_drake.effects import parse_effect
from kpioed_drake.study import synthetic as S

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("diagnosis_rates", ROOT / "studies" / "diagnosis_rates.py")
rates = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rates)


def test_quick_run_writes_cases_and_resumes(tmp_path, capsys):
    assert rates.main(["--out", str(tmp_path), "--quick", "--workers", "1"]) == 0
    files = sorted((tmp_path / "cases").glob("*.json"))
    assert [f.name for f in files] == ["clean-0.json", "pair-0.json", "single-joint_scale-0.json"]
    table = capsys.readouterr().out
    assert "| single:joint_scale | 1 |" in table and "| clean | 1 |" in table
    recs = {f.name: json.loads(f.read_text()) for f in files}
    assert recs["single-joint_scale-0.json"]["truth_names"][0].startswith("joint_scale:")
    assert recs["pair-0.json"]["options"]["mass_spread"] == 0.3
    summary = json.loads((tmp_path / "summary.json").read_text())["summary"]
    assert summary["clean"]["cases"] == 1 and "false_alarms" in summary["clean"]
    # resume: the files are read back, not recomputed (a recomputation would rewrite them)
    stamps = [f.stat().st_mtime_ns for f in files]
    (tmp_path / "cases" / "pair-0.json").write_text(json.dumps({**recs["pair-0.json"], "marker": 1}))
    stamps[1] = (tmp_path / "cases" / "pair-0.json").stat().st_mtime_ns
    assert rates.main(["--out", str(tmp_path), "--quick", "--workers", "1"]) == 0
    assert [f.stat().st_mtime_ns for f in files] == stamps


def test_bad_kind_is_refused(tmp_path):
    with pytest.raises(SystemExit) as e:
        rates.main(["--out", str(tmp_path), "--kinds", "single:nonsense"])
    assert e.value.code == 2
    assert not (tmp_path / "cases").exists()


def test_harder_harness_draws(kr16):
    # other masses: a different robot, the same kinematics; payload levels per pose
    rng = np.random.default_rng(2)
    case = S.synthetic_case(kr16, rng, [], n_poses=20, mass_spread=0.3, payload_kg=(0.0, 7.0))
    m_true, m_file = case.model_true.robot.masses[1:], kr16.masses[1:]
    assert np.all(np.abs(m_true / m_file - 1) <= 0.3) and not np.allclose(m_true, m_file)
    assert set(np.unique(case.data.payload_kg)) == {0.0, 7.0}
    # the same seeds with a rescaled effect: same truth, poses and noise, the signal scaled
    eff = parse_effect("joint_scale:2=500")
    runs = []
    for v in (500e-6, 1000e-6):
        rng = np.random.default_rng(3)
        runs.append(S.synthetic_case(kr16, rng, [eff.with_values([v])], n_poses=20, mass_spread=0.3))
    np.testing.assert_array_equal(runs[0].data.q, runs[1].data.q)
    lam = [S.detectability(c)[0] for c in runs]
    assert lam[1] == pytest.approx(4 * lam[0], rel=1e-3)  # columns at the values: nearly linear
