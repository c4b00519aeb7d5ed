"""A corpus of bad inputs across all commands (issue 15): each ends with a clear one-line message.

Every case asserts the exit status (2 bad input, 3 solver/infeasible), that the message names the
file, row or field, that no traceback is printed, and that no file in the work folder was written
or changed.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
from pathlib import Path

import numpy as np
import pytest

from kpioed_drake.cli import main
from kpioed_drake.files.designs import write_design
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate

REPO = Path(__file__).resolve().parents[1]
KR16_YAML = (REPO / "models" / "robots" / "kr16.yaml").read_text()


def _bad_robot(old: str, new: str) -> str:
    assert old in KR16_YAML, old
    return KR16_YAML.replace(old, new, 1)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A work folder with good and bad input files (names -> paths)."""
    d = tmp_path_factory.mktemp("corpus")
    robot = load_robot("kr16")
    design = np.loadtxt(REPO / "studies/results/designs/kr16_kpi_ca.csv", delimiter=",", skiprows=1)
    q = np.deg2rad(design)
    write_design(d / "design.csv", q)
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=0.02, seed=3))
    table.to_csv(d / "data.csv", index=False)
    text = (d / "data.csv").read_text()
    table.assign(temperature_C=20.0).to_csv(d / "const_temp.csv", index=False)
    q_flat = np.tile(robot.q_work, (60, 1))  # only joints 1 and 2 move: the wrist is undetermined
    q_flat[:, 0] += np.linspace(-1.0, 1.0, 60)
    q_flat[:, 1] += 0.3 * np.sin(np.linspace(0.0, 6.0, 60))
    simulate(robot, q_flat, SimulationOptions(sigma_mm=0.02, seed=3))[0].to_csv(
        d / "degenerate.csv", index=False
    )
    lines = text.splitlines()
    f = {
        "design": d / "design.csv",
        "data": d / "data.csv",
        "dir": d / "a_folder",
        "const_temp": d / "const_temp.csv",
        "degenerate": d / "degenerate.csv",
    }
    f["dir"].mkdir()
    w = {
        "empty.csv": "",
        "header_only.csv": lines[0] + "\n",
        "nine_poses.csv": "\n".join(lines[:10]) + "\n",
        "nan_value.csv": "\n".join(
            [lines[0], lines[1].replace(lines[1].split(",")[2], "nan", 1), *lines[2:]]
        ),
        "text_value.csv": "\n".join(
            [lines[0], lines[1].replace(lines[1].split(",")[0], "abc", 1), *lines[2:]]
        ),
        "no_xyz.csv": "\n".join(",".join(r.split(",")[:6]) for r in lines) + "\n",
        "semicolon.csv": text.replace(",", ";").replace(".", ","),
        "outside_limits.csv": "\n".join([lines[0], "400," + ",".join(lines[1].split(",")[1:]), *lines[2:]]),
        "design_short.csv": "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,-90,90,0,0,0\n",
        "design_bad_col.csv": "q1_deg,q2_deg,q3,q4_deg,q5_deg,q6_deg\n0,-90,90,0,0,0\n",
        "metres.csv": _scale_xyz(lines, 1e-3),
        "half_garbage.csv": _garbage(lines),
        "robot_nan_radius.yaml": _bad_robot("radius_mm: ", "radius_mm: .nan #"),
        "robot_nan_mass.yaml": _bad_robot("mass_kg: ", "mass_kg: .nan #"),
        "robot_beam9.yaml": _bad_robot("beam_links:\n- 0\n", "beam_links:\n- 9\n"),
        "robot_syntax.yaml": KR16_YAML.replace("joints:", "joints: [", 1),
        "robot_5_joints.yaml": _drop_joint(KR16_YAML),
        "robot_qwork.yaml": _bad_robot("q_work_deg:\n- -16.1793\n", "q_work_deg:\n- -400\n"),
    }
    for name, content in w.items():
        (d / name).write_text(content)
    (d / "utf16.csv").write_bytes(text.encode("utf-16"))
    f.update({k.rsplit(".", 1)[0]: d / k for k in [*w, "utf16.csv"]})
    f["root"] = d
    return f


def _scale_xyz(lines, factor):
    out = [lines[0]]
    for r in lines[1:]:
        v = r.split(",")
        v[6:9] = [f"{float(x) * factor:.9f}" for x in v[6:9]]
        out.append(",".join(v))
    return "\n".join(out) + "\n"


def _garbage(lines):
    rng = np.random.default_rng(0)
    out = [lines[0]]
    for k, r in enumerate(lines[1:]):
        v = r.split(",")
        if k % 2:
            v[6:9] = [f"{float(x) + rng.uniform(-500, 500):.6f}" for x in v[6:9]]
        out.append(",".join(v))
    return "\n".join(out) + "\n"


def _drop_joint(text):
    i = text.index("- name: A6")
    j = text.index("\nlinks:")
    return text[:i] + text[j + 1 :]


def _snapshot(root: Path) -> dict:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
        for p in sorted(root.rglob("*"))
    }


# (id, argv with {names} of files, expected exit status, regex the message must match)
# fmt: off
CASES = [
    # info / evaluate
    ("info-unknown-robot", "info --robot kr17", 2, r"unknown robot 'kr17'"),
    ("info-robot-nan-radius", "info --robot {robot_nan_radius}", 2, r"radius_mm"),
    ("info-robot-beam9", "info --robot {robot_beam9}", 2, r"beam_links"),
    ("info-robot-syntax", "info --robot {robot_syntax}", 2, r"line \d+"),
    ("info-robot-5-joints", "info --robot {robot_5_joints}", 2, r"joints"),
    ("info-robot-qwork", "info --robot {robot_qwork}", 2, r"q_work_deg"),
    ("info-robot-folder", "info --robot {dir}/x.yaml", 2, r"x\.yaml"),
    ("evaluate-missing-design", "evaluate --robot kr16 --design {root}/nope.csv", 2, r"nope\.csv"),
    ("evaluate-design-folder", "evaluate --robot kr16 --design {dir}", 2, r"a_folder"),
    ("evaluate-empty", "evaluate --robot kr16 --design {empty}", 2, r"empty\.csv"),
    ("evaluate-too-few", "evaluate --robot kr16 --design {design_short}", 2, r"design_short\.csv.*poses"),
    ("evaluate-bad-column", "evaluate --robot kr16 --design {design_bad_col}", 2, r"q3_deg"),
    ("evaluate-sigma-negative", "evaluate --robot kr16 --design {design} --sigma-mm -1", 2, r"sigma"),
    ("evaluate-sigma-nan", "evaluate --robot kr16 --design {design} --sigma-mm nan", 2, r"sigma"),
    ("evaluate-q-work-short", "evaluate --robot kr16 --design {design} --q-work 1,2,3", 2, r"q-work|q_work"),
    ("evaluate-q-work-text", "evaluate --robot kr16 --design {design} --q-work a,b,c,d,e,f", 2, r"q-work|q_work"),
    ("evaluate-extend-unknown", "evaluate --robot kr16 --design {design} --extend warp:2", 2, r"warp"),
    ("evaluate-extend-joint9", "evaluate --robot kr16 --design {design} --extend joint_elasticity:9", 2, r"joint"),
    ("evaluate-robot-nan-radius", "evaluate --robot {robot_nan_radius} --design {design}", 2, r"radius_mm"),
    ("evaluate-json-folder", "evaluate --robot kr16 --design {design} --json {dir}", 2, r"a_folder"),
    ("evaluate-json-is-input", "evaluate --robot kr16 --design {design} --json {design}", 2, r"design\.csv"),
    # design
    ("design-n-zero", "design --robot kr16 --criterion kpi --n 0 --out {root}/o.csv", 2, r"n|poses"),
    ("design-n-too-few", "design --robot kr16 --criterion kpi --n 5 --out {root}/o.csv", 2, r"poses"),
    ("design-seed-negative", "design --robot kr16 --criterion kpi --seed -1 --out {root}/o.csv", 2, r"seed"),
    ("design-starts-zero", "design --robot kr16 --criterion kpi --starts 0 --out {root}/o.csv", 2, r"starts"),
    ("design-criterion", "design --robot kr16 --criterion e --out {root}/o.csv", 2, r"criterion"),
    ("design-solver", "design --robot kr16 --criterion kpi --solver cplex --out {root}/o.csv", 2, r"solver"),
    ("design-out-folder", "design --robot kr16 --criterion heuristic --out {dir}", 2, r"a_folder"),
    ("design-plot-xyz", "design --robot kr16 --criterion heuristic --out {root}/o.csv --plot {root}/p.xyz", 2, r"p\.xyz"),
    ("design-out-below-file", "design --robot kr16 --criterion heuristic --out {design}/o.csv", 2, r"design\.csv"),
    ("design-robot-nan-radius", "design --robot {robot_nan_radius} --criterion kpi --out {root}/o.csv", 2, r"radius_mm"),
    ("design-sigma-zero", "design --robot kr16 --criterion kpi --sigma-mm 0 --out {root}/o.csv", 2, r"sigma"),
    # simulate
    ("simulate-seed-negative", "simulate --robot kr16 --design {design} --seed -1 --out {root}/s.csv", 2, r"seed"),
    ("simulate-payload-negative", "simulate --robot kr16 --design {design} --payload-kg -5 --out {root}/s.csv", 2, r"payload"),
    ("simulate-sigma-negative", "simulate --robot kr16 --design {design} --sigma-mm -0.1 --out {root}/s.csv", 2, r"sigma"),
    ("simulate-effect-unknown", "simulate --robot kr16 --design {design} --effect warp:1 --out {root}/s.csv", 2, r"warp"),
    ("simulate-out-is-input", "simulate --robot kr16 --design {design} --out {design}", 2, r"design\.csv"),
    ("simulate-out-folder", "simulate --robot kr16 --design {design} --out {dir}", 2, r"a_folder"),
    ("simulate-missing-design", "simulate --robot kr16 --design {root}/none.csv --out {root}/s.csv", 2, r"none\.csv"),
    # calibrate
    ("calibrate-missing", "calibrate --robot kr16 {root}/none.csv", 2, r"none\.csv"),
    ("calibrate-folder", "calibrate --robot kr16 {dir}", 2, r"a_folder"),
    ("calibrate-empty", "calibrate --robot kr16 {empty}", 2, r"empty\.csv"),
    ("calibrate-header-only", "calibrate --robot kr16 {header_only}", 2, r"header_only\.csv"),
    ("calibrate-nine-poses", "calibrate --robot kr16 {nine_poses}", 2, r"nine_poses\.csv.*poses"),
    ("calibrate-nine-poses-extended", "calibrate --robot kr16 {nine_poses} --extend joint_elasticity:2 --extend gear_cyclic:4:2 --extend joint_elasticity:3", 2, r"nine_poses\.csv"),
    ("calibrate-nan", "calibrate --robot kr16 {nan_value}", 2, r"nan_value\.csv.*row 2"),
    ("calibrate-text", "calibrate --robot kr16 {text_value}", 2, r"text_value\.csv.*row 2"),
    ("calibrate-no-xyz", "calibrate --robot kr16 {no_xyz}", 2, r"x_mm"),
    ("calibrate-semicolon", "calibrate --robot kr16 {semicolon}", 2, r"semicolon\.csv.*(';'|separator)"),
    ("calibrate-utf16", "calibrate --robot kr16 {utf16}", 2, r"utf16\.csv.*(UTF-16|encoding|UTF-8)"),
    ("calibrate-outside-limits", "calibrate --robot kr16 {outside_limits}", 2, r"outside_limits\.csv.*row 2"),
    ("calibrate-metres", "calibrate --robot kr16 {metres}", 2, r"metres|mm"),
    ("calibrate-half-garbage", "calibrate --robot kr16 {half_garbage}", 2, r"half_garbage\.csv"),
    ("calibrate-other-robot", "calibrate --robot kr300 {data}", 2, r"data\.csv"),
    ("calibrate-json-is-input", "calibrate --robot kr16 {data} --json {data}", 2, r"data\.csv"),
    ("calibrate-out-folder", "calibrate --robot kr16 {data} --out {dir}", 2, r"a_folder"),
    ("calibrate-plots-is-file", "calibrate --robot kr16 {data} --plots {design}", 2, r"design\.csv"),
    ("calibrate-sigma-negative", "calibrate --robot kr16 {data} --sigma-mm -1", 2, r"sigma"),
    ("calibrate-outlier-alpha", "calibrate --robot kr16 {data} --outlier-alpha 2", 2, r"outlier"),
    ("calibrate-extend-unknown", "calibrate --robot kr16 {data} --extend warp:1", 2, r"warp"),
    ("calibrate-thermal-constant", "calibrate --robot kr16 {const_temp} --extend thermal_expansion", 2, r"temperature"),
    # diagnose
    ("diagnose-missing", "diagnose --robot kr16 {root}/none.csv", 2, r"none\.csv"),
    ("diagnose-nine-poses", "diagnose --robot kr16 {nine_poses}", 2, r"nine_poses\.csv"),
    ("diagnose-nan", "diagnose --robot kr16 {nan_value}", 2, r"nan_value\.csv.*row 2"),
    ("diagnose-half-garbage", "diagnose --robot kr16 {half_garbage}", 2, r"half_garbage\.csv"),
    ("diagnose-json-is-input", "diagnose --robot kr16 {data} --json {data}", 2, r"data\.csv"),
    ("diagnose-plots-is-file", "diagnose --robot kr16 {data} --plots {design}", 2, r"design\.csv"),
    ("calibrate-degenerate", "calibrate --robot kr16 {degenerate}", 2, r"degenerate\.csv.*do not determine"),
    ("diagnose-degenerate", "diagnose --robot kr16 {degenerate}", 2, r"degenerate\.csv.*do not determine"),
    ("info-robot-nan-mass", "info --robot {robot_nan_mass}", 2, r"mass_kg"),
    ("evaluate-html-suffix", "evaluate --robot kr16 --design {design} --html {root}/page.png", 2, r"page\.png"),
    # study
    ("study-heuristic-draws-zero", "study --robots kr16 --heuristic-draws 0 --out {root}/st", 2, r"--heuristic-draws"),
    ("study-scheduler-unreachable", "study --robots kr16 --n 20 --heuristic-draws 1 --no-progress --scheduler tcp://127.0.0.1:9 --out {root}/st", 2, r"scheduler"),
    ("study-robots-empty", "study --robots , --out {root}/st", 2, r"robots"),
    ("study-n-too-few", "study --robots kr16 --n 5 --out {root}/st", 2, r"poses|--n"),
    ("study-seed-negative", "study --robots kr16 --seed -1 --out {root}/st", 2, r"seed"),
    ("study-jobs-zero", "study --robots kr16 --jobs 0 --out {root}/st", 2, r"jobs"),
    ("study-unknown-robot", "study --robots kr17 --out {root}/st", 2, r"kr17"),
    ("study-out-is-file", "study --robots kr16 --out {design}", 2, r"design\.csv"),
]
# fmt: on


@pytest.mark.parametrize(("argv", "status", "pattern"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input(files, capsys, argv, status, pattern):
    names = {k: str(v) for k, v in files.items()}
    before = _snapshot(files["root"])
    try:
        code = main(argv.format(**names).split())
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == status, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("kpioed:")]
    assert lines, err
    assert re.search(pattern, lines[-1]), lines[-1]
    assert _snapshot(files["root"]) == before, "a failing command wrote or changed a file"


def test_corpus_size():
    assert len(CASES) >= 60
    assert len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize(
    ("errno_", "text"), [(errno.EROFS, "read-only file system"), (errno.ENOSPC, "no space left")]
)
def test_unwritable_output(files, capsys, tmp_path, monkeypatch, errno_, text):
    """A read-only file system or a full disk: one line naming the file, exit 2, nothing written.

    (Simulated: the tests run as root, whom file permissions do not stop.)
    """
    target = tmp_path / "r.json"

    def refuse(path, data):
        raise OSError(errno_, os.strerror(errno_), str(path))

    monkeypatch.setattr("kpioed_drake.outputs.atomic_write_bytes", refuse)
    design = str(files["design"])
    code = main(["evaluate", "--robot", "kr16", "--design", design, "--no-certify", "--json", str(target)])
    err = capsys.readouterr().err
    assert code == 2 and str(target) in err and text in err and "Traceback" not in err
    assert not target.exists()
