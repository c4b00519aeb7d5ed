"""The figures every report prints (``estimation.accuracy``): computed by one function, printed the
same way by ``calibrate``, ``diagnose`` and ``validate``; counts of poses and rows; an extended fit
whose effects the data cannot determine names and drops them."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.accuracy import accuracy
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import read_measurements

FIGURE_LINE = re.compile(
    r"^ *RMS x, y, z, all: (\d+\.\d{4}), (\d+\.\d{4}), (\d+\.\d{4}), (\d+\.\d{4}) mm; "
    r"3-D error mean (\d+\.\d{4}), 95 % (\d+\.\d{4}), max (\d+\.\d{4}) mm$"
)


def test_figures_equal_a_hand_computation():
    rng = np.random.default_rng(11)
    q = np.repeat(rng.uniform(-1.0, 1.0, size=(12, 6)), 2, axis=0)  # 12 poses x 2 targets
    target = np.tile([0, 1], 12)
    r = rng.normal(0.0, [0.01, 0.02, 0.03], size=(24, 3))
    f = accuracy(r, q, kind="held-out", tracker="cross", target=target)
    e = np.linalg.norm(r, axis=1)
    assert (f.n_poses, f.n_rows) == (12, 24)
    assert_allclose(f.rms_xyz_mm, np.sqrt(np.mean(r**2, axis=0)), rtol=0, atol=1e-15)
    assert_allclose(f.rms_mm, np.sqrt(np.mean(r**2)), rtol=0, atol=1e-15)
    assert_allclose(
        [f.mean_error_mm, f.p95_error_mm, f.max_error_mm], [e.mean(), np.percentile(e, 95), e.max()]
    )
    t2 = f.targets[1]
    assert t2["n_rows"] == 12 and t2["max_error_mm"] == pytest.approx(e[1::2].max(), abs=1e-15)
    lines = f.lines()
    head = (
        "  held-out on 12 poses (24 rows), tracker frame cross-registered (on the other half of the poses):"
    )
    assert lines[0] == head
    assert FIGURE_LINE.match(lines[1]) and lines[3].startswith("    target 2 (12 rows): RMS x, y, z, all: ")
    assert float(FIGURE_LINE.match(lines[1]).group(5)) == pytest.approx(e.mean(), abs=5e-5)


@pytest.fixture(scope="module")
def kr16_data(tmp_path_factory):
    d = tmp_path_factory.mktemp("figures")
    robot = load_robot("kr16")
    q = robot.q_work + np.random.default_rng(7).uniform(-0.6, 0.6, size=(50, 6))
    simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=4))[0].to_csv(d / "data.csv", index=False)
    return d


def _figure_lines(text: str) -> dict[str, tuple[float, ...]]:
    """Header -> the numbers of the figure line under it."""
    lines = text.splitlines()
    return {
        lines[i - 1].strip(): tuple(float(x) for x in FIGURE_LINE.match(line).groups())
        for i, line in enumerate(lines)
        if FIGURE_LINE.match(line)
    }


def test_calibrate_diagnose_and_validate_print_the_same_figures(kr16_data):
    """On the data of a calibration: calibrate's fit, the calibrated model validated with its tracker
    frame kept, and diagnose's geometric fit print the same figure line (the same fit)."""
    d = kr16_data
    cal = api.calibrate("kr16", d / "data.csv", out=d / "cal.yaml")
    val = api.validate(str(d / "cal.yaml"), d / "data.csv")
    diag = api.diagnose("kr16", d / "data.csv")
    c, v, g = _figure_lines(cal.summary()), _figure_lines(val.summary()), _figure_lines(diag.summary())
    assert list(c) == ["fit on 50 poses, tracker frame estimated in the fit:"]
    assert list(v) == ["held-out on 50 poses, tracker frame kept (the model's):"]
    assert "geometric model, fit on 50 poses, tracker frame estimated in the fit:" in g
    assert any(
        k.startswith("geometric model, held-out on 50 poses, tracker frame estimated with each fold")
        for k in g
    )
    (fit,) = c.values()
    assert v[next(iter(v))] == fit
    assert_allclose(
        g["geometric model, fit on 50 poses, tracker frame estimated in the fit:"], fit, atol=1.5e-4
    )
    # and the JSON of each carries the same record
    cj, vj = cal.to_dict()["figures"]["fit"], val.to_dict()["figures"]
    gj = diag.to_json()["baseline"]["figures"]["fit"]
    for key in ("rms_mm", "mean_error_mm", "p95_error_mm", "max_error_mm"):
        assert_allclose(vj[key], cj[key], rtol=0, atol=1e-9, err_msg=key)
        assert_allclose(gj[key], cj[key], rtol=0, atol=1e-4, err_msg=key)
    assert_allclose(vj["rms_xyz_mm"], cj["rms_xyz_mm"], rtol=0, atol=1e-9)
    assert (cj["kind"], vj["kind"], gj["kind"]) == ("fit", "held-out", "fit")


@pytest.fixture(scope="module")
def two_smr(tmp_path_factory):
    """kr16 with two SMRs and an elastic joint 2: 40 poses x 2 targets."""
    d = tmp_path_factory.mktemp("two")
    kr16 = Path(load_robot("kr16").source).read_text()
    (d / "r.yaml").write_text(kr16 + "targets_mm: [[-89.58, -2.84, 327.03], [60, 80, 300]]\n")
    robot = load_robot(str(d / "r.yaml"))
    q = robot.q_work + np.random.default_rng(3).uniform(-0.6, 0.6, size=(40, 6))
    opts = SimulationOptions(sigma_mm=0.02, seed=1, n_targets=2, effects=("joint_elasticity:2=8e-7",))
    simulate(robot, q, opts)[0].to_csv(d / "data.csv", index=False)
    return robot, read_measurements(d / "data.csv", robot)


def test_an_undetermined_effect_is_named_with_what_it_trades_against_and_dropped(two_smr):
    """The elasticity of joint 2 and the gravity-torque basis of joint 2 (which contains it): the
    data cannot separate them; the basis is dropped with a warning naming it and its partner, the
    counts say poses and rows."""
    robot, data = two_smr
    effects = ("joint_elasticity:2", "joint_elasticity_basis:2")
    rep = calibrate(robot, data, CalibrationOptions(effects=effects))
    assert [e.name for e in rep.effects] == ["joint_elasticity:2"]
    (w,) = [w for w in rep.warnings if "do not determine the effect" in w]
    assert w.startswith(
        "these 40 poses (80 rows) do not determine the effect joint_elasticity_basis:2 (it trades against"
    )
    assert "joint_elasticity:2" in w.split("trades against")[1] and "dropped from the model" in w
    d = rep.to_dict()
    assert d["identifiability"]["effects_dropped"] == ["joint_elasticity_basis:2"]
    assert (d["n_poses"], d["n_rows"]) == (40, 80)
    assert (
        rep.summary()
        .splitlines()[0]
        .endswith("40 poses (80 rows, 2 targets), 80 rows used, 31 parameters, sigma 0.02 mm")
    )
    # the other order keeps the basis and drops the elasticity it contains
    other = calibrate(robot, data, CalibrationOptions(effects=effects[::-1]))
    assert [e.name for e in other.effects] == ["joint_elasticity_basis:2"]
    with pytest.raises(InputError, match="do not determine the effect joint_elasticity_basis:2") as info:
        calibrate(robot, data, CalibrationOptions(effects=effects, strict=True))
    assert info.value.fields == ("strict",)
