"""Progress of long runs: shown on request, silent otherwise, and the cold search's estimate."""

import io
import sys

import pytest

from kpioed_drake import progress
from kpioed_drake.design.approximate import search
from kpioed_drake.estimation.problem import make_problem


def test_silent_unless_asked(monkeypatch, capsys):
    monkeypatch.setenv(progress.ENV, "0")
    with progress.stage("work", total=3):
        progress.step(g_max=1.5)
    progress.note("an estimate")
    assert capsys.readouterr().err == ""


def test_shown_when_asked(monkeypatch):
    monkeypatch.setenv(progress.ENV, "1")
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with progress.stage("certificate search", total=2, unit="round"):
        progress.step(g_max=1.25)
        progress.step()
        bar = progress._CURRENT.get()
        assert bar is not None and bar.n == 2 and bar.postfix == "g_max=1.25"
    progress.note("about 2 min here")
    text = err.getvalue()
    assert "certificate search:" in text and "/2 [" in text  # tqdm redraws at most every 0.1 s
    assert "kpioed: about 2 min here" in text


def test_step_outside_a_stage_does_nothing(monkeypatch):
    monkeypatch.setenv(progress.ENV, "1")
    progress.step(g_max=2.0)  # no stage: nothing to advance, no error


@pytest.mark.parametrize("robot", ["kr16", "models/robots/humanoid18.urdf"])
def test_cold_search_estimate_grows_with_the_robot(robot):
    """The estimate is positive and finite; the 18-joint twin's is larger than a six-joint's by
    more than its joint count alone (its evaluations cost more too)."""
    est = search.cold_search_estimate_s(make_problem(robot), evaluations=3)
    assert 0.0 < est < 1e5


def test_twin_estimate_exceeds_six_joints():
    small = search.cold_search_estimate_s(make_problem("kr16"), evaluations=5)
    large = search.cold_search_estimate_s(make_problem("models/robots/humanoid18.urdf"), evaluations=5)
    assert large > 3.0 * small
