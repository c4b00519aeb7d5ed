"""Fixtures shared by the tests: the session's own certificate cache (one for every xdist worker), the
smaller searches of the certificate and the approximate start, and the kr16 models."""

import os
import tempfile

import numpy as np
import pytest

from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate import design as approximate
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.tracker.measurement import nominal_model


def pytest_configure(config):
    """Run the tests with an empty certificate cache of their own (as on a fresh CI machine), never
    the user's ``~/.cache/kpioed``; subprocesses of the CLI tests inherit it. With ``-n`` (xdist) the
    workers share the session's folder (:func:`pytest_configure_node`): a certificate search is
    paid once per run, not once per worker (the cache writes atomically)."""
    shared = getattr(config, "workerinput", {}).get("kpioed_cache")
    os.environ["KPIOED_CACHE"] = shared or tempfile.mkdtemp(prefix="kpioed-test-cache-")


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """xdist: hand each worker the session's certificate cache folder."""
    node.workerinput["kpioed_cache"] = os.environ["KPIOED_CACHE"]


@pytest.fixture
def quick_certificate(monkeypatch):
    """A smaller search behind the certificate (the bound stays rigorous for the poses evaluated;
    the disk cache keys the search settings, so it never serves the full search's result)."""
    for name, value in (
        ("CERTIFY_ROUNDS", 2),
        ("VERIFY_ROUNDS", 1),
        ("VERIFY_POOL", 500),
        ("VERIFY_STARTS", 8),
    ):
        monkeypatch.setattr(certificate, name, value)


@pytest.fixture
def quick_start(monkeypatch):
    """A smaller approximate design behind the optimiser's start (300 candidates and 2 rounds instead
    of 1000 and 4): every pose of the start still a feasible candidate, only its value is worse."""
    monkeypatch.setattr(approximate, "START_POOL", 300)
    monkeypatch.setattr(approximate, "START_ROUNDS", 2)


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def nominal(kr16):
    """kr16's nominal model."""
    return nominal_model(kr16, load_cell(robot=kr16))


@pytest.fixture(scope="module")
def model(kr16):
    """kr16's model with its joint rows, tracker rotation and reflector perturbed (seed 3)."""
    nom = nominal_model(kr16, load_cell(robot=kr16))
    rng = np.random.default_rng(3)
    p = nom.p.copy()
    lay = nom.layout
    p[lay.joints] += 0.01 * rng.standard_normal(lay.joints.stop)
    p[lay.tracker_rotation] = 0.01 * rng.standard_normal(3)
    p[lay.target(0)] += rng.standard_normal(3)
    return nom.with_params(p)
