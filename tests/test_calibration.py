"""Calibration from measured data (kpioed_drake.calibration, simulation, cli calibrate/simulate)."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from kpioed_drake import calibration, simulation
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot import models
from kpioed_drake.tracker import measurement
from kpioed_drake.tracker.data import Measurements, read_measurements

SIGMA = 0.02


@pytest.fixture(scope="module")
def robot():
    return models.load_robot("kr16")


@pytest.fixture(scope="module")
def design(robot):
    rng = np.random.default_rng(20240601)
    return rng.uniform(robot.lower, robot.upper, size=(60, 6))


def simulated(robot, q, seed, sigma=SIGMA):
    table, truth = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=sigma, seed=seed))
    return table, truth


def calibrate_cli(data, out, js, plots):
    """``kpioed calibrate`` of kr16 on ``data``, writing the model, the JSON report and the plots."""
    args = ["--out", str(out), "--json", str(js), "--plots", str(plots)]
    return main(["calibrate", "--robot", "kr16", str(data), *args])


def z_scores(report, truth_model):
    """(27,) (estimate - truth) / reported std; the tracker rotation as a rotation vector."""
    res = report.result
    free = res.free
    z = (res.model.p[free] - truth_model.p[free]) / res.std
    rot = Rotation.from_matrix(res.model.R_WT.T @ truth_model.R_WT).as_rotvec()
    r = res.model.layout.free_tracker_rotation
    z[r] = rot / res.std[r]
    return z


def kpi_distance2(report, truth_model):
    s_true = measurement.kpi_jacobian(truth_model, report.q_work)[0]
    d = report.kpi - s_true
    return float(d @ np.linalg.solve(report.kpi_cov, d))


# ----------------------------------------------------------------------------------------------
# simulation
# ----------------------------------------------------------------------------------------------
def test_simulation_table_and_truth(robot, design):
    table, truth = simulated(robot, design, seed=5)
    assert list(table.columns) == [f"q{i}_deg" for i in range(1, 7)] + [
        "x_mm",
        "y_mm",
        "z_mm",
        "temperature_C",
        "time_s",
    ]
    assert_allclose(np.deg2rad(table[[f"q{i}_deg" for i in range(1, 7)]].to_numpy()), design, atol=1e-9)
    assert_allclose(np.diff(table["time_s"]), 30.0)
    assert np.all(np.abs(table["temperature_C"] - 20.0) < 3.0)
    model = truth["model"]
    nominal = problem.make_problem(robot).model
    lay = model.layout
    fixed = [lay.names.index(n) for n in measurement.FIXED_NAMES]
    assert_allclose(model.p[fixed], nominal.p[fixed], atol=0)
    dev = (model.p - nominal.p)[:24]
    dev_len = dev[~lay.is_angle[:24]]
    dev_ang = np.rad2deg(dev[lay.is_angle[:24]])
    assert 0.1 < np.std(dev_len[dev_len != 0]) < 1.5  # SPEC size 0.5 mm
    assert 0.01 < np.std(dev_ang[dev_ang != 0]) < 0.15  # SPEC size 0.05 deg
    assert_allclose(model.R_WT @ model.R_WT.T, np.eye(3), atol=1e-12)
    # noise free the table is exactly the model response (up to the 1e-6 mm rounding of the file)
    t0, tr0 = simulation.simulate(robot, design, simulation.SimulationOptions(sigma_mm=0.0, seed=5))
    eta = t0[["x_mm", "y_mm", "z_mm"]].to_numpy()
    assert_allclose(eta, measurement.measure(tr0["model"], design), atol=1e-6)


def test_noise_free_nominal_robot_calibrates_to_nominal(robot, design):
    table, truth = simulation.simulate(
        robot, design, simulation.SimulationOptions(sigma_mm=0.0, seed=1, geometric_errors=False)
    )
    rep = calibration.calibrate(robot, Measurements.from_table(table, robot))
    joint_ref = np.r_[rep.result.free[:18], 30, 31, 32]
    assert_allclose(rep.model.p[joint_ref], rep.nominal.p[joint_ref], atol=1e-7)
    assert_allclose(rep.kpi, rep.kpi_nominal, atol=1e-7)
    assert rep.rms_residual_mm < 1e-8


# ----------------------------------------------------------------------------------------------
# recovery, outliers, goodness of fit
# ----------------------------------------------------------------------------------------------
def test_recovers_parameters_and_kpi_with_an_outlier(robot, design, tmp_path):
    table, truth = simulated(robot, design, seed=11)
    k_bad = 16  # data row 17 = file row 18
    table.loc[k_bad, "y_mm"] += 0.5  # 25 sigma
    path = tmp_path / "data.csv"
    path.write_text(simulation.table_csv_text(table))
    data = read_measurements(path, robot)
    rep = calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=SIGMA))
    assert rep.result.converged
    assert rep.outliers == [k_bad]
    assert rep.outlier_rows == [k_bad + 2]
    assert not rep.used[k_bad]
    z = z_scores(rep, truth["model"])
    print("max |z| with outlier:", np.max(np.abs(z)))
    assert np.max(np.abs(z)) < 4.0, z  # 27 N(0,1) deviates
    assert kpi_distance2(rep, truth["model"]) < chi2.ppf(0.999, 3)
    # and the outlier is what it is: its prediction error is huge
    assert rep.normalized[k_bad] > 100.0
    d = rep.to_dict()
    assert d["n_outliers"] == 1 and d["outlier_rows"] == [18]
    # without the outlier test the estimate is visibly worse
    rep0 = calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=SIGMA, outlier_alpha=0))
    assert rep0.chi2_per_dof > 3.0
    assert rep0.outliers == []


def test_chi2_per_dof_near_one_on_clean_data(robot, design):
    table, truth = simulated(robot, design, seed=12)
    rep = calibration.calibrate(
        robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=SIGMA)
    )
    dof = rep.dof
    assert dof == 3 * 60 - 27
    lo, hi = chi2.ppf(0.0005, dof) / dof, chi2.ppf(0.9995, dof) / dof
    print(f"chi2/dof = {rep.chi2_per_dof:.4f} (99.9 % interval {lo:.3f}..{hi:.3f}), p = {rep.p_value:.3f}")
    assert lo < rep.chi2_per_dof < hi
    assert rep.outliers == []
    assert rep.warnings == []
    assert 0.015 < rep.rms_residual_mm < 0.025
    z = z_scores(rep, truth["model"])
    assert np.max(np.abs(z)) < 4.0
    # sigma given 4x too small: the outlier test runs at the residuals' robust scale (about 0.02 mm),
    # so no pose is removed; the warnings say so, and the a-posteriori standard deviations
    # (a-priori x sqrt(chi2/dof)) recover those of the right sigma
    data = Measurements.from_table(table, robot)
    rep2 = calibration.calibrate(robot, data, calibration.CalibrationOptions(sigma_mm=0.005))
    assert 10.0 < rep2.chi2_per_dof < 25.0
    assert rep2.outliers == [] and rep2.to_dict()["robust"]["n_removed"] == 0
    assert 0.015 < rep2.to_dict()["robust"]["scale_mm"] < 0.025
    assert any("larger than a noise" in w for w in rep2.warnings)
    assert any("non-geometric rest, a-posteriori sigmas used" in w for w in rep2.warnings)
    post = np.array([p["std_aposteriori"] for p in rep2.parameter_table() if p["estimated"]])
    right = np.array([p["std"] for p in rep.parameter_table() if p["estimated"]])
    assert_allclose(post, right * np.sqrt(rep.chi2_per_dof), rtol=1e-6)  # both: the data's own scale
    assert "a-posteriori" in rep2.summary()


@pytest.mark.slow
def test_monte_carlo_kpi_coverage(robot, design):
    """Coverage of the reported 95 % KPI ellipsoid over 200 seeds (new truth and noise each).

    Binomial: with N = 200 the coverage has standard deviation sqrt(0.95 * 0.05 / 200) = 0.0154;
    we accept 0.95 +- 3 sd = [0.904, 0.996]. The mean squared Mahalanobis distance must be 3 within
    4 standard errors (sd of chi^2(3) = sqrt(6)).
    """
    N = 200
    q95 = chi2.ppf(0.95, 3)
    d2 = np.empty(N)
    for seed in range(N):
        table, truth = simulated(robot, design, seed=1000 + seed)
        rep = calibration.calibrate(
            robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=SIGMA)
        )
        d2[seed] = kpi_distance2(rep, truth["model"])
    coverage = np.mean(d2 <= q95)
    print(f"KPI 95 % coverage {coverage:.3f}, mean d2 {d2.mean():.3f}")
    assert abs(coverage - 0.95) <= 3.0 * np.sqrt(0.95 * 0.05 / N)
    assert abs(d2.mean() - 3.0) < 4.0 * np.sqrt(6.0 / N)


# ----------------------------------------------------------------------------------------------
# outputs
# ----------------------------------------------------------------------------------------------
def test_calibrate_cli_outputs(robot, design, tmp_path, capsys):
    table, truth = simulated(robot, design, seed=21)
    table.loc[3, "x_mm"] -= 1.0
    data = tmp_path / "data.csv"
    data.write_text(simulation.table_csv_text(table))
    out, js, plots = tmp_path / "cal.yaml", tmp_path / "rep.json", tmp_path / "plots"
    rc = calibrate_cli(data, out, js, plots)
    assert rc == 0
    text = capsys.readouterr().out
    assert "chi2/dof" in text and "rows 5" in text
    rep = json.loads(js.read_text())
    for key in (
        "rms_residual_mm",
        "chi2_per_dof",
        "p_value",
        "n_outliers",
        "outlier_rows",
        "kpi_mm",
        "kpi_cov_mm2",
        "parameters",
        "correlations",
        "row_convention",
    ):
        assert key in rep
    assert rep["outlier_rows"] == [5] and rep["n_outliers"] == 1
    assert len(rep["parameters"]) == 33
    assert {"name", "value", "nominal", "std", "unit"} <= set(rep["parameters"][0])
    a1 = next(p for p in rep["parameters"] if p["name"] == "alpha1")
    assert a1["unit"] == "deg" and a1["std"] > 0
    d1 = next(p for p in rep["parameters"] if p["name"] == "d1")
    assert d1["std"] == 0.0 and not d1["estimated"]
    assert np.asarray(rep["kpi_cov_mm2"]).shape == (3, 3)
    assert sorted(p.name for p in plots.iterdir()) == ["residuals_per_pose.png", "residuals_vs_joints.png"]
    # the calibrated model file is a robot model
    cal = models.load_robot(str(out))
    true_geom = truth["model"].geometry
    free24 = [i for i in range(24) if i in set(truth["model"].layout.free.tolist())]
    est = np.asarray([p["value"] for p in rep["parameters"]][:24])
    lay = truth["model"].layout
    est_int = np.where(lay.is_angle[:24], np.deg2rad(est), est)
    assert_allclose(cal.geometry.ravel(), est_int, atol=1e-9)
    nominal = models.load_robot("kr16")
    assert_allclose(cal.masses, nominal.masses)
    assert len(cal.capsules) == len(nominal.capsules)
    assert_allclose(cal.q_work, nominal.q_work)
    assert np.max(np.abs(cal.geometry.ravel()[free24] - true_geom.ravel()[free24])) < 0.05
    # usable by the other commands (kpi at q_work of the calibrated robot = the reported KPI)
    prob = problem.make_problem(str(out), sigma_mm=SIGMA)
    reflector = np.asarray(rep["reflector"]["p_FQ_mm"])
    s = measurement.kpi_jacobian(prob.model.with_params(np.r_[prob.model.p[:30], reflector]), cal.q_work)[0]
    assert_allclose(s, rep["kpi_mm"], atol=1e-8)
    # JSON to stdout
    assert main(["calibrate", "--robot", "kr16", str(data), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_outliers"] == 1


def test_simulate_cli_then_calibrate(robot, design, tmp_path, capsys):
    dpath = tmp_path / "design.csv"
    write_design(dpath, design)
    data, truth_path = tmp_path / "data.csv", tmp_path / "truth.json"
    args = ["simulate", "--robot", "kr16", "--design", str(dpath), "--seed", "4", "--out", str(data)]
    assert main([*args, "--truth", str(truth_path)]) == 0
    truth = json.loads(truth_path.read_text())
    assert len(truth["parameters"]) == 33 and truth["effects"] == []
    m = read_measurements(data, robot)
    assert m.n == 60 and m.temperature_C is not None and m.time_s is not None and m.payload_kg is None
    rep = calibration.calibrate(robot, m)
    true_p = np.array([p["value"] for p in truth["parameters"]])
    est = rep.parameter_table()
    for i in list(range(24)) + [30, 31, 32]:
        if est[i]["estimated"]:
            assert abs(est[i]["value"] - true_p[i]) < 4.0 * est[i]["std"], est[i]
    # an effect that another module simulates
    data2 = tmp_path / "data2.csv"
    args2 = ["simulate", "--robot", "kr16", "--design", str(dpath), "--out", str(data2)]
    assert main([*args2, "--effect", "gear_cyclic:4:2=0.01,-0.005", "--payload-kg", "5"]) == 0
    assert "payload_kg" in data2.read_text().splitlines()[0]
    # bad effect: exit 2, nothing written
    data3 = tmp_path / "data3.csv"
    args3 = ["simulate", "--robot", "kr16", "--design", str(dpath), "--out", str(data3)]
    assert main([*args3, "--effect", "no_such_effect"]) == 2
    assert not data3.exists()
    assert "kpioed: error:" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# bad input
# ----------------------------------------------------------------------------------------------
def _good_table(robot, design, n=12):
    table, _ = simulation.simulate(robot, design[:n], simulation.SimulationOptions(sigma_mm=SIGMA, seed=3))
    return simulation.table_csv_text(table)


def _edit(text, fn):
    lines = text.splitlines()
    fn(lines)
    return "\n".join(lines) + "\n"


def _set_cell(lines, row, column, value):
    header = lines[0].split(",")
    cells = lines[row - 1].split(",")
    cells[header.index(column)] = value
    lines[row - 1] = ",".join(cells)


def _bad_cases(robot, design):
    good = _good_table(robot, design)
    rad_lines = good.splitlines()
    cases = {
        "missing_column": (
            _edit(good, lambda L: L.__setitem__(slice(None), [",".join(r.split(",")[:8]) for r in L])),
            ["row 1", "missing column 'z_mm'"],
        ),
        "misspelled_column": (
            _edit(good, lambda L: L.__setitem__(0, L[0].replace("q3_deg", "q3_dg"))),
            ["row 1", "'q3_deg'", "found 'q3_dg'"],
        ),
        "misspelled_optional_column": (
            _edit(good, lambda L: L.__setitem__(0, L[0].replace("temperature_C", "temperatur_C"))),
            ["row 1", "'temperatur_C'", "did you mean 'temperature_C'"],
        ),
        "text_in_number": (
            _edit(good, lambda L: _set_cell(L, 5, "x_mm", "abc")),
            ["row 5", "'x_mm'", "'abc'"],
        ),
        "nan": (
            _edit(good, lambda L: _set_cell(L, 7, "y_mm", "nan")),
            ["row 7", "'y_mm'", "not a finite number"],
        ),
        "empty_cell": (_edit(good, lambda L: _set_cell(L, 3, "q5_deg", "")), ["row 3", "'q5_deg'"]),
        "duplicated_header": (
            _edit(good, lambda L: L.__setitem__(0, L[0].replace("time_s", "x_mm"))),
            ["row 1", "'x_mm' appears more than once"],
        ),
        "radians": (
            "\n".join(
                [rad_lines[0]]
                + [
                    ",".join([f"{np.deg2rad(float(v)):.6f}" for v in r.split(",")[:6]] + r.split(",")[6:])
                    for r in rad_lines[1:]
                ]
            )
            + "\n",
            ["radians", "q*_deg"],
        ),
        "outside_limits": (
            _edit(good, lambda L: _set_cell(L, 4, "q2_deg", "50.0")),
            ["row 4", "'q2_deg'", "outside"],
        ),
        "too_few_rows": (
            _edit(good, lambda L: L.__delitem__(slice(9, None))),
            ["8 rows", "at least 9 rows"],
        ),
        "empty_file": ("", ["empty"]),
        "header_only": (good.splitlines()[0] + "\n", ["no data rows"]),
        "ragged_row": (_edit(good, lambda L: L.__setitem__(2, L[2] + ",1.0")), ["row 3", "fields"]),
        "negative_payload": (
            _edit(
                good,
                lambda L: L.__setitem__(
                    slice(None),
                    [L[0] + ",payload_kg"]
                    + [r + (",-1" if k == 5 else ",0") for k, r in enumerate(L[1:], 1)],
                ),
            ),
            ["row 6", "'payload_kg'"],
        ),
    }
    return cases


def test_bad_input_library_errors(robot, design, tmp_path):
    for name, (text, needles) in _bad_cases(robot, design).items():
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        with pytest.raises(InputError) as exc:
            read_measurements(path, robot)
        msg = str(exc.value)
        assert str(path) in msg, (name, msg)
        for needle in needles:
            assert needle in msg, (name, needle, msg)
    with pytest.raises(InputError, match="file not found"):
        read_measurements(tmp_path / "nope.csv", robot)


def test_bad_input_cli_exit_2_without_output(robot, design, tmp_path, capsys):
    for name, (text, needles) in _bad_cases(robot, design).items():
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        out, js, plots = tmp_path / f"{name}.yaml", tmp_path / f"{name}.json", tmp_path / f"{name}_plots"
        rc = calibrate_cli(path, out, js, plots)
        err = capsys.readouterr().err
        assert rc == 2, name
        assert err.startswith("kpioed: error:") and needles[0] in err, (name, err)
        assert not out.exists() and not js.exists() and not plots.exists(), name
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], name  # no temporary leftovers
    # bad --q-work and --sigma-mm
    good = tmp_path / "good.csv"
    good.write_text(_good_table(robot, design))
    out = tmp_path / "never.yaml"
    assert main(["calibrate", "--robot", "kr16", str(good), "--q-work", "0,0,0,0,0", "--out", str(out)]) == 2
    assert main(["calibrate", "--robot", "kr16", str(good), "--sigma-mm", "-1", "--out", str(out)]) == 2
    assert not out.exists()
    capsys.readouterr()
