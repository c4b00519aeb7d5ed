"""Outlier screening of a 6-DoF probe's orientation rows (kpioed_drake.calibration.robust).

Simulated kr16 pose data (0.02 mm, 0.005 deg): three poses whose measured orientation is turned
by 2 deg are removed, exactly those, each named with the part that failed (orientation), and the
fit then puts the true TCP within its 99.7 % ellipsoid; without them nothing is removed at the
default family-wise level 0.01; a 5 mm position error on a pose data set is still named a position
outlier. The orientation statistic is chi^2(3) on clean data (mean 3) and at a unit noise its robust
scale is the orientation noise. The identifiability test before the fit weighs the orientation rows
beside the positions as the fit does.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from test_calibration import kpi_distance2

from kpioed_drake import api, calibration, simulation
from kpioed_drake.calibration.fit import hold_undetermined
from kpioed_drake.calibration.robust import effective_statistics
from kpioed_drake.files.orientation_columns import QUATERNION_COLUMNS
from kpioed_drake.robot.models import load_cell
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model
from kpioed_drake.tracker.orientation import with_probe

SIGMA_MM = 0.02
SIGMA_DEG = 0.005
N_POSES = 60
TURN_DEG = 2.0


@pytest.fixture(scope="module")
def clean(kr16):
    q = np.random.default_rng(41).uniform(kr16.lower, kr16.upper, size=(N_POSES, 6))
    options = simulation.SimulationOptions(sigma_mm=SIGMA_MM, seed=42, orientation_sigma_deg=SIGMA_DEG)
    return simulation.simulate(kr16, q, options)


def _turned(table, seed: int, k: int = 3):
    """A copy of ``table`` with the orientations of ``k`` random rows turned by TURN_DEG."""
    rng = np.random.default_rng(seed)
    bad = np.sort(rng.choice(len(table), size=k, replace=False))
    axis = rng.standard_normal((k, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    cols = list(QUATERNION_COLUMNS)
    R = Rotation.from_quat(table.loc[bad, cols].to_numpy(), scalar_first=True)
    out = table.copy()
    out.loc[bad, cols] = (Rotation.from_rotvec(np.deg2rad(TURN_DEG) * axis) * R).as_quat(scalar_first=True)
    return out, bad


def _calibrate(kr16, table):
    options = calibration.CalibrationOptions(sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG)
    return calibration.calibrate(kr16, Measurements.from_table(table, kr16), options)


def test_turned_orientations_are_removed_and_named(kr16, clean):
    table, truth = clean
    turned, bad = _turned(table, seed=43)
    rep = _calibrate(kr16, turned)
    assert sorted(rep.outliers) == bad.tolist()
    robust = rep.to_dict()["robust"]
    assert [r["part"] for r in robust["reasons"]] == ["orientation"] * bad.size
    assert all(r["statistic"] > r["threshold"] for r in robust["reasons"])
    assert all(r["residual_angle_deg"] > 1.5 for r in robust["reasons"])
    # removed, they are predicted by the fit without them: a prediction error far beyond the noise
    assert np.all(rep.normalized_rot[bad] > 100 * robust["reasons"][0]["threshold"])
    assert np.all(rep.normalized_rot[rep.used] < robust["reasons"][-1]["threshold"])
    assert "(orientation)" in rep.summary() and "robust scale of the orientation residuals" in rep.summary()
    # the fit without them: the true TCP within 3 sigma (the 99.7 % ellipsoid), a noise-level fit
    assert kpi_distance2(rep, truth["model"]) <= chi2.ppf(0.9973, 3)
    assert 0.8 < rep.chi2_per_dof < 1.2
    poses = rep.to_dict()["poses"]
    assert all("normalized_chi2_orientation" in p for p in poses)


def test_clean_pose_data_keep_every_pose(kr16, clean):
    """At the default family-wise level 0.01 (both parts, Bonferroni over 2 n tests)."""
    table, truth = clean
    rep = _calibrate(kr16, table)
    assert rep.outliers == [] and rep.outlier_alpha == 0.01
    assert kpi_distance2(rep, truth["model"]) <= chi2.ppf(0.9973, 3)
    t_rot = rep.normalized_rot[rep.used]
    assert t_rot.mean() == pytest.approx(3.0, abs=3 * np.sqrt(6.0 / t_rot.size))  # chi^2(3): mean 3, var 6
    now = effective_statistics(rep.result, rep.used)
    assert np.rad2deg(now.scales[1]) == pytest.approx(SIGMA_DEG, rel=0.2)  # the noise, from the residuals
    assert rep.to_dict()["robust"]["orientation"]["sigma_deg_median"] == pytest.approx(SIGMA_DEG)


def test_a_position_error_on_pose_data_is_a_position_outlier(kr16, clean):
    table, _ = clean
    moved = table.copy()
    moved.loc[7, ["x_mm", "y_mm", "z_mm"]] += np.array([3.0, -4.0, 0.0])
    rep = _calibrate(kr16, moved)
    assert rep.outliers == [7]
    assert rep.to_dict()["robust"]["reasons"][0]["part"] == "position"


def test_the_orientation_scale_follows_a_noise_larger_than_given(kr16, clean):
    """A sigma_deg four times too small: the test runs at the residuals' scale, nothing removed."""
    table, _ = clean
    options = calibration.CalibrationOptions(sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG / 4)
    rep = calibration.calibrate(kr16, Measurements.from_table(table, kr16), options)
    assert rep.outliers == []
    o = rep.to_dict()["robust"]["orientation"]
    assert o["scale_deg"] == pytest.approx(SIGMA_DEG, rel=0.2)
    assert o["sigma_effective_deg_median"] == pytest.approx(o["scale_deg"])


def test_the_nominal_identifiability_test_weighs_orientations_as_the_fit(kr16):
    """20 heuristic poses measured with a probe: weighted as the fit weighs them (sigma_mm 0.02 mm,
    0.005 deg) they determine every parameter and the fit explains the noise; weighted as if the
    positions had 1 mm of noise (50 times too little beside the orientations) theta2 and theta3
    look tied (correlation beyond 0.999) and holding one biases the fit."""
    q = api.design("kr16", criterion="heuristic", n=20, seed=3, certify=False).q
    options = simulation.SimulationOptions(sigma_mm=SIGMA_MM, seed=1, orientation_sigma_deg=SIGMA_DEG)
    data = Measurements.from_table(simulation.simulate(kr16, q, options)[0], kr16)
    start = with_probe(nominal_model(kr16, load_cell(robot=kr16)))
    held = {}
    for sigma_mm in (SIGMA_MM, 1.0):
        model = hold_undetermined(start, data, False, [], SIGMA_DEG, sigma_mm)
        held[sigma_mm] = set(start.layout.free_names) - set(model.layout.free_names)
    assert held[SIGMA_MM] == set() and held[1.0] & {"theta2", "theta3"}
    rep = calibration.calibrate(
        kr16, data, calibration.CalibrationOptions(sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG)
    )
    assert rep.identifiability["at_nominal"] == [] and not rep.rejects
