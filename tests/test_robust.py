"""Outlier screening robust to real residuals (issue 12, item 8).

Gross errors (here 5 mm, 3 % of the rows) are removed whatever sigma is given; clean data lose no
pose, also with a sigma four times too small (the test runs at the residuals' robust scale); the
JSON report says how many rows were removed and why; heavy-tailed data where over a third of the
rows fail even at the robust scale are refused (``force``: kept, with a warning).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from kpioed_drake import calibration, simulation
from kpioed_drake.calibration.robust import CHI2_3_MEDIAN, robust_scale_factor
from kpioed_drake.errors import InputError
from kpioed_drake.robot import models
from kpioed_drake.tracker.data import Measurements

SIGMA = 0.02
N_POSES = 200
GROSS_MM = 5.0


@pytest.fixture(scope="module")
def kr16():
    return models.load_robot("kr16")


@pytest.fixture(scope="module")
def clean(kr16):
    q = np.random.default_rng(31).uniform(kr16.lower, kr16.upper, size=(N_POSES, 6))
    table, _ = simulation.simulate(kr16, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=32))
    return table


def with_gross_errors(table, share: float, seed: int):
    """A copy of ``table`` with ``share`` of its rows moved by GROSS_MM in a random direction."""
    rng = np.random.default_rng(seed)
    bad = np.sort(rng.choice(len(table), size=int(round(share * len(table))), replace=False))
    u = rng.standard_normal((bad.size, 3))
    u *= GROSS_MM / np.linalg.norm(u, axis=1, keepdims=True)
    out = table.copy()
    out.loc[bad, ["x_mm", "y_mm", "z_mm"]] += u
    return out, bad


def test_robust_scale_factor_of_chi2_samples():
    rng = np.random.default_rng(5)
    t = rng.chisquare(3, size=20000)
    assert abs(robust_scale_factor(t) - 1.0) < 0.03
    assert abs(robust_scale_factor(9.0 * t) - 3.0) < 0.09
    assert np.isnan(robust_scale_factor(np.array([])))
    assert CHI2_3_MEDIAN == pytest.approx(chi2.ppf(0.5, 3))


@pytest.mark.parametrize("sigma", [SIGMA, SIGMA / 4])
def test_gross_errors_removed_at_any_sigma(kr16, clean, sigma):
    """3 % of 5 mm errors: exactly those rows removed, at the right sigma and one 4x too small."""
    table, bad = with_gross_errors(clean, 0.03, seed=33)
    rep = calibration.calibrate(
        kr16, Measurements.from_table(table, kr16), calibration.CalibrationOptions(sigma_mm=sigma)
    )
    assert sorted(rep.outliers) == bad.tolist()
    d = rep.to_dict()["robust"]
    assert d["n_removed"] == bad.size and d["n_downweighted"] == 0 and not d["capped"]
    assert sorted(r["row"] for r in d["reasons"]) == [int(i) + 2 for i in bad]
    assert all(r["statistic"] > r["threshold"] and r["residual_norm_mm"] > 2.0 for r in d["reasons"])
    assert 0.015 < d["scale_mm"] < 0.025  # the noise, whatever sigma was given
    assert d["sigma_effective_mm"] == pytest.approx(max(sigma, d["scale_mm"]))
    assert "robust scale of the residuals" in rep.summary()


@pytest.mark.parametrize("sigma", [SIGMA, SIGMA / 4])
def test_clean_data_keep_every_pose(kr16, clean, sigma):
    rep = calibration.calibrate(
        kr16, Measurements.from_table(clean, kr16), calibration.CalibrationOptions(sigma_mm=sigma)
    )
    assert rep.outliers == [] and rep.to_dict()["robust"]["n_removed"] == 0
    rest = [w for w in rep.warnings if "non-geometric rest" in w]
    assert bool(rest) == (sigma < SIGMA)  # said plainly only when the residuals exceed sigma


def test_heavy_tailed_data_refused_unless_forced(kr16, clean):
    """45 % of the rows off by 5 mm: no single bad points even at the robust scale."""
    table, _ = with_gross_errors(clean, 0.45, seed=34)
    data = Measurements.from_table(table, kr16)
    with pytest.raises(InputError, match=r"fail the outlier test even at the residuals' own scale"):
        calibration.calibrate(kr16, data, calibration.CalibrationOptions(sigma_mm=SIGMA))
    rep = calibration.calibrate(kr16, data, calibration.CalibrationOptions(sigma_mm=SIGMA, force=True))
    assert rep.outliers == [] and any(w.startswith("forced:") for w in rep.warnings)


def test_cap_reached_is_reported(kr16, clean):
    """More gross errors than the cap allows: the removal stops at the cap and says so."""
    table, bad = with_gross_errors(clean, 0.15, seed=35)
    rep = calibration.calibrate(
        kr16, Measurements.from_table(table, kr16), calibration.CalibrationOptions(sigma_mm=SIGMA)
    )
    assert len(rep.outliers) == int(0.1 * N_POSES) and set(rep.outliers) <= set(bad.tolist())
    assert rep.to_dict()["robust"]["capped"]
    assert any("outlier removal stopped" in w for w in rep.warnings)
