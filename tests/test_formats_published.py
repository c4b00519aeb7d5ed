"""Format files for exports as published: no header (``header: false``, ``columns``), whitespace
separated, several targets in one row (``targets``), target labels of the file's own
(``target_labels``); every new field's bad input names the file and the field and writes nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import calibration, simulation
from kpioed_drake.cli import main
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import load_robot
from kpioed_drake.tracker.data import Measurements, read_data

THREE = np.array([[-89.58, -2.84, 327.03], [60.0, 80.0, 300.0], [-40.0, 100.0, 280.0]])
SIGMA = 0.02
COLUMNS = "[x1, y1, z1, x2, y2, z2, x3, y3, z3, J1, J2, J3, J4, J5, J6]"
FORMAT = f"""header: false
columns: {COLUMNS}
separator: whitespace
joints: [J1, J2, J3, J4, J5, J6]
targets: {{1: {{x: x1, y: y1, z: z1}}, 2: {{x: x2, y: y2, z: z2}}, 3: {{x: x3, y: y3, z: z3}}}}
"""


@pytest.fixture(scope="module")
def export(tmp_path_factory):
    """kr16 with three SMRs, simulated (seed 7), written as a tracker export: no header, spaces,
    the three SMRs of a pose in one row, then the controller's axes."""
    work = tmp_path_factory.mktemp("export")
    kr16 = load_robot("kr16")
    robot = dataclasses.replace(kr16, targets=THREE, p_FQ=THREE[0])
    q = np.random.default_rng(5).uniform(kr16.lower, kr16.upper, size=(30, 6))
    table, _ = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=SIGMA, seed=7))
    data = Measurements.from_table(table, robot)
    xyz = data.eta.reshape(30, 9)
    lines = [" ".join(f"{v:.6f}" for v in [*xyz[i], *np.rad2deg(data.q[3 * i])]) for i in range(30)]
    (work / "export.txt").write_text("\n".join(lines) + "\n")
    (work / "format.yaml").write_text(FORMAT)
    return robot, data, work


def test_an_export_reads_as_the_same_measurements(export):
    robot, data, work = export
    read = read_data(work / "export.txt", robot, work / "format.yaml")
    assert read.n == 90 and read.n_targets == 3
    assert_allclose(read.eta, data.eta, atol=1e-6)
    assert_allclose(read.q, data.q, atol=1e-7)
    np.testing.assert_array_equal(read.target, data.target)
    report = calibration.calibrate(robot, read, calibration.CalibrationOptions(sigma_mm=SIGMA))
    assert report.chi2_per_dof < 1.5


def test_target_labels_of_the_files_own(export, tmp_path):
    robot, data, _ = export
    rows = [
        " ".join(f"{v:.6f}" for v in np.rad2deg(data.q[i])) + f" {['A', 'B', 'C'][data.target[i]]} "
        + " ".join(f"{v:.6f}" for v in data.eta[i])
        for i in range(data.n)
    ]  # fmt: skip
    (tmp_path / "labels.txt").write_text("\n".join(rows) + "\n")
    (tmp_path / "f.yaml").write_text(
        "header: false\ncolumns: [J1, J2, J3, J4, J5, J6, smr, x, y, z]\nseparator: whitespace\n"
        "joints: [J1, J2, J3, J4, J5, J6]\nposition: {x: x, y: y, z: z}\ntarget: smr\n"
        "target_labels: {A: 1, B: 2, C: 3}\n"
    )
    read = read_data(tmp_path / "labels.txt", robot, tmp_path / "f.yaml")
    np.testing.assert_array_equal(read.target, data.target)
    (tmp_path / "g.yaml").write_text((tmp_path / "f.yaml").read_text().replace("C: 3", "D: 3"))
    with pytest.raises(InputError, match=r"labels.txt: row 3, column 'smr': label 'C' is not in"):
        read_data(tmp_path / "labels.txt", robot, tmp_path / "g.yaml")


def test_a_headerless_file_without_a_format_says_so(export, tmp_path, capsys):
    _, _, work = export
    out = tmp_path / "cal.yaml"
    assert main(["calibrate", "--robot", "kr16", str(work / "export.txt"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no header row" in err and "header: false" in err and not out.exists()


@pytest.mark.parametrize(
    "edit, field",
    [
        (("header: false\n", ""), "columns"),
        ((f"columns: {COLUMNS}\n", ""), "columns"),
        (("{1: {x: x1", "{0: {x: x1"), "targets.0"),
        (("separator: whitespace", "separator: tab"), "separator"),
        ((", z: z3}", "}"), "targets.3.z"),
        (("separator: whitespace\n", "separator: whitespace\ntarget_labels: {A: 1}\n"), "target_labels"),
    ],
)
def test_bad_format_fields_are_named(export, tmp_path, capsys, edit, field):
    _, _, work = export
    bad = tmp_path / "bad.yaml"
    bad.write_text(FORMAT.replace(*edit))
    out = tmp_path / "cal.yaml"
    args = ["calibrate", "--robot", "kr16", str(work / "export.txt"), "--format", str(bad), "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and field in err and not out.exists()
