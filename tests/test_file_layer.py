"""The file layer reads a measurement file in one place: one read enters the reader's module at
most three times (its call and the returns from the robot's joint units), for the native CSV and
for a file a format file describes; both give the same measurements."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from kpioed_drake.tracker.data import read_data

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import reader_transitions as rt  # noqa: E402


def test_one_read_enters_the_reader_at_most_three_times(tmp_path):
    robot, native, foreign, fmt = rt.sample_files(tmp_path)
    for args in ((native, robot), (foreign, robot, fmt)):
        seq = rt.stays(read_data, *args)
        assert seq[0] == "kpioed_drake.tracker.data", seq[:3]
        assert 1 <= seq.count(rt.READER) <= 3, (args[0].name, seq)
    a, b = read_data(native, robot), read_data(foreign, robot, fmt)
    np.testing.assert_allclose(a.q, b.q, atol=1e-12)
    np.testing.assert_allclose(a.eta, b.eta, atol=1e-9)


def test_the_count_sees_every_return(tmp_path):
    """The count can fail: a module called once per item (the robot model's properties, once per
    joint column) is entered once more per call, by the return from the caller's module too."""
    robot, native, _, _ = rt.sample_files(tmp_path)
    seq = rt.stays(read_data, native, robot)
    assert seq.count("kpioed_drake.robot.models") > 3
    assert rt.stays(lambda: np.stack([np.zeros(2)])) == []  # numpy's frames are no module of the package
