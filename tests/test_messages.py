"""Messages name the API's parameters; the command line shows them as the running command's options.

``InputError(fields=...)`` carries the parameters a message names, :func:`kpioed_drake.cli.main`
replaces them by the options of the command's parser; text that is not an error names them through
:func:`kpioed_drake.errors.param`. One check of the noise argument serves every command.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from pathlib import Path

import numpy as np
import pytest

from kpioed_drake import api, cli
from kpioed_drake.calibration import CalibrationOptions, calibrate
from kpioed_drake.cli import COMMANDS, build_parser, main, option_names
from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.errors import InputError, check_sigma, name_fields, param, param_names
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import Measurements

REPO = Path(__file__).resolve().parents[1]


def _commands() -> dict:
    """Each subcommand's parser by name."""
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a.choices, dict)]
    return dict(sub.choices)


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


@pytest.fixture(scope="module")
def data(tmp_path_factory, kr16):
    """A measurement CSV of kr16 (60 poses of the study's KPI design) with noise 0.002 mm."""
    design = np.loadtxt(REPO / "studies/results/designs/kr16_kpi_ca.csv", delimiter=",", skiprows=1)
    table, _ = simulate(kr16, np.deg2rad(design), SimulationOptions(sigma_mm=0.002, seed=3))
    path = tmp_path_factory.mktemp("messages") / "data.csv"
    table.to_csv(path, index=False)
    return path


def test_cli_names_the_option_and_the_api_the_parameter(data, capsys):
    assert main(["calibrate", "--robot", "kr16", str(data), "--sigma-mm", "-1"]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("kpioed:")]
    assert lines == ["kpioed: error: --sigma-mm must be a positive number of millimetres, got -1.0"]
    with pytest.raises(InputError, match=r"^sigma_mm must be a positive number of millimetres") as err:
        api.calibrate("kr16", data, sigma_mm=-1)
    assert err.value.fields == ("sigma_mm",)
    assert "--" not in str(err.value)


def test_a_refusal_names_force_as_the_option_or_the_parameter(tmp_path, data, capsys):
    """The plausibility refusal: ``(use --force ...)`` on the command line, ``force`` in Python."""
    metres = tmp_path / "metres.csv"
    lines = data.read_text().splitlines()
    rows = [r.split(",") for r in lines[1:]]
    for r in rows:
        r[6:9] = [f"{float(x) * 1e-3:.9f}" for x in r[6:9]]
    metres.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    assert main(["calibrate", "--robot", "kr16", str(metres)]) == 2
    assert "(use --force to go on anyway)" in capsys.readouterr().err
    with pytest.raises(InputError, match=r"\(use force to go on anyway\)") as err:
        api.calibrate("kr16", metres)
    assert err.value.fields == ("force",)


def test_a_warning_names_the_option_only_on_the_command_line(data, capsys):
    """Data with noise 0.002 mm calibrated at sigma 0.02 mm: the chi-square warning points at the
    noise argument, as ``--sigma-mm`` in the command's summary and ``sigma_mm`` in the API's report."""
    assert main(["calibrate", "--robot", "kr16", str(data)]) == 0
    out = capsys.readouterr().out
    assert "; --sigma-mm is probably too large" in out and "sigma_mm" not in out
    report = api.calibrate("kr16", data)
    assert any("; sigma_mm is probably too large" in w for w in report.warnings)
    assert not any("--" in w for w in report.warnings)


def test_option_names_of_a_command():
    commands = _commands()
    design, calibrate_ = option_names(commands["design"]), option_names(commands["calibrate"])
    assert design["sigma_mm"] == "--sigma-mm" and design["n"] == "--n"
    assert design["target_var_mm2"] == "--target-var" and design["q_work_deg"] == "--q-work"
    assert design["certify"] == "--certify"  # not --no-certify
    assert calibrate_["force"] == "--force" and calibrate_["plots_dir"] == "--plots"
    assert "target_var_mm2" not in calibrate_


@pytest.mark.parametrize("command", COMMANDS)
def test_api_names_are_parameters_of_the_api_function(command):
    """A command's ``api_names`` (the shared table for the dests it has, and its own) maps parameters
    its API function has, or fields of the options record it takes."""
    api_names = cli.api_names(_commands()[command])
    function = getattr(api, command)
    names = set(inspect.signature(function).parameters)
    record = typing.get_type_hints(function).get("options")
    for cls in typing.get_args(record) or (record,):
        if dataclasses.is_dataclass(cls):
            names |= {f.name for f in dataclasses.fields(cls)}
    assert set(api_names) <= names


def test_name_fields_replaces_whole_words_outside_backticks():
    names = {"n": "--n", "seed": "--seed", "starts": "--starts", "scheduler": "--scheduler"}
    text = "n 5: the n_targets and -n stay; try another seed/starts"
    assert name_fields(text, ("n", "seed", "starts"), names) == (
        "--n 5: the n_targets and -n stay; try another --seed/--starts"
    )
    assert name_fields("no `dask scheduler` answered; leave scheduler out", ("scheduler",), names) == (
        "no `dask scheduler` answered; leave --scheduler out"
    )
    assert name_fields("strict: held", ("strict",), names) == "strict: held"  # no such option: kept
    assert name_fields("seed 3", (), names) == "seed 3"


def test_param_gives_the_option_within_the_command_line_only():
    assert param("sigma_mm") == "sigma_mm"
    with param_names({"sigma_mm": "--sigma-mm"}):
        assert param("sigma_mm") == "--sigma-mm" and param("seed") == "seed"
    assert param("sigma_mm") == "sigma_mm"


@pytest.mark.parametrize("value", [0.02, 1, np.float32(0.5)])
def test_check_sigma_accepts_a_positive_number(value):
    assert check_sigma(value) == pytest.approx(float(value), rel=1e-7)


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), float("inf"), True, "0.02", None])
def test_check_sigma_refuses_naming_sigma_mm(value):
    with pytest.raises(InputError, match=r"^sigma_mm must be a positive number") as err:
        check_sigma(value)
    assert err.value.fields == ("sigma_mm",)


def test_check_sigma_zero_and_none_where_allowed():
    assert check_sigma(0.0, zero_ok=True) == 0.0 and check_sigma(None, allow_none=True) is None
    with pytest.raises(InputError, match=r"^sigma_mm must be a non-negative number"):
        check_sigma(-0.1, zero_ok=True)


def test_every_workflow_checks_sigma_alike(kr16):
    """Calibration, diagnosis and the design problem refuse 0; the simulation accepts it (noise-free
    data), and every refusal is the one message with ``fields == ("sigma_mm",)``."""
    q = np.tile(kr16.q_work, (12, 1)) + np.linspace(-0.3, 0.3, 12)[:, None]
    meas = Measurements.from_arrays(q, np.zeros((12, 3)))
    refusals = [
        lambda: make_problem(kr16, sigma_mm=0.0),
        lambda: calibrate(kr16, meas, CalibrationOptions(sigma_mm=0.0)),
        lambda: diagnose(kr16, meas, DiagnosisOptions(sigma_mm=0.0)),
        lambda: simulate(kr16, q, SimulationOptions(sigma_mm=-1.0)),
    ]
    for refuse in refusals:
        with pytest.raises(InputError, match=r"^sigma_mm must be a (positive|non-negative) number") as err:
            refuse()
        assert err.value.fields == ("sigma_mm",)
    table, _ = simulate(kr16, q, SimulationOptions(sigma_mm=0.0, seed=0))
    assert len(table) == 12
