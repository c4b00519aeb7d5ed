"""The independent UR10 6-DoF baseline (studies/ur10_6dof_baseline.py): on a simulated data set
(the script's own nominal model + known parameter errors + the real data's per-row noise, seeded)
its fit recovers the true parameters within 5 standard deviations of its own covariance, and its
orientation residual's analytic Jacobian agrees with central differences."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "ur10-laser-tracker"
pytestmark = pytest.mark.skipif(not (DATA / "train_6dof.csv").exists(), reason="UR10 data absent")


def _script():
    spec = importlib.util.spec_from_file_location(
        "ur10_6dof_baseline", ROOT / "studies" / "ur10_6dof_baseline.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


b = _script()


def _truth(rng):
    """Nominal + known errors on the free parameters; tracker and probe frames put in T0, R0."""
    x = b.nominal_params()
    for i in range(1, 7):
        for n, s in (
            (f"theta{i}", 1e-3),
            (f"d{i}", 0.5),
            (f"a{i}", 0.5),
            (f"alpha{i}", 1e-3),
            (f"beta{i}", 5e-4),
        ):
            if n in b.IDX and n not in b.GAUGE:
                x[b.IDX[n]] += rng.normal(0, s)
    x[[b.IDX["p_x"], b.IDX["p_y"], b.IDX["p_z"]]] = (0.3, 0.6, 93.0)
    fr = b.Frames()
    fr.T0[:3, :3] = Rotation.from_euler("XYZ", (4.0, -3.0, 100.0), degrees=True).as_matrix()
    fr.T0[:3, 3] = (300.0, -3000.0, -250.0)
    fr.R0[:3, :3] = Rotation.from_euler("XYZ", (0.2, -0.1, -90.0), degrees=True).as_matrix()
    return x, fr


def _simulate(x, fr, rng):
    """The train poses and per-row stds, measurements from the true model plus that noise (the
    orientation noise on the intrinsic XYZ Euler angles, as the data's stds describe it)."""
    df = pd.read_csv(DATA / "train_6dof.csv")
    q = np.radians(df[[f"q{i}_deg" for i in range(1, 7)]].to_numpy())
    p, R = b.forward(x, q, fr)
    sp = df[["std_x_mm", "std_y_mm", "std_z_mm"]].to_numpy()
    se = df[["std_rx_deg", "std_ry_deg", "std_rz_deg"]].to_numpy()
    df[["x_mm", "y_mm", "z_mm"]] = p + rng.normal(0, 1, p.shape) * sp
    eul = Rotation.from_matrix(R).as_euler("XYZ", degrees=True)
    df[["rx_deg", "ry_deg", "rz_deg"]] = eul + rng.normal(0, 1, eul.shape) * se
    return b.make_data(df)


def _in_fit_frames(x_true, fr_true, fit):
    """The true model in the fit's parameterization (its closed-form T0, R0)."""
    x = x_true.copy()
    R0f, t0f = fit.fr.T0[:3, :3], fit.fr.T0[:3, 3]
    Rt, tt = fr_true.T0[:3, :3], fr_true.T0[:3, 3]
    x[[b.IDX[f"w_{c}"] for c in "xyz"]] = Rotation.from_matrix(Rt @ R0f.T).as_euler("XYZ")
    x[[b.IDX[f"t_{c}"] for c in "xyz"]] = tt - Rt @ R0f.T @ t0f
    x[[b.IDX[f"r_{c}"] for c in "xyz"]] = Rotation.from_matrix(
        fr_true.R0[:3, :3] @ fit.fr.R0[:3, :3].T
    ).as_euler("XYZ")
    return x


def test_simulated_fit_recovers_the_true_parameters():
    rng = np.random.default_rng(44)
    x_true, fr_true = _truth(rng)
    d = _simulate(x_true, fr_true, rng)
    fit = b.calibrate(d, b.Weights())
    assert fit.rank_free == fit.free.sum() == 30 and fit.rank_all == 30
    m = len(b.residuals(fit.x, d, fit.fr, fit.w))
    dof = m - 30
    assert abs(fit.cost / dof - 1) < 4 * np.sqrt(2 / dof)  # chi-square: whitened by the true noise
    truth = _in_fit_frames(x_true, fr_true, fit)
    sd = np.sqrt(np.diag(fit.cov))[fit.free]
    assert np.all(np.abs(fit.x[fit.free] - truth[fit.free]) <= 5 * sd), np.array(b.NAMES)[fit.free][
        np.abs(fit.x[fit.free] - truth[fit.free]) > 5 * sd
    ]
    assert_allclose(fit.x[~fit.free], truth[~fit.free])  # the gauge stays at its (true) nominal


def test_orientation_jacobian_matches_finite_differences():
    rng = np.random.default_rng(7)
    x_true, fr_true = _truth(rng)
    d = _simulate(x_true, fr_true, rng)
    x = x_true + rng.normal(0, 1e-2, x_true.shape)
    fr_true.R0[:3, :3] = fr_true.R0[:3, :3] @ Rotation.from_rotvec((0.4, -0.3, 0.5)).as_matrix()
    n = 3 * len(d.q)
    assert b.errors(x, fr_true, d)[1].min() > 20  # rotation residuals far from 0: Jr^-1 matters
    for w in (b.Weights(), b.Weights(fixed=(0.3, 1e-3))):
        r, J = b.residuals(x, d, fr_true, w, jac=True)
        h = 1e-6
        Jn = np.empty((len(r) - n, len(x)))
        for k in range(len(x)):
            e = np.zeros_like(x)
            e[k] = h
            Jn[:, k] = (b.residuals(x + e, d, fr_true, w)[n:] - b.residuals(x - e, d, fr_true, w)[n:]) / (
                2 * h
            )
        assert_allclose(J[n:], Jn, rtol=0, atol=1e-6 * np.abs(J[n:]).max())


def test_real_data_reproduces_the_readme_level():
    train, test = b.read(DATA / "train_6dof.csv"), b.read(DATA / "test_6dof.csv")
    fit = b.calibrate(train, b.Weights())
    ep, er, _, _ = b.errors(fit.x, fit.fr, test)
    assert fit.rank_all == fit.rank_free == 30
    assert ep.mean() < 0.5 and er.mean() < 0.06
