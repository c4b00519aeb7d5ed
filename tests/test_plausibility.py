"""Plausibility judges the right thing: what the data alone tell (tracker frame, target offsets) is
registered before comparing with the nominal model, the gate grows with the robot, and a fitted model
whose robot parameters moved by metres or tens of degrees is refused (``force`` goes on)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from kpioed_drake import api, calibration, simulation
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import plausibility
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model

REPO = Path(__file__).resolve().parents[1]
UR10 = Path(os.environ.get("KPIOED_SHARED_DATA", REPO.parent / "shared" / "data")) / "ur10-laser-tracker"
SIGMA = 0.02


@pytest.fixture(scope="module")
def kr16_data():
    robot = load_robot("kr16")
    q = np.random.default_rng(11).uniform(robot.lower, robot.upper, size=(40, 6))
    table, _ = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=11))
    return robot, Measurements.from_table(table, robot)


def test_the_gate_grows_with_the_reach():
    small, large = load_robot("ur5"), load_robot("kr500")
    gate = [plausibility.geometric_gate_mm(nominal_model(r, load_cell(robot=r))) for r in (small, large)]
    assert gate[0] == plausibility.MAX_GEOMETRIC_MM
    assert gate[1] == pytest.approx(plausibility.GATE_REACH_SHARE * large.reach)
    assert gate[1] > gate[0]


def test_a_wrong_nominal_tool_point_is_registered_not_refused(kr16_data):
    """The nominal reflector 250 mm off: the registered target offset absorbs it, and the calibration
    finds the true offset."""
    robot, data = kr16_data
    off = dataclasses.replace(robot, p_FQ=load_cell(robot=robot).p_FQ + [0.0, 0.0, 250.0])
    model = nominal_model(off, load_cell(robot=off))
    assert plausibility.check_data(model, data, n_params=33) == []
    report = calibration.calibrate(off, data, calibration.CalibrationOptions(sigma_mm=SIGMA))
    assert report.chi2_per_dof < 2.0


@pytest.mark.skipif(not UR10.is_dir(), reason=f"{UR10} not available")
def test_real_ur10_data_with_the_probe_250_mm_off_is_kept(tmp_path):
    text = (REPO / "models" / "robots" / "ur10.yaml").read_text()
    path = tmp_path / "ur10-off.yaml"
    path.write_text(
        text.replace("reflector_position_mm: [0.0, 0.0, 93.0]", "reflector_position_mm: [0.0, 0.0, 343.0]")
    )
    report = api.calibrate(str(path), UR10 / "train.csv", sigma_mm=0.01)
    d = report.to_dict()
    z = next(p for p in d["parameters"] if p["name"] == "reflector_z")
    assert abs(z["value"] - 93.0) < 5.0


def test_a_fit_that_moves_a_joint_by_metres_is_refused_and_force_goes_on(kr16_data):
    """A coupling left out of the joint map for some poses: joint 3 off by joint 2's angle at a third
    of the poses makes the fit move robot parameters far beyond any geometric error."""
    robot, data = kr16_data
    q = data.q.copy()
    q[::3, 2] += q[::3, 1]
    wrong = dataclasses.replace(data, q=q)
    fake = dataclasses.replace(
        calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=SIGMA)).result,
    )
    nominal = nominal_model(robot, load_cell(robot=robot))
    p = fake.model.p.copy()
    i = nominal.layout.names.index("a2")
    p[i] += 1627.0
    moved = dataclasses.replace(fake, model=fake.model.with_params(p))
    with pytest.raises(InputError, match=r"a2 \[A2 \(joint 2\)\] by \+1627 mm"):
        plausibility.check_fitted(moved, nominal, data, force=False, warnings=[])
    warnings: list[str] = []
    plausibility.check_fitted(moved, nominal, data, force=True, warnings=warnings)
    assert warnings and warnings[0].startswith("forced:")
    with pytest.raises(InputError, match="wrong joint map|gross errors|misses"):
        calibration.calibrate(robot, wrong, calibration.CalibrationOptions(sigma_mm=SIGMA))


def test_validate_force(tmp_path, kr16_data, capsys):
    robot, data = kr16_data
    table = tmp_path / "mm.csv"
    metres = tmp_path / "m.csv"
    header = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
    rows = np.hstack([np.rad2deg(data.q), data.eta / 1000.0])
    metres.write_text(header + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    assert main(["validate", "--robot", "kr16", str(metres)]) == 2
    assert "metres" in capsys.readouterr().err
    assert main(["validate", "--robot", "kr16", str(metres), "--force", "--json", str(table)]) == 0
    assert "forced:" in " ".join(__import__("json").loads(table.read_text())["warnings"])
