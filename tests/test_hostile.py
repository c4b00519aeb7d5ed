"""Hostile inputs by class: URDF graphs and numbers, model files, option ranges, output paths,
measured values and Ctrl-C at start-up. Each ends with exit status 2 (130 for Ctrl-C) and one line
naming what the user typed (the file and its row, field or joint; the option), no traceback, and
nothing written.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kpioed_drake import api
from kpioed_drake.cli import build_parser, main
from kpioed_drake.errors import EXIT_INTERRUPTED, InputError
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_robot
from kpioed_drake.robot.modelspec import EffectSpec, checked_effects
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import Measurements

REPO = Path(__file__).resolve().parents[1]
ROBOTS = REPO / "models" / "robots"
UR5_URDF = (ROBOTS / "ur5.urdf").read_text()
UR5_SIDECAR = (ROBOTS / "ur5.kpioed.yaml").read_text()
DESIGN = REPO / "studies/results/designs/kr16_kpi_ca.csv"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
"""A subprocess's environment: this checkout's package, wherever it runs."""


def _snapshot(root: Path) -> dict:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
        for p in sorted(root.rglob("*"))
    }


def _refused(argv: list[str], capsys, root: Path | None = None) -> str:
    """Run ``argv``: exit status 2, no traceback, nothing written into ``root``; the message line."""
    before = _snapshot(root) if root is not None else None
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("kpioed:")]
    assert lines, err
    if root is not None:
        assert _snapshot(root) == before, "a failing command wrote or changed a file"
    return lines[-1]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with kr16's design and simulated data (60 poses), and an extended model file."""
    d = tmp_path_factory.mktemp("hostile")
    robot = load_robot("kr16")
    q = np.deg2rad(np.loadtxt(DESIGN, delimiter=",", skiprows=1))
    write_design(d / "design.csv", q)
    opts = SimulationOptions(sigma_mm=0.02, seed=5, effects=("joint_elasticity:2",))
    simulate(robot, q, opts)[0].to_csv(d / "data.csv", index=False)
    argv = ["calibrate", "--robot", "kr16", str(d / "data.csv"), "--extend", "joint_elasticity_basis:2"]
    assert main([*argv, "--out", str(d / "extended.yaml")]) == 0
    return d


# ---------------------------------------------------------------------------------------------
# URDF graphs: every walk over the file's links ends, with an answer or an error naming the file


def _urdf(tmp_path: Path, text: str, side: str = UR5_SIDECAR, name: str = "bad") -> Path:
    path = tmp_path / f"{name}.urdf"
    path.write_text(text)
    (tmp_path / f"{name}.kpioed.yaml").write_text(side)
    return path


def _joint(name, kind, parent, child, extra=""):
    limit = (
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>' if kind != "fixed" else ""
    )
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{limit}{extra}'
        "</joint>"
    )


GRAPHS = {
    "two-parents-revolute": (
        _joint("loop", "revolute", "wrist_3_link", "shoulder_link"),
        r"link 'shoulder_link' is the child of two joints \('shoulder_pan_joint' and 'loop'\)",
    ),
    "two-parents-fixed": (
        _joint("loop", "fixed", "wrist_3_link", "shoulder_link"),
        r"link 'shoulder_link' is the child of two joints",
    ),
    "two-parents-side": (
        _joint("extra", "fixed", "base_link", "forearm_link"),
        r"link 'forearm_link' is the child of two joints \('elbow_joint' and 'extra'\)",
    ),
    "loop-to-root": (_joint("back", "fixed", "wrist_3_link", "base_link"), r"closed loop|root"),
    "loop-apart": (
        '<link name="a"/><link name="b"/>'
        + _joint("ab", "fixed", "a", "b")
        + _joint("ba", "revolute", "b", "a"),
        r"joints ('ba', 'ab'|'ab', 'ba') form a closed loop",
    ),
    "joint-to-itself": (_joint("s", "fixed", "wrist_3_link", "wrist_3_link"), r"joint 's': connects link"),
    "unknown-link": (_joint("s", "fixed", "wrist_3_link", "nowhere"), r"child link 'nowhere' is not a link"),
    "duplicate-link": ('<link name="wrist_3_link"/>', r"link 'wrist_3_link' is defined more than once"),
    "duplicate-joint": (
        '<link name="tool"/>' + _joint("wrist_3_joint", "fixed", "wrist_3_link", "tool"),
        r"joint 'wrist_3_joint' is defined more than once",
    ),
}


@pytest.mark.parametrize("case", sorted(GRAPHS))
def test_a_urdf_that_is_no_tree_is_refused(case, tmp_path, capsys):
    extra, pattern = GRAPHS[case]
    path = _urdf(tmp_path, UR5_URDF.replace("</robot>", extra + "</robot>"))
    line = _refused(["info", "--robot", path], capsys, tmp_path)
    assert str(path) in line and re.search(pattern, line), line


def test_a_link_with_two_parents_ends_at_once(tmp_path):
    """The loop that ran out of memory: a subprocess under a memory limit and a timeout."""
    extra = _joint("loop", "revolute", "wrist_3_link", "shoulder_link")
    path = _urdf(tmp_path, UR5_URDF.replace("</robot>", extra + "</robot>"))

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    cmd = [sys.executable, "-m", "kpioed_drake.cli", "info", "--robot", str(path)]
    res = subprocess.run(
        cmd, capture_output=True, text=True, timeout=300, preexec_fn=limit, cwd=tmp_path, env=ENV
    )
    assert res.returncode == 2, res.stderr[-2000:]
    assert "is the child of two joints" in res.stderr and "Traceback" not in res.stderr


def test_a_deep_urdf_is_walked_without_recursion(tmp_path, capsys):
    """3000 fixed links above the robot (the old recursive walk ended in RecursionError)."""
    n = 3000
    links = "".join(f'<link name="d{i}"/>' for i in range(n))
    joints = "".join(_joint(f"dj{i}", "fixed", f"d{i}", f"d{i + 1}") for i in range(n - 1))
    joints += _joint("onto", "fixed", f"d{n - 1}", "base_link")
    path = _urdf(tmp_path, UR5_URDF.replace("</robot>", links + joints + "</robot>"), name="deep")
    assert main(["info", "--robot", str(path), "--json"]) == 0
    assert '"robot": "ur5-urdf"' in capsys.readouterr().out


LIMIT = '<limit lower="-6.2831853071795862" upper="6.2831853071795862" effort="150" velocity="3.15"/>'
LIFT = '<joint name="shoulder_lift_joint" type="revolute">'


def _lift_limit(limit: str) -> str:
    """The UR5 URDF with the shoulder lift joint's ``<limit>`` replaced."""
    i = UR5_URDF.index(LIFT)
    j = UR5_URDF.index(LIMIT, i)
    return UR5_URDF[:j] + limit + UR5_URDF[j + len(LIMIT) :]


URDF_NUMBERS = {
    "lower-above-upper": (
        _lift_limit('<limit lower="1" upper="-1" effort="150" velocity="3.15"/>'),
        r"joint 'shoulder_lift_joint': <limit lower='1' upper='-1'>: the lower limit is above the upper",
    ),
    "velocity-negative": (
        _lift_limit('<limit lower="-1" upper="1" effort="150" velocity="-3"/>'),
        r"joint 'shoulder_lift_joint': <limit velocity='-3'>: expected a number >= 0",
    ),
    "lower-nan": (
        _lift_limit('<limit lower="nan" upper="1" effort="150" velocity="3"/>'),
        r"joint 'shoulder_lift_joint': <limit lower='nan'>: expected one finite number",
    ),
    "mimic-multiplier-text": (
        UR5_URDF.replace(
            '<joint name="elbow_joint" type="revolute">',
            '<joint name="elbow_joint" type="revolute"><mimic joint="wrist_1_joint" multiplier="abc"/>',
        ),
        r"joint 'elbow_joint': <mimic multiplier='abc'>: expected one finite number",
    ),
    "mass-negative": (
        UR5_URDF.replace('<mass value="3.7"/>', '<mass value="-3.7"/>'),
        r"link 'shoulder_link': <mass value='-3.7'>: expected a number >= 0",
    ),
    "origin-1e300": (
        UR5_URDF.replace('<origin xyz="-0.42499999999999999 0 0" rpy="0 0 0"/>', '<origin xyz="1e300 0 0"/>'),
        r"joint 'elbow_joint': xyz='1e300 0 0': expected values of at most 1000 in size",
    ),
    "radius-negative": (
        UR5_URDF.replace('<cylinder radius="0.06"', '<cylinder radius="-0.06"'),
        r"link 'shoulder_link' collision 0: <cylinder>: expected sizes >= 0",
    ),
    "nested-20000-deep": (
        UR5_URDF.replace(
            '<link name="wrist_3_link">', '<link name="wrist_3_link">' + "<x>" * 20000 + "</x>" * 20000
        ),
        r"elements nested deeper than 64 \(<x>\); not a URDF",
    ),
    "sidecar-nested-20000-deep": (
        UR5_URDF,
        r"bad\.kpioed\.yaml: lists or mappings nested too deeply",
    ),
    "mimic-cycle": (
        UR5_URDF.replace(
            '<joint name="elbow_joint" type="revolute">',
            '<joint name="elbow_joint" type="revolute"><mimic joint="wrist_1_joint"/>',
        ).replace(
            '<joint name="wrist_1_joint" type="revolute">',
            '<joint name="wrist_1_joint" type="revolute"><mimic joint="elbow_joint"/>',
        ),
        r"bad\.urdf: joint 'elbow_joint': <mimic joint='wrist_1_joint'> must name a commanded",
    ),
}


@pytest.mark.parametrize("case", sorted(URDF_NUMBERS))
def test_a_bad_urdf_number_names_the_urdf_and_the_joint(case, tmp_path, capsys):
    text, pattern = URDF_NUMBERS[case]
    deep = "notes: " + "[" * 20000 + "]" * 20000 + "\n"
    path = _urdf(tmp_path, text, UR5_SIDECAR + deep if case.startswith("sidecar") else UR5_SIDECAR)
    line = _refused(["info", "--robot", path], capsys, tmp_path)
    assert str(tmp_path / "bad") in line and re.search(pattern, line), line


def test_the_sidecar_limits_replace_a_urdf_limit_drake_refuses(tmp_path):
    """lower above upper in the URDF, the joint's limits in the sidecar: the robot loads with them."""
    side = UR5_SIDECAR + "limits: [{joint: shoulder_lift_joint, lower: -170, upper: 170}]\n"
    path = _urdf(tmp_path, _lift_limit('<limit lower="1" upper="-1" effort="150" velocity="3.15"/>'), side)
    robot = load_robot(str(path))
    np.testing.assert_allclose(
        np.rad2deg([robot.lower[1], robot.upper[1]]), [-170.0, 170.0], rtol=0, atol=1e-9
    )
    assert f'lower="{float(np.deg2rad(-170.0))!r}"' in robot.urdf.text  # what Drake parsed


# ---------------------------------------------------------------------------------------------
# Model files: every number checked where it is read, the field named


def _basis_rows(text: str) -> tuple[int, int]:
    """The span of the first row of ``basis_directions`` in an extended model file."""
    i = text.index("basis_directions:")
    j = text.index("- [", i) + 3
    return j, text.index(",", j)


MODEL_FILES = {
    "basis-nan": (
        lambda t: t[: _basis_rows(t)[0]] + ".nan" + t[_basis_rows(t)[1] :],
        r"effects\[0\]\.basis_directions\[0\]\[0\]: expected a finite number, got nan",
    ),
    "basis-inf": (
        lambda t: t[: _basis_rows(t)[0]] + ".inf" + t[_basis_rows(t)[1] :],
        r"effects\[0\]\.basis_directions\[0\]\[0\]: expected a finite number, got inf",
    ),
    "effects-null": (
        lambda t: t[: t.index("effects:")] + "effects: [null]\n",
        r"effects\[0\]: expected a mapping \(key: value\), got nothing",
    ),
    "values-text": (
        lambda t: t.replace("  values: [", "  values: [abc, ", 1),
        r"effects\[0\]\.values\[0\]: expected a finite number, got 'abc'",
    ),
    "values-a-word": (
        lambda t: t[: t.index("effects:")] + "effects:\n- {name: joint_elasticity:2, values: abc}\n",
        r"effects\[0\]\.values: expected a list \[\.\.\.\], got 'abc'",
    ),
    "unknown-field": (
        lambda t: t[: t.index("effects:")] + "effects:\n- {name: joint_elasticity:2, value: [1e-6]}\n",
        r"effects\[0\]: unknown field 'value'",
    ),
}


@pytest.mark.parametrize("command", ["validate", "compensate", "info"])
@pytest.mark.parametrize("case", sorted(MODEL_FILES))
def test_a_bad_model_file_names_the_file_and_field(case, command, work, tmp_path, capsys):
    edit, pattern = MODEL_FILES[case]
    model = tmp_path / f"{case}.yaml"
    model.write_text(edit((work / "extended.yaml").read_text()))
    argv = {
        "validate": ["validate", "--robot", model, work / "data.csv"],
        "compensate": ["compensate", "--robot", model, "--nominal", "kr16", "--program", work / "design.csv"]
        + ["--out", tmp_path / "c.csv"],
        "info": ["info", "--robot", model],
    }[command]
    line = _refused(argv, capsys, tmp_path)
    assert str(model) in line and re.search(pattern, line), line


def test_the_effects_of_a_robot_in_memory_are_checked_alike():
    """NaN in basis_directions of an effect built in Python (no file): named, not an SVD failure."""
    spec = EffectSpec(
        name="joint_elasticity_basis:2",
        values=[1e-6],
        basis_rms=[1.0, 2.0],
        basis_directions=[[1.0], [np.nan]],
    )
    with pytest.raises(InputError, match=r"^robot: effects\[0\]\.basis_directions: expected finite numbers"):
        checked_effects([spec], "robot")


# ---------------------------------------------------------------------------------------------
# Options: each refused by its command-line name, before the work starts


BASE = {
    "evaluate": "evaluate --robot kr16 --design {design} --no-certify",
    "design": "design --robot kr16 --criterion kpi --out {root}/o.csv",
    "simulate": "simulate --robot kr16 --design {design} --out {root}/s.csv",
    "calibrate": "calibrate --robot kr16 {data}",
    "next": "next --robot kr16 {data} --target-var 0.01",
    "diagnose": "diagnose --robot kr16 {data}",
    "study": "study --robots kr16 --out {root}/st",
    "compensate": "compensate --robot {extended} --nominal kr16 --program {design} --out {root}/c.csv",
}
"""A command line of each command with numeric options, to which a bad value is added."""
BAD_VALUES = {int: ("-1",), float: ("nan", "inf", "-1")}
"""Values no numeric option accepts: a negative count, seed or index; a number that is none or
negative."""


def _numeric_options() -> list[tuple[str, str, str]]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return [
        (command, a.option_strings[-1], value)
        for command, p in sub.choices.items()
        if command in BASE
        for a in p._actions
        if a.type in BAD_VALUES
        for value in BAD_VALUES[a.type]
    ]


OPTION_CASES = _numeric_options() + [
    ("next", "--n", "100000"),
    ("next", "--max-plan", "0"),
    ("design", "--target-var", "0"),
    ("calibrate", "--outlier-alpha", "1"),
]


def test_every_numeric_option_is_in_the_sweep():
    assert len({(c, o) for c, o, _ in OPTION_CASES}) >= 20
    assert {c for c, _, _ in OPTION_CASES} == set(BASE)


@pytest.mark.parametrize(("command", "option", "value"), OPTION_CASES)
def test_an_option_out_of_range_is_refused_by_its_name(command, option, value, work, capsys):
    names = {k: str(work / f"{k}.csv") for k in ("design", "data")} | {
        "root": str(work),
        "extended": str(work / "extended.yaml"),
    }
    argv = BASE[command].format(**names).split() + [option, value]
    line = _refused(argv, capsys, work)
    assert line.startswith(f"kpioed: error: {option}"), line


def test_next_names_the_force_it_has(work, tmp_path, capsys):
    """The plausibility refusal advises --force; next has it (it advised a force it had no option for)."""
    lines = (work / "data.csv").read_text().splitlines()
    rows = [r.split(",") for r in lines[1:]]
    for r in rows:
        r[6:9] = [f"{float(x) * 1e-3:.9f}" for x in r[6:9]]
    metres = tmp_path / "metres.csv"
    metres.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    line = _refused(["next", "--robot", "kr16", metres, "--target-var", "0.01"], capsys, tmp_path)
    assert "look like metres" in line and line.endswith("(use --force to go on anyway)"), line
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert "--force" in sub.choices["next"]._option_string_actions


# ---------------------------------------------------------------------------------------------
# Output paths: checked before the work (an empty name, an unwritable folder, a folder)

OUTPUT_COMMANDS = {
    "calibrate-extend": "calibrate --robot kr16 {data} --extend joint_elasticity:2 {flag} {path}",
    "diagnose": "diagnose --robot kr16 {data} {flag} {path}",
    "design": "design --robot kr16 --criterion heuristic --n 30 --out {root}/d.csv {flag} {path}",
    "simulate": "simulate --robot kr16 --design {design} --out {root}/s.csv {flag} {path}",
    "next": "next --robot kr16 {data} --target-var 0.01 {flag} {path}",
    "validate": "validate --robot kr16 {data} {flag} {path}",
}
"""Commands with an output option, and the option tried."""
FLAGS = {
    "calibrate-extend": "--out",
    "diagnose": "--out",
    "design": "--json",
    "simulate": "--truth",
    "next": "--out",
    "validate": "--json",
}


def _output_argv(work: Path, command: str, path: str) -> list[str]:
    names = {k: str(work / f"{k}.csv") for k in ("design", "data")} | {"root": str(work)}
    argv = OUTPUT_COMMANDS[command].format(**names, flag=FLAGS[command], path="PATH").split()
    return [path if a == "PATH" else a for a in argv]


@pytest.mark.parametrize("command", sorted(OUTPUT_COMMANDS))
def test_an_empty_output_name_is_refused(command, work, capsys):
    line = _refused(_output_argv(work, command, ""), capsys, work)
    assert line == f"kpioed: error: {FLAGS[command]}: expected a value, got an empty string"


@pytest.mark.parametrize("command", sorted(OUTPUT_COMMANDS))
def test_an_unwritable_output_is_refused_before_the_work(command, work, capsys, monkeypatch):
    """/proc takes no new file; the message names the path the user typed, before any data is read."""

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the output paths were checked")

    monkeypatch.setattr("kpioed_drake.calibration.inputs.read_data", no_work)
    monkeypatch.setattr("kpioed_drake.design.workflow.load_robot", no_work)
    monkeypatch.setattr("kpioed_drake.simulation.workflow.load_robot", no_work)
    line = _refused(_output_argv(work, command, "/proc/kpioed-out.x"), capsys, work)
    assert (
        line == "kpioed: error: /proc/kpioed-out.x: cannot be written: No such file or directory (in /proc)"
    )


def test_an_existing_folder_that_takes_no_file_is_refused(work, capsys):
    """--plots /proc: the folder exists, but no picture can be made in it."""
    line = _refused(["calibrate", "--robot", "kr16", work / "data.csv", "--plots", "/proc"], capsys, work)
    assert line == "kpioed: error: /proc: cannot be written: No such file or directory (in /proc)"


def test_the_library_refuses_an_empty_output_name(work):
    with pytest.raises(InputError, match=r"^output '': expected a file or folder name"):
        api.diagnose("kr16", work / "data.csv", out="")
    with pytest.raises(InputError, match=r"^output '': expected a file or folder name"):
        api.study(out_dir="", robots=["kr16"], n=30)


def test_a_failed_write_names_the_output_not_its_temporary_file(tmp_path, monkeypatch):
    from kpioed_drake import outputs

    def refuse(*args, **kwargs):
        raise OSError(2, "No such file or directory", str(tmp_path / ".r.json.abc.tmp"))

    monkeypatch.setattr(outputs.tempfile, "mkstemp", refuse)
    with pytest.raises(OSError) as err:
        outputs.atomic_write_text(tmp_path / "r.json", "{}")
    assert err.value.filename == str(tmp_path / "r.json")


def test_a_yaml_output_for_a_urdf_robot_quotes_the_path(work, capsys, monkeypatch, tmp_path):
    """The path the user typed stays as typed (it was echoed as '--out --out/try.yaml')."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    argv = ["calibrate", "--robot", ROBOTS / "ur5.urdf", work / "data.csv", "--out", "out/try.yaml"]
    line = _refused(argv, capsys)
    assert "--out/try.yaml" not in line and line.endswith("got 'out/try.yaml'"), line
    assert line.startswith("kpioed: error: --out: ur5-urdf is a URDF robot"), line


# ---------------------------------------------------------------------------------------------
# Measured values: each checked where it is read, named by file, row and column


def _edit_row(work: Path, tmp_path: Path, name: str, row: int, column: int, value: str) -> Path:
    lines = (work / "data.csv").read_text().splitlines()
    cells = lines[row - 1].split(",")
    cells[column] = value
    lines[row - 1] = ",".join(cells)
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("command", ["calibrate", "validate", "diagnose"])
def test_an_impossible_value_is_named_by_row_and_column(command, work, tmp_path, capsys):
    path = _edit_row(work, tmp_path, "huge.csv", 6, 7, "1e300")
    line = _refused([command, "--robot", "kr16", path], capsys, tmp_path)
    assert f"{path}: row 6, column 'y_mm': 1e+300 mm is no measured value" in line, line


def test_one_wild_row_is_named_not_the_units(work, tmp_path, capsys):
    """One coordinate 500 m away: the row is named (it passed for micrometres)."""
    path = _edit_row(work, tmp_path, "wild.csv", 6, 7, "5e5")
    line = _refused(["calibrate", "--robot", "kr16", path], capsys, tmp_path)
    assert f"{path}: row(s) 6 miss the nominal model by more than" in line and "micrometres" not in line, line


def test_identical_poses_name_the_file_and_what_to_do(work, tmp_path, capsys):
    lines = (work / "data.csv").read_text().splitlines()
    path = tmp_path / "same.csv"
    path.write_text("\n".join([lines[0]] + [lines[1]] * 10) + "\n")
    for command in ("calibrate", "validate"):
        line = _refused([command, "--robot", "kr16", path], capsys, tmp_path)
        assert f"{path}: the poses put the reflector at one point" in line and "measure poses" in line, line


@pytest.mark.parametrize(
    ("column", "value"), [("temperature_C", -300.0), ("time_s", 1e15), ("payload_kg", 1e7)]
)
def test_measurements_in_memory_are_checked_alike(column, value):
    rng = np.random.default_rng(7)
    q, eta = rng.normal(size=(12, 6)), rng.normal(size=(12, 3)) * 500.0
    cond = np.zeros(12)
    cond[4] = value
    with pytest.raises(InputError, match=rf"^data: row 6, column '{column}': "):
        Measurements.from_arrays(q, eta, **{column: cond})


# ---------------------------------------------------------------------------------------------
# Ctrl-C at start-up: one line and status 130, whenever it comes

STARTING = "test: the imports start"
"""Printed to stderr by :data:`ANNOUNCE_IMPORTS` when the command's parser (and its imports) starts."""
ANNOUNCE_IMPORTS = f"""
import sys
import kpioed_drake.cli as cli

build = cli.build_parser


def announce():
    print({STARTING!r}, file=sys.stderr, flush=True)
    return build()


cli.build_parser = announce
sys.exit(cli.main())  # as the kpioed command: its arguments from sys.argv
"""
"""The command line, saying on stderr when it starts building its parser (nothing else changed)."""


@pytest.mark.parametrize(
    ("argv", "after_s"),
    [
        (["info", "--robot", "kr16"], 0.0),
        (["info", "--robot", "kr16"], 0.3),
        (["design", "--robot", "kr16", "--criterion", "kpi", "--out", "d.csv"], 0.6),
        (["calibrate", "--robot", "kr16", "data.csv"], 1.2),
        (["calibrate", "--robot", "kr16", "data.csv"], 2.5),
    ],
)
def test_ctrl_c_at_start_up_is_one_line_and_status_130(argv, after_s, tmp_path):
    """SIGINT ``after_s`` after the imports started (1-2 s of them): interrupted with 130 and one
    line, or finished first (0, or 2 for the missing data file); never a traceback or status 1."""
    cmd = [sys.executable, "-c", ANNOUNCE_IMPORTS, *argv]
    proc = subprocess.Popen(
        cmd, cwd=tmp_path, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    first = proc.stderr.readline()
    assert first.strip() == STARTING, first + proc.stderr.read()
    time.sleep(after_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert "Traceback" not in err and "Error" not in err.replace("error:", ""), err
    if proc.returncode == EXIT_INTERRUPTED:
        assert err.splitlines()[-1] == "kpioed: interrupted", err
    else:
        assert proc.returncode in (0, 2), (proc.returncode, err)
    assert not (tmp_path / "d.csv").exists()


# ---------------------------------------------------------------------------------------------
# Help texts for any robot


@pytest.mark.parametrize(
    "command", ["calibrate", "next", "diagnose", "validate", "simulate", "evaluate", "design"]
)
def test_help_assumes_no_six_joints(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for six in ("q6", "q1,...,q6", "SPEC format", "PARAMS.yaml", "six joint"):
        assert six not in text, (command, six)
    if command in ("calibrate", "diagnose"):
        assert "NAME.urdf" in text


def test_the_data_formats_guide_assumes_no_six_joints():
    text = (REPO / "docs" / "data-formats.md").read_text()
    assert "six joint" not in text and "q6_deg" not in text
