"""The options records of the workflows: frozen, checked when made, read from YAML (Drake's
``yaml_load_typed``), and the same run whether given as a record or as keywords."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.design import DesignOptions
from kpioed_drake.diagnosis import DiagnosisOptions
from kpioed_drake.errors import InputError
from kpioed_drake.options import load_options, options_from
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate
from kpioed_drake.tracker.data import Measurements

RECORDS = (CalibrationOptions, DesignOptions, SimulationOptions, DiagnosisOptions)


@pytest.mark.parametrize("cls", RECORDS)
def test_every_field_has_a_docstring_and_the_defaults_load_from_empty_yaml(cls):
    source = __import__(cls.__module__, fromlist=["_"]).__file__
    text = open(source).read()
    body = text[text.index(f"class {cls.__name__}") :]
    for f in dataclasses.fields(cls):
        after = body[body.index(f"    {f.name}:") :].splitlines()[1].strip()
        assert after.startswith('"""'), f"{cls.__name__}.{f.name} has no docstring"
    assert load_options(cls, data="{}") == cls()
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(cls(), dataclasses.fields(cls)[0].name, None)


def test_yaml_lists_become_tuples_and_unknown_fields_are_refused(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("sigma_mm: 0.05\neffects: [joint_elasticity:2, joint_scale:3]\nstrict: true\n")
    opts = load_options(CalibrationOptions, filename=path)
    assert opts == CalibrationOptions(
        sigma_mm=0.05, effects=("joint_elasticity:2", "joint_scale:3"), strict=True
    )
    with pytest.raises(InputError, match="cal.yaml"):
        path.write_text("sigma: 0.05\n")
        load_options(CalibrationOptions, filename=path)


@pytest.mark.parametrize(
    "cls, field, value, match",
    [
        (CalibrationOptions, "sigma_mm", 0.0, "sigma_mm"),
        (CalibrationOptions, "outlier_alpha", 1.0, "outlier_alpha"),
        (CalibrationOptions, "max_iter", 0, "max_iter"),
        (SimulationOptions, "sigma_mm", -1.0, "sigma_mm"),
        (SimulationOptions, "seed", -1, "seed"),
        (DesignOptions, "criterion", "d-opt", "criterion"),
        (DesignOptions, "n", 0, "n"),
        (DesignOptions, "target_var_mm2", -0.1, "target_var_mm2"),
        (DesignOptions, "condition_span", "3K", "condition_span goes with discriminate"),
    ],
)
def test_a_bad_value_is_refused_when_the_record_is_made(cls, field, value, match):
    with pytest.raises(InputError, match=match) as exc:
        cls(**{field: value})
    assert field in exc.value.fields or field in str(exc.value)


def test_options_from_replaces_fields_and_names_an_unknown_one():
    base = DesignOptions(n=30, seed=2)
    assert options_from(DesignOptions, base, n=12) == DesignOptions(n=12, seed=2)
    assert options_from(DesignOptions, None) == DesignOptions()
    with pytest.raises(InputError, match="unknown option nn; the options are .*n,"):
        options_from(DesignOptions, base, nn=3)
    with pytest.raises(InputError, match="expected a DesignOptions"):
        options_from(DesignOptions, CalibrationOptions())


@pytest.mark.slow
def test_a_design_from_a_record_equals_the_design_from_keywords(tmp_path):
    kw = dict(criterion="kpi", n=12, seed=1, certify=False)
    by_keywords = api.design("kr16", out=tmp_path / "a.csv", **kw)
    by_record = api.design("kr16", options=DesignOptions(**kw), out=tmp_path / "b.csv")
    assert_allclose(by_record.q, by_keywords.q, rtol=0, atol=0)
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()


def test_calibrate_and_simulate_take_their_records():
    robot = load_robot("kr16")
    rng = np.random.default_rng(5)
    q = robot.lower + rng.random((40, 6)) * (robot.upper - robot.lower)
    table, truth = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=5))
    assert truth["seed"] == 5 and truth["sigma_mm"] == 0.02
    data = Measurements.from_table(table, robot)
    report = calibrate(robot, data, CalibrationOptions(sigma_mm=0.05, outlier_alpha=0))
    assert report.to_dict()["sigma_mm"] == 0.05 and report.outliers == []
    again = calibrate(robot, data, CalibrationOptions(sigma_mm=0.05))
    assert_allclose(report.result.model.p, again.result.model.p, rtol=0, atol=1e-9)
