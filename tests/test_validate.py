"""``kpioed validate`` / ``api.validate``: prediction errors of a model on fresh data (issue 12)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.truth import SimulationOptions, simulate

KEYS = ("n_poses", "rms_mm", "mean_error_mm", "p95_error_mm", "max_error_mm", "errors_mm")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """kr16 with random geometric errors (one seed: one true robot and tracker), measured twice:
    60 poses to calibrate, 20 fresh ones to validate."""
    d = tmp_path_factory.mktemp("validate")
    robot = load_robot("kr16")
    rng = np.random.default_rng(7)
    q_cal = robot.q_work + rng.uniform(-0.6, 0.6, size=(60, 6))
    q_val = robot.q_work + rng.uniform(-0.5, 0.5, size=(20, 6))
    simulate(robot, q_cal, SimulationOptions(sigma_mm=0.02, seed=4))[0].to_csv(d / "cal.csv", index=False)
    simulate(robot, q_val, SimulationOptions(sigma_mm=0.02, seed=4))[0].to_csv(d / "val.csv", index=False)
    status = main(["calibrate", "--robot", "kr16", str(d / "cal.csv"), "--out", str(d / "cal.yaml")])
    assert status == 0
    return d


def test_calibrated_model_predicts_fresh_data(work, capsys):
    nominal = api.validate("kr16", work / "val.csv", json_path=work / "nominal.json")
    main(
        [
            "validate",
            "--robot",
            str(work / "cal.yaml"),
            str(work / "val.csv"),
            "--json",
            str(work / "cal.json"),
        ]
    )
    capsys.readouterr()
    rep_nom = json.loads((work / "nominal.json").read_text())
    rep_cal = json.loads((work / "cal.json").read_text())
    for rep in (rep_nom, rep_cal):
        assert all(k in rep for k in KEYS) and rep["n_poses"] == 20 and len(rep["errors_mm"]) == 20
        e = np.asarray(rep["errors_mm"])
        assert rep["mean_error_mm"] == pytest.approx(e.mean()) and rep["max_error_mm"] == pytest.approx(
            e.max()
        )
        assert e.min() <= rep["p95_error_mm"] <= e.max()
    assert rep_nom["mean_error_mm"] == pytest.approx(float(np.mean(nominal.errors_mm)))
    # calibration removes the geometric errors: the rest is noise (0.02 mm per coordinate)
    assert rep_cal["rms_mm"] < 0.04 < rep_nom["rms_mm"]
    assert rep_cal["mean_error_mm"] < rep_nom["mean_error_mm"] / 5


def test_keep_tracker_uses_the_calibrated_tracker_frame(work):
    """The calibrated model file carries the tracker pose: kept, it predicts like re-registered."""
    robot = load_robot(str(work / "cal.yaml"))
    assert robot.X_WT is not None and robot.p_FQ is not None
    reg = api.validate(str(work / "cal.yaml"), work / "val.csv")
    kept = api.validate(str(work / "cal.yaml"), work / "val.csv", keep_tracker=True)
    assert not kept.registered and reg.registered
    assert np.mean(kept.errors_mm) < 0.06
    assert np.mean(reg.errors_mm) <= np.mean(kept.errors_mm) + 1e-12  # registration is the optimum
    # the nominal model's tracker (the cell's) is far from this data set's: kept, it fails
    nominal_kept = api.validate("kr16", work / "val.csv", keep_tracker=True)
    assert np.mean(nominal_kept.errors_mm) > 10 * np.mean(kept.errors_mm)


def test_plots_and_stdout_json(work, capsys):
    status = main(
        ["validate", "--robot", "kr16", str(work / "val.csv"), "--plots", str(work / "plots"), "--json"]
    )
    out = capsys.readouterr().out
    assert status == 0 and json.loads(out)["n_poses"] == 20
    assert (work / "plots" / "validation_errors.png").stat().st_size > 1000


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"keep_tracker": "yes"}, "keep_tracker"),
        ({"json_path": "VAL"}, "val.csv"),
        ({"data_format": "missing-format.yaml"}, "missing-format.yaml: file not found"),
    ],
)
def test_api_validate_refuses_bad_arguments(work, kwargs, needle):
    if kwargs.get("json_path") == "VAL":
        kwargs = {"json_path": work / "val.csv"}
    before = (work / "val.csv").read_bytes()
    with pytest.raises(InputError, match=needle):
        api.validate("kr16", work / "val.csv", **kwargs)
    assert (work / "val.csv").read_bytes() == before


def test_cli_validate_bad_data_exits_2_and_writes_nothing(work, tmp_path, capsys):
    text = (work / "val.csv").read_text().replace("x_mm", "x_mn", 1)
    (tmp_path / "bad.csv").write_text(text)
    status = main(
        ["validate", "--robot", "kr16", str(tmp_path / "bad.csv"), "--json", str(tmp_path / "o.json")]
    )
    err = capsys.readouterr().err
    assert status == 2 and "bad.csv" in err and "x_mm" in err
    assert not (tmp_path / "o.json").exists()
