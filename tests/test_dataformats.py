"""Measurement files of other layouts (format files) and joint maps in the robot file (issue 12)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import read_data

REPO = Path(__file__).resolve().parents[1]
KR16_YAML = (REPO / "models" / "robots" / "kr16.yaml").read_text()

FOREIGN_FORMAT = """\
separator: ";"
decimal: ","
length_unit: m
angle_unit: rad
frame: tracker
joints: [J1, J2, J3, J4, J5, J6]
position: {x: X_t - dX, y: Y, z: Z}
time: order
time_unit: order
"""


@pytest.fixture(scope="module")
def sim():
    """Simulated kr16 data (SPEC layout) as a DataFrame, and the robot."""
    robot = load_robot("kr16")
    rng = np.random.default_rng(3)
    q = robot.q_work + rng.uniform(-0.3, 0.3, size=(30, 6))
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=1))
    return robot, table


def _write_foreign(path: Path, q_ctrl: np.ndarray, eta_mm: np.ndarray) -> None:
    """kr16 data in a foreign layout: ';' separator, decimal comma, metres, radians, x = X_t - dX."""
    lines = ["order;J1;J2;J3;J4;J5;J6;X_t;dX;Y;Z"]
    for k, (qq, e) in enumerate(zip(q_ctrl, eta_mm / 1000.0, strict=True)):
        vals = [k, *qq, e[0] + 0.25, 0.25, e[1], e[2]]
        lines.append(";".join(repr(float(v)).replace(".", ",") for v in vals))
    path.write_text("\n".join(lines) + "\n")


def test_foreign_layout_reads_like_the_spec_file(sim, tmp_path):
    robot, table = sim
    q = np.deg2rad(table[[f"q{i}_deg" for i in range(1, 7)]].to_numpy())
    eta = table[["x_mm", "y_mm", "z_mm"]].to_numpy()
    _write_foreign(tmp_path / "data.csv", q, eta)
    (tmp_path / "fmt.yaml").write_text(FOREIGN_FORMAT)
    data = read_data(tmp_path / "data.csv", robot, tmp_path / "fmt.yaml")
    assert data.n == len(table) and data.frame == "tracker"
    np.testing.assert_allclose(data.q, q, atol=1e-12)
    np.testing.assert_allclose(data.eta, eta, atol=1e-9)
    np.testing.assert_array_equal(data.time_s, np.arange(len(table)))
    np.testing.assert_array_equal(data.rows, np.arange(2, len(table) + 2))


def test_joint_map_sign_offset_and_coupling(sim, tmp_path):
    """Fanuc-like coupling q3 = J3 + J2, a sign flip of joint 4 and an offset of joint 1."""
    robot, table = sim
    q = np.deg2rad(table[[f"q{i}_deg" for i in range(1, 7)]].to_numpy())
    yaml = KR16_YAML + (
        "joint_map:\n  sign: [1, 1, 1, -1, 1, 1]\n  offset_deg: [10, 0, 0, 0, 0, 0]\n"
        "  couplings:\n  - {joint: 3, from_joint: 2, factor: 1.0}\n"
    )
    (tmp_path / "mapped.yaml").write_text(yaml)
    mapped = load_robot(str(tmp_path / "mapped.yaml"))
    J = mapped.joint_map.to_controller(q)
    np.testing.assert_allclose(J[:, 2], q[:, 2] - q[:, 1], atol=1e-12)
    np.testing.assert_allclose(J[:, 3], -q[:, 3], atol=1e-12)
    np.testing.assert_allclose(J[:, 0], q[:, 0] - np.deg2rad(10.0), atol=1e-12)
    _write_foreign(tmp_path / "data.csv", J, table[["x_mm", "y_mm", "z_mm"]].to_numpy())
    (tmp_path / "fmt.yaml").write_text(FOREIGN_FORMAT)
    data = read_data(tmp_path / "data.csv", mapped, tmp_path / "fmt.yaml")
    np.testing.assert_allclose(data.q, q, atol=1e-12)
    (tmp_path / "model.yaml").write_text(FOREIGN_FORMAT + "angles: model\n")
    raw = read_data(tmp_path / "data.csv", mapped, tmp_path / "model.yaml")
    np.testing.assert_allclose(raw.q, J, atol=1e-12)


@pytest.mark.parametrize(
    ("robot_extra", "fmt_change", "needle"),
    [
        ("", ("Y, z: Z", "Y, z: Zed"), "'position.z' names column 'Zed'"),
        ("", ("length_unit: m", "length_unit: mm"), "look like metres"),
        ("", ("length_unit: m", "length_unit: inch"), "field 'length_unit'"),
        ("", ("angle_unit: rad", "angle_unit: deg"), "look like radians"),
        ("", ("frame: tracker", "frame: world"), "field 'frame'"),
        ("", ('decimal: ","', 'decimal: ";"'), "field 'decimal'"),
        ("", ("joints: [J1, J2, J3, J4, J5, J6]", "joints: [J1, J2, J3]"), "field 'joints'"),
        ("", ("time_unit: order", "time_units: order"), "time_units"),
        ("joint_map:\n  sign: [1, 2, 1, 1, 1, 1]\n", ("", ""), "joint_map.sign"),
        (
            "joint_map:\n  couplings:\n  - {joint: 3, from_joint: 7, factor: 1}\n",
            ("", ""),
            "joint_map.couplings[0]",
        ),
        ("joint_map:\n  offset_deg: [0, 0]\n", ("", ""), "joint_map.offset_deg"),
        ("extra_gauge: [d9]\n", ("", ""), "extra_gauge"),
        ("reflector_position_mm: [1, 2]\n", ("", ""), "reflector_position_mm"),
    ],
)
def test_bad_format_or_joint_map_exits_2_naming_file_and_field(
    sim, tmp_path, capsys, robot_extra, fmt_change, needle
):
    robot, table = sim
    q = np.deg2rad(table[[f"q{i}_deg" for i in range(1, 7)]].to_numpy())
    _write_foreign(tmp_path / "data.csv", q, table[["x_mm", "y_mm", "z_mm"]].to_numpy())
    (tmp_path / "fmt.yaml").write_text(FOREIGN_FORMAT.replace(*fmt_change, 1))
    (tmp_path / "robot.yaml").write_text(KR16_YAML + robot_extra)
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["validate", "--robot", str(tmp_path / "robot.yaml"), str(tmp_path / "data.csv")]
    status = main([*argv, "--format", str(tmp_path / "fmt.yaml"), "--json", str(tmp_path / "out.json")])
    err = capsys.readouterr().err
    assert status == 2, err
    assert needle in err and "Traceback" not in err
    assert "robot.yaml" in err or "fmt.yaml" in err or "data.csv" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_text_in_a_number_field_names_row_and_column(sim, tmp_path):
    robot, table = sim
    q = np.deg2rad(table[[f"q{i}_deg" for i in range(1, 7)]].to_numpy())
    _write_foreign(tmp_path / "data.csv", q, table[["x_mm", "y_mm", "z_mm"]].to_numpy())
    lines = (tmp_path / "data.csv").read_text().splitlines()
    cells = lines[4].split(";")
    cells[3] = "abc"
    lines[4] = ";".join(cells)
    (tmp_path / "data.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "fmt.yaml").write_text(FOREIGN_FORMAT)
    with pytest.raises(InputError, match=r"data.csv: row 5, column 'J3': 'abc' is not a number"):
        read_data(tmp_path / "data.csv", robot, tmp_path / "fmt.yaml")
