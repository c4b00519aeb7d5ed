"""Fixtures shared by the effect tests; the test session's own certificate cache."""

import os
import tempfile

import numpy as np
import pytest

from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.tracker.measurement import nominal_model


def pytest_configure(config):
    """Run the tests with an empty certificate cache of their own (as on a fresh CI machine), never
    the user's ``~/.cache/kpioed``; subprocesses of the CLI tests inherit it."""
    os.environ["KPIOED_CACHE"] = tempfile.mkdtemp(prefix="kpioed-test-cache-")


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def model(kr16):
    nom = nominal_model(kr16, load_cell(robot=kr16))
    rng = np.random.default_rng(3)
    p = nom.p.copy()
    lay = nom.layout
    p[lay.joints] += 0.01 * rng.standard_normal(lay.joints.stop)
    p[lay.tracker_rotation] = 0.01 * rng.standard_normal(3)
    p[lay.target(0)] += rng.standard_normal(3)
    return nom.with_params(p)
