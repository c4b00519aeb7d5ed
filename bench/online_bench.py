"""Benchmark section 7: one online step (``kpioed next``) at 100 measured poses, kr16.

The step calibrates, evaluates tr(Cs)/3 and designs 5 next poses with the 100 held fixed; the
certificate of the combined design is the expensive part. Timed three times in this process (the
first call fills the certificate cache, the others find it warm), and once without the certificate.
"""

from __future__ import annotations

import os
import time

import numpy as np

from kpioed_drake.online import NextOptions, next_poses
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate
from kpioed_drake.tracker.data import Measurements

SECTION = "## 7. Online step (`kpioed next`) at 100 measured poses (kr16, 5 next poses)"
TARGET_S = 5.0


def bench_section() -> tuple[list[str], dict]:
    """The Markdown rows and a summary {"warm_s": the slowest warm call with the certificate}."""
    robot = load_robot("kr16")
    q = np.random.default_rng(1).uniform(robot.lower, robot.upper, size=(100, 6))
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=1.0, seed=1))
    data = Measurements.from_table(table, robot)
    rows = ["| call | certificate | wall [s] |", "|---|---|---|"]
    walls = []
    for k, certify in enumerate((True, True, True, False)):
        t0 = time.perf_counter()
        next_poses(robot, data, NextOptions(target_var_mm2=1e-3, sigma_mm=1.0, certify=certify))
        wall = time.perf_counter() - t0
        rows.append(f"| {k + 1} | {'yes' if certify else 'no'} | {wall:.2f} |")
        if certify and k > 0:
            walls.append(wall)
    return rows, {"warm_s": max(walls)}


def section_lines(rows: list[str], summary: dict) -> list[str]:
    """The whole Markdown section."""
    ok = "met" if summary["warm_s"] <= TARGET_S else "NOT met"
    return [
        SECTION,
        "",
        *rows,
        "",
        f"Target: each call within {TARGET_S:g} s with the certificate cache warm: slowest warm call "
        f"{summary['warm_s']:.2f} s ({ok}). Load average after these rows: {os.getloadavg()[0]:.2f}.",
        "",
    ]
