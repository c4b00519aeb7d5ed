"""Model extensions used by evaluate, design and calibrate (``--extend``)."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.cli import main
from kpioed_drake.design import DesignObjective
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.study.synthetic import random_poses
from kpioed_drake.tracker.data import as_measurements

EXT = ["joint_elasticity:2", "gear_cyclic:4:2"]


def test_extended_problem_adds_columns_and_variance():
    base, ext = make_problem("kr16"), make_problem("kr16", extend=EXT)
    assert ext.n_params == 30 and ext.param_names[-1] == "gear_cyclic:4:2.b"
    q = random_poses(ext.robot, 40, np.random.default_rng(1))
    F0, F1 = base.F1(q), ext.F1(q)
    assert F1.shape == (120, 30)
    assert_allclose(F1[:, :27], F0, rtol=0, atol=0)
    assert ext.Js().shape == (3, 30)
    # estimating more parameters from the same data cannot make the TCP more precise
    assert ext.criteria(q)["kpi_avg_var_mm2"] >= base.criteria(q)["kpi_avg_var_mm2"] * (1 - 1e-12)


@pytest.mark.parametrize("criterion", ["kpi", "param"])
def test_extended_objective_gradient_matches_finite_differences(criterion):
    prob = make_problem("kr16", extend=EXT)
    q = random_poses(prob.robot, 30, np.random.default_rng(2))
    obj = DesignObjective(prob, criterion)
    v, g = obj.value_and_grad(q)
    rng = np.random.default_rng(3)
    eps = 1e-6
    for k, j in zip(rng.integers(0, 30, 8), rng.integers(0, 6, 8), strict=True):
        qp, qm = q.copy(), q.copy()
        qp[k, j] += eps
        qm[k, j] -= eps
        fd = (obj.value(qp) - obj.value(qm)) / (2 * eps)
        assert_allclose(g[k, j], fd, rtol=1e-4, atol=1e-8 * abs(v))


def test_extend_rejects_effects_that_need_per_pose_inputs():
    with pytest.raises(InputError, match="thermal_expansion"):
        make_problem("kr16", extend=["thermal_expansion"])
    with pytest.raises(InputError, match="given twice"):
        make_problem("kr16", extend=["joint_elasticity:2", "joint_elasticity:2"])


@pytest.mark.slow
def test_design_cli_with_extension(tmp_path, capsys):
    """design and evaluate take --extend (28 parameters); the certificate is tests/test_design_start.py's."""
    out, js = tmp_path / "d.csv", tmp_path / "d.json"
    ext = ["--robot", "kr16", "--extend", "joint_elasticity:2", "--no-certify"]
    code = main(["design", *ext, "--criterion", "kpi", "--n", "20", "--out", str(out), "--json", str(js)])
    assert code == 0
    capsys.readouterr()
    code = main(["evaluate", *ext, "--design", str(out), "--json", "-"])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["n_params"] == 28 and d["extensions"] == ["joint_elasticity:2"]
    assert d["feasible"] and json.loads(js.read_text())["feasible"]


def test_calibrate_with_extension_recovers_elasticity(tmp_path):
    robot = load_robot("kr16")
    q = random_poses(robot, 80, np.random.default_rng(4))
    df, truth = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=5, effects=["joint_elasticity:3"]))
    path = tmp_path / "data.csv"
    df.to_csv(path, index=False)
    rep = calibrate(
        robot,
        as_measurements(str(path), robot),
        CalibrationOptions(effects=["joint_elasticity:3"], sigma_mm=0.02),
    ).to_dict()
    (hidden,) = truth["effects"]
    (e,) = rep["effects"]
    assert e["effect"] == "joint_elasticity" and e["joint"] == 3
    assert rep["chi2_per_dof"] < 1.5
    true_value = hidden.display_values()[0]
    assert abs(e["value"] - true_value) < 4 * e["std"][0], (e, true_value)


def test_calibrate_cli_extend(tmp_path, capsys):
    robot = load_robot("kr16")
    q = random_poses(robot, 60, np.random.default_rng(6))
    design = tmp_path / "d.csv"
    write_design(design, q)
    data = tmp_path / "data.csv"
    assert (
        main(
            [
                "simulate",
                "--robot",
                "kr16",
                "--design",
                str(design),
                "--effect",
                "joint_elasticity:2",
                "--seed",
                "1",
                "--out",
                str(data),
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert (
        main(["calibrate", "--robot", "kr16", str(data), "--extend", "joint_elasticity:2", "--json", "-"])
        == 0
    )
    d = json.loads(capsys.readouterr().out)
    assert d["effects"][0]["effect"] == "joint_elasticity" and d["chi2_per_dof"] < 1.5
