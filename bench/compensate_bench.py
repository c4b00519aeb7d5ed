"""Benchmark rows of ``kpioed compensate`` on 1000 program rows.

The calibrated models come from simulated kr16 data (the study's 60-pose KPI design
``studies/results/designs/kr16_kpi_ca.csv``, seed 0: SPEC-size geometric errors, an elastic joint
2, noise N(0, 0.02 mm)): the geometric calibration's model file (``kpioed calibrate --out``) and the
extended fit (``calibrate`` with ``effects=["joint_elasticity:2"]``). The program: 1000 poses drawn
uniformly within 90 % of each joint's range (seed 1, singular ones included: those the calibrated
arm cannot reach are written marked, ``--allow-unreachable``). Rows:

- ``kpioed compensate --program`` in a fresh process (wall time includes Python and Drake), with the
  geometric model file, and with the elasticity given as ``--effect`` (Drake gravity torques and
  their derivatives at every iteration);
- ``api.compensate`` in this process with the extended fit's report (geometry and elasticity);
- ``kpioed compensate --targets``: the nominal points of the same poses, started from their joints.

Used by ``bench/run_bench.py`` (section "Compensation of 1000 program rows"; ``--only compensate``
runs these rows alone and replaces just that section of ``bench/results.md``).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from fits_bench import replace_section, run_command

from kpioed_drake import api
from kpioed_drake.calibration import CalibrationOptions, calibrate, calibrated_robot_yaml
from kpioed_drake.compensation.solve import model_pose
from kpioed_drake.files.designs import read_design, write_design
from kpioed_drake.outputs import atomic_write_text
from kpioed_drake.robot.jointmap import q_columns
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model

REPO = Path(__file__).resolve().parents[1]
DESIGN = REPO / "studies" / "results" / "designs" / "kr16_kpi_ca.csv"
N_ROWS = 1000
TARGET_S = 10.0
"""Wall-time target of 1000 program rows [s] (2-core machine)."""
SECTION = "## 5. Compensation of 1000 program rows"


def _inputs(folder: Path) -> dict:
    """The model file, the extended fit's report, the program and the target file."""
    robot = load_robot("kr16")
    table, _ = simulate(
        robot,
        read_design(DESIGN, robot),
        SimulationOptions(sigma_mm=0.02, seed=0, effects=["joint_elasticity:2"]),
    )
    data = Measurements.from_table(table, robot)
    model_file = folder / "kr16-cal.yaml"
    model_file.write_text(calibrated_robot_yaml(calibrate(robot, data, CalibrationOptions(sigma_mm=0.02))))
    extended = calibrate(
        robot, data, CalibrationOptions(sigma_mm=0.02, effects=["joint_elasticity:2"])
    ).to_dict()
    span = robot.upper - robot.lower
    q = robot.lower + span * np.random.default_rng(1).uniform(0.05, 0.95, (N_ROWS, robot.n_joints))
    write_design(folder / "program.csv", q, robot=robot)
    points = model_pose(nominal_model(robot, load_cell(robot=robot)), q)[0]
    targets = pd.DataFrame(np.rad2deg(q), columns=q_columns(robot))
    targets[["x_mm", "y_mm", "z_mm"]] = points
    targets.to_csv(folder / "targets.csv", index=False)
    effect = f"joint_elasticity:2={extended['effects'][0]['value']!r}"
    return {"model": str(model_file), "extended": extended, "effect": effect}


def _row(label: str, wall: float, cpu: float | None, out: Path) -> tuple[str, float]:
    t = pd.read_csv(out)
    cpu_text = f"{cpu:.2f}" if cpu is not None else "-"
    return (
        f"| {label} | {wall:.2f} | {cpu_text} | {int(t['reachable'].sum())} of {len(t)} | "
        f"{t['dq_deg'].median():.3f} |",
        wall,
    )


def bench_compensate() -> tuple[list[str], dict]:
    """The Markdown rows of the section and a summary {"wall_s": the slowest program row}."""
    rows = [
        "| run | wall [s] | CPU [s] | rows reached | median correction [deg] |",
        "|---|---|---|---|---|",
    ]
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        inp = _inputs(folder)
        program = ["compensate", "--robot", inp["model"], "--program", str(folder / "program.csv")]
        for label, extra in (
            ("kpioed, geometric model file", []),
            ("kpioed, + --effect elasticity", ["--effect", inp["effect"]]),
        ):
            print(f"compensate: {label} ...", file=sys.stderr, flush=True)
            m = run_command([*program, *extra, "--allow-unreachable", "--out", str(folder / "q.csv")])
            row, wall = _row(label, m["wall_s"], m["cpu_s"], folder / "q.csv")
            rows.append(row)
            walls.append(wall)
        t0, c0 = time.perf_counter(), time.process_time()
        api.compensate(
            "kr16",
            program=folder / "program.csv",
            out=folder / "q_api.csv",
            effects=inp["extended"],
            allow_unreachable=True,
        )
        row, wall = _row(
            "api.compensate, extended fit (in process)",
            time.perf_counter() - t0,
            time.process_time() - c0,
            folder / "q_api.csv",
        )
        rows.append(row)
        walls.append(wall)
        targets = ["compensate", "--robot", inp["model"], "--targets", str(folder / "targets.csv")]
        m = run_command([*targets, "--allow-unreachable", "--out", str(folder / "q_t.csv")])
        rows.append(
            _row("kpioed --targets, from the rows' joints", m["wall_s"], m["cpu_s"], folder / "q_t.csv")[0]
        )
    return rows, {"wall_s": max(walls)}


def targets_lines(summary: dict) -> list[str]:
    """The 'Targets' line of these rows."""
    w = summary["wall_s"]
    return [
        f"- compensate 1000 program rows <= {TARGET_S:g} s: slowest {w:.2f} s "
        f"({'met' if w <= TARGET_S else 'NOT met'})"
    ]


def section_lines(rows: list[str], summary: dict) -> list[str]:
    """The whole Markdown section."""
    load = os.getloadavg()[0]
    note = (
        "Models from simulated kr16 data (60-pose KPI design, seed 0, elastic joint 2); 1000 program poses "
        "uniform within 90 % of the joint ranges (seed 1), singular ones included (those the calibrated arm "
        "cannot reach are written marked). `kpioed` rows: a fresh process as in section 4 (Python and "
        "Drake imports included); the API row: this process, the extended fit's geometry and elasticity. "
        f"Load average after these rows: {load:.2f}."
    )
    return [SECTION, "", *rows, "", note, "", *targets_lines(summary), ""]


def update_results(out: str | Path) -> list[str]:
    """Run these rows alone and replace (or insert) their section in the results file ``out``."""
    rows, summary = bench_compensate()
    section = section_lines(rows, summary)
    path = Path(out)
    atomic_write_text(path, replace_section(path.read_text(), section, SECTION))
    return section
