"""Extended models are models: ``calibrate --extend E --out`` writes the effects, every command
reading ``--robot MODEL`` uses them (validate predicts with them), bad entries name file and field."""

import json

import numpy as np
import pytest

from kpioed_drake import api
from kpioed_drake import effects as fx
from kpioed_drake.calibration.validate import predicted_world
from kpioed_drake.cli import main
from kpioed_drake.diagnosis import workflow
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.study.synthetic import random_poses
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model, reflector_world

SIGMA = 0.02


@pytest.fixture(scope="module")
def kr16_case(tmp_path_factory):
    """kr16 with a hidden joint_elasticity:2 (4e-7 rad/(N m)): 60 calibration poses and 40 fresh ones
    (the same true robot: seed 3)."""
    work = tmp_path_factory.mktemp("extmodels")
    robot = load_robot("kr16")
    for name, seed, n in (("d", 1, 60), ("f", 2, 40)):
        write_design(work / f"{name}.csv", random_poses(robot, n, np.random.default_rng(seed)))
        sim = ["simulate", "--robot", "kr16", "--design", str(work / f"{name}.csv"), "--seed", "3"]
        assert (
            main([*sim, "--effect", "joint_elasticity:2=4e-7", "--out", str(work / f"{name}_data.csv")]) == 0
        )
    return work


def test_extended_calibration_round_trips_and_validates_better(kr16_case):
    w = kr16_case
    rep = api.calibrate("kr16", w / "d_data.csv", extend=["joint_elasticity:2"], out=w / "ext.yaml")
    geo = api.calibrate("kr16", w / "d_data.csv", out=w / "geo.yaml")
    d = rep.to_dict()
    (row,) = d["effects"]
    assert row["name"] == "joint_elasticity:2" and row["unit"] == "rad/(N m)"
    assert d["identifiability"] and d["robust"]["scale_mm"] > 0 and d["chi2_per_dof"] < 1.3
    assert geo.chi2_per_dof > 3.0 and d["effects"] and not geo.to_dict()["effects"]
    # round trip: the written file's effects are the estimated values
    (back,) = fx.model_effects(load_robot(str(w / "ext.yaml")))
    (est,) = rep.effects
    np.testing.assert_allclose(back.values, est.values, rtol=1e-12)
    assert load_robot(str(w / "ext.yaml")).effects[0].std == pytest.approx(row["std"], rel=1e-12)
    # validation on fresh poses predicts with the effects; the extended model predicts better
    ext_v = api.validate(str(w / "ext.yaml"), w / "f_data.csv")
    geo_v = api.validate(str(w / "geo.yaml"), w / "f_data.csv")
    e, g = ext_v.to_dict()["rms_mm"], geo_v.to_dict()["rms_mm"]
    print("fresh RMS extended", e, "geometric", g)
    assert ext_v.effects == ("joint_elasticity:2",) and e < 0.7 * g and e < 4 * SIGMA


def test_cli_and_api_agree_and_json_has_effects(kr16_case, capsys):
    w = kr16_case
    args = ["calibrate", "--robot", "kr16", str(w / "d_data.csv"), "--extend", "joint_elasticity:2"]
    assert main([*args, "--json", "-"]) == 0
    cli = json.loads(capsys.readouterr().out)
    direct = api.calibrate("kr16", w / "d_data.csv", extend=["joint_elasticity:2"]).to_dict()
    assert cli["effects"][0]["values"] == pytest.approx(direct["effects"][0]["values"], rel=1e-12)
    assert main([*args, "--plots", str(w / "plots"), "--html", str(w / "p.html")]) == 0
    assert any((w / "plots").iterdir()) and (w / "p.html").is_file()


def test_bad_effect_entry_names_file_and_field(kr16_case, capsys):
    w = kr16_case
    text = (w / "ext.yaml").read_text() if (w / "ext.yaml").is_file() else None
    if text is None:
        api.calibrate("kr16", w / "d_data.csv", extend=["joint_elasticity:2"], out=w / "ext.yaml")
        text = (w / "ext.yaml").read_text()
    bad = w / "bad.yaml"
    bad.write_text(text.replace("name: joint_elasticity:2", "name: joint_elasticity:9"))
    with pytest.raises(InputError, match=r"bad.yaml: effects\[0\].name/values: .*joint must be 1..6"):
        fx.model_effects(load_robot(str(bad)))
    bad.write_text(text.replace("unit: rad/(N m)", "unit: deg"))
    assert main(["validate", "--robot", str(bad), str(w / "f_data.csv"), "--json", str(w / "v.json")]) == 2
    assert "effects[0].unit" in capsys.readouterr().err and not (w / "v.json").exists()
    bad.write_text(text.replace("values: [", "values: [.nan, "))
    assert main(["validate", "--robot", str(bad), str(w / "f_data.csv")]) == 2
    assert "effects[0].values" in capsys.readouterr().err


def test_any_joint_of_the_robot_and_a_urdf_sidecar(tmp_path, capsys):
    """lift7: ``--extend gear_cyclic:7:1`` (joint 7 of 7) is accepted, the sidecar carries it; joint
    8 is refused naming the effect, nothing written."""
    robot = load_robot("lift7")
    write_design(tmp_path / "d.csv", random_poses(robot, 60, np.random.default_rng(5)), robot=robot)
    sim = ["simulate", "--robot", "lift7", "--design", str(tmp_path / "d.csv"), "--seed", "2"]
    assert main([*sim, "--effect", "gear_cyclic:7:1=0.02,-0.01", "--out", str(tmp_path / "data.csv")]) == 0
    out = tmp_path / "cal.urdf"
    cal = ["calibrate", "--robot", "lift7", str(tmp_path / "data.csv")]
    assert main([*cal, "--extend", "gear_cyclic:8:1", "--out", str(out)]) == 2
    assert "1..7" in capsys.readouterr().err and not out.exists()
    assert main([*cal, "--extend", "gear_cyclic:7:1", "--out", str(out)]) == 0
    (eff,) = fx.model_effects(load_robot(str(out)))
    assert eff.name == "gear_cyclic:7:1"
    np.testing.assert_allclose(np.rad2deg(eff.values), [0.02, -0.01], atol=3e-3)


def test_diagnose_out_writes_the_extended_model_that_validates(kr16_case, capsys):
    """diagnose names joint_elasticity:2 and writes its extended model; on fresh poses that model's
    error is what diagnose's cross-validation reported (within 25 %) and below half the geometric one's."""
    w = kr16_case
    rep = api.diagnose("kr16", w / "d_data.csv", out=w / "diag.yaml", json_path=w / "diag.json")
    assert [c["effect"] for c in rep.causes] == ["joint_elasticity"]
    (eff,) = fx.model_effects(load_robot(str(w / "diag.yaml")))
    assert eff.name == "joint_elasticity:2"
    fresh = api.validate(str(w / "diag.yaml"), w / "f_data.csv").to_dict()["rms_mm"]
    api.calibrate("kr16", w / "d_data.csv", out=w / "geo2.yaml")
    geo = api.validate(str(w / "geo2.yaml"), w / "f_data.csv").to_dict()["rms_mm"]
    held_out = rep.extended["holdout_rms_mm"]
    print("diagnose held-out", held_out, "fresh extended", fresh, "fresh geometric", geo)
    assert abs(fresh - held_out) < 0.25 * held_out and fresh < 0.5 * geo  # measured 0.0203, 0.0224, 0.0670
    assert any("out: the model written" in n for n in json.loads((w / "diag.json").read_text())["notes"])
    # CLI: the same file, nothing written on a bad out suffix
    assert main(["diagnose", "--robot", "kr16", str(w / "d_data.csv"), "--out", str(w / "x.urdf")]) == 2
    assert "out" in capsys.readouterr().err and not (w / "x.urdf").exists()


def _ext_model(w):
    if not (w / "ext.yaml").is_file():
        api.calibrate("kr16", w / "d_data.csv", extend=["joint_elasticity:2"], out=w / "ext.yaml")
    return str(w / "ext.yaml")


def test_simulate_and_design_use_the_file_effects(kr16_case):
    """``--robot MODEL``: simulate's truth and evaluate/design's problem carry the file's effects."""
    path = _ext_model(kr16_case)
    robot = load_robot(path)
    (stored,) = fx.model_effects(robot)
    q = random_poses(robot, 20, np.random.default_rng(9))
    _, truth = simulate(robot, q, SimulationOptions(sigma_mm=0.0, geometric_errors=False))
    assert [e.name for e in truth["effects"]] == ["joint_elasticity:2"]
    np.testing.assert_allclose(truth["effects"][0].values, stored.values, rtol=1e-12)
    _, truth = simulate(robot, q, SimulationOptions(sigma_mm=0.0, effects=["joint_elasticity:2=1e-6"]))
    assert truth["effects"][0].values == pytest.approx((1e-6,))  # the given one replaces the file's
    prob = make_problem(path, sigma_mm=0.02)
    assert prob.param_names[-1] == "joint_elasticity:2.c" and prob.n_params == 28


def test_a_failing_picture_is_a_note_and_the_json_is_written(kr16_case, monkeypatch):
    def broken(report, folder):
        raise ValueError("no picture")

    monkeypatch.setattr(workflow, "write_plots", broken)
    w = kr16_case
    rep = workflow.diagnose_file("kr16", w / "d_data.csv", json_path=w / "pj.json", plots_dir=w / "pp")
    notes = json.loads((w / "pj.json").read_text())["notes"]
    assert any("plots: a picture could not be drawn (ValueError: no picture)" in n for n in notes)
    assert rep.causes and (w / "pp").is_dir()


def test_column_compliance_pictures(tmp_path):
    """lift7 with a hidden column_compliance:1: diagnose draws every picture (no plots note)."""
    robot = load_robot("lift7")
    write_design(tmp_path / "d.csv", random_poses(robot, 80, np.random.default_rng(1)), robot=robot)
    sim = ["simulate", "--robot", "lift7", "--design", str(tmp_path / "d.csv"), "--seed", "1"]
    assert main([*sim, "--effect", "column_compliance:1", "--out", str(tmp_path / "data.csv")]) == 0
    rep = workflow.diagnose_file("lift7", tmp_path / "data.csv", plots_dir=tmp_path / "p")
    assert [c["effect"] for c in rep.causes] == ["column_compliance"]
    assert {p.name for p in (tmp_path / "p").iterdir()} == {"residual_structure.png", "before_after.png"}
    assert not any(n.startswith("plots:") for n in rep.notes)


def test_validate_names_a_missing_condition_column():
    """A model with tracker_drift needs the time_s column to predict; its absence is named."""
    robot = load_robot("kr16")
    q = random_poses(robot, 12, np.random.default_rng(3))
    data = Measurements.from_arrays(q, np.zeros((12, 3)))
    model = nominal_model(robot, load_cell(robot=robot))
    with pytest.raises(InputError, match="tracker_drift needs the time_s column"):
        predicted_world(model, data, [fx.parse_effect("tracker_drift=0.01,0,0")])
    np.testing.assert_allclose(predicted_world(model, data), reflector_world(model, q), atol=0)


def test_diagnose_of_an_extended_model_keeps_its_effects_in_the_model_it_writes(kr16_case, tmp_path):
    """Data without the effect: ``diagnose --robot EXT --out`` does not name it, says so, and the model
    it writes still carries the file's effect (nothing of the user's model is lost)."""
    w = kr16_case
    api.calibrate("kr16", w / "d_data.csv", extend=["joint_elasticity:2"], out=tmp_path / "ext.yaml")
    clean = tmp_path / "clean.csv"
    sim = ["simulate", "--robot", "kr16", "--design", str(w / "d.csv"), "--seed", "5", "--out", str(clean)]
    assert main(sim) == 0
    report = api.diagnose(str(tmp_path / "ext.yaml"), clean, sigma_mm=SIGMA, out=tmp_path / "out.yaml")
    assert "joint_elasticity:2" not in [c.effect.name for c in report.cause_records]
    assert any("model file's effects (joint_elasticity:2)" in n for n in report.notes)
    (kept,) = fx.model_effects(load_robot(str(tmp_path / "out.yaml")))
    assert kept.name == "joint_elasticity:2"
