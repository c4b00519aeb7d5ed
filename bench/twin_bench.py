"""Benchmark section 8: the 18-joint two-arm twin (``models/robots/humanoid18.urdf``).

Three jobs a humanoid user waits for, each timed once in this process:

- the 40-pose KPI design with its certificate (``kpioed design --criterion kpi --n 40``), with a
  cold certificate cache (an empty temporary folder: the search behind the bound runs) and warm
  (the search read from that folder), and without the certificate (``--no-certify``);
- one online step (``kpioed next``) at the 40 designed poses measured (simulated, 0.05 mm), warm;
- ``diagnose`` of 400 poses of the elastic twin stand-ins (``bench/humanoid.py``: joint elasticity
  of 9 joints; and with lateral compliance of the torso yaw and both shoulders; and the two-arm
  diagnosis stand-in of issue 46, lateral compliance of 8 bearings of the torso and both arms
  beside the 9 elasticities), validated on 100 held-out poses per hand. CPU: this process and the
  diagnosis's worker processes.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import humanoid
import numpy as np

from kpioed_drake.api import design
from kpioed_drake.design.approximate.certcache import CACHE_ENV
from kpioed_drake.online import NextOptions, next_poses
from kpioed_drake.robot.models import load_robot
from kpioed_drake.simulation import SimulationOptions, simulate
from kpioed_drake.tracker.data import Measurements

SECTION = "## 8. The 18-joint two-arm twin: design, online step, diagnosis"
TWIN = str(humanoid.ROBOTS / "humanoid18.urdf")
DESIGN_TARGET_S, EFFICIENCY_TARGET, NEXT_TARGET_S, DIAGNOSE_TARGET_S = 120.0, 0.97, 30.0, 60.0
NEXT_SIGMA_MM, NEXT_TARGET_VAR_MM2 = 0.05, 1.5e-3
"""Noise of the online step's simulated data [mm] and the precision it plans for [mm^2] (a few
poses more than the 40 measured)."""


def _timed(fn):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def _designs(cache: Path) -> tuple[list[str], dict, np.ndarray]:
    """Rows of the three designs (cold, warm, no certificate), the summary, the warm design's poses."""
    rows, summary = [], {}
    old = os.environ.get(CACHE_ENV)
    os.environ[CACHE_ENV] = str(cache)
    try:
        for label, certified in (("cold cache", True), ("warm cache", True), ("no certificate", False)):
            res, wall, cpu = _timed(lambda c=certified: design(TWIN, criterion="kpi", n=40, certify=c))
            eff = res.certificate["efficiency"] if res.certificate else None
            rows.append(
                f"| design, 40 poses, {label} | {wall:.1f} | {cpu:.1f} | "
                f"tr(Cs)/3 {res.kpi_avg_var_mm2:.4f} mm^2"
                + (f", efficiency {eff:.3f}" if eff is not None else "")
                + " |"
            )
            summary[label] = {"wall_s": wall, "efficiency": eff}
            print(rows[-1], file=sys.stderr, flush=True)
            if label == "warm cache":
                q = res.q
    finally:
        if old is None:
            os.environ.pop(CACHE_ENV, None)
        else:
            os.environ[CACHE_ENV] = old
    return rows, summary, q


def _online(q: np.ndarray) -> tuple[str, float]:
    """The row of a warm online step at the poses ``q`` measured, and its wall time."""
    robot = load_robot(TWIN)
    table, _ = simulate(robot, q, SimulationOptions(sigma_mm=NEXT_SIGMA_MM, seed=1))
    data = Measurements.from_table(table, robot)
    opts = NextOptions(target_var_mm2=NEXT_TARGET_VAR_MM2, sigma_mm=NEXT_SIGMA_MM)
    next_poses(robot, data, opts)  # fills the certificate cache of the step's setup
    res, wall, cpu = _timed(lambda: next_poses(robot, data, opts))
    after = "done"
    if not res.done:
        after = f"{len(res.q_next)} next poses -> {res.predicted_kpi_avg_var_mm2:.2e} mm^2"
    row = (
        f"| `next` at {len(q)} measured poses, warm | {wall:.1f} | {cpu:.1f} | "
        f"tr(Cs)/3 {res.kpi_avg_var_mm2:.2e} mm^2, {after} |"
    )
    return row, wall


DIAGNOSES = (
    ("elastic twin", {"lateral": False}),
    ("elastic + lateral twin", {"lateral": True}),
    ("two-arm stand-in (elastic 9 joints + lateral 8 bearings)", {"spread": True}),
)
"""The diagnosis rows: label and :func:`humanoid.measure`'s stand-in."""


def _diagnoses(folder: Path) -> tuple[list[str], float]:
    """Rows of the twin diagnoses and the slowest one's wall time."""
    rows, slowest = [], 0.0
    for k, (label, kind) in enumerate(DIAGNOSES):
        sub = folder / f"diagnosis{k}"
        sub.mkdir()
        m = humanoid.measure(sub, twin=True, **kind)
        g, e = m["geometric_per_target_mm"], m["extended_per_target_mm"]
        rows.append(
            f"| `diagnose`, 400 poses, {label} | {m['diagnose_s']:.1f} | {m['diagnose_cpu_s']:.1f} | "
            f"{len(m['named'])} effects; held-out mean per hand {g[0]:.2f} / {g[1]:.2f} -> "
            f"{e[0]:.2f} / {e[1]:.2f} mm |"
        )
        print(rows[-1], file=sys.stderr, flush=True)
        slowest = max(slowest, m["diagnose_s"])
    return rows, slowest


def bench_section() -> tuple[list[str], dict]:
    """The Markdown rows and a summary (the targets' measured values)."""
    rows = ["| job | wall [s] | CPU [s] | result |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        d_rows, summary, q = _designs(Path(tmp) / "cache")
        rows += d_rows
        row, summary["next_s"] = _online(q)
        rows.append(row)
        print(row, file=sys.stderr, flush=True)
        g_rows, summary["diagnose_s"] = _diagnoses(Path(tmp))
        rows += g_rows
    return rows, summary


def targets_lines(summary: dict) -> list[str]:
    """The section's targets, met or not."""
    warm = summary["warm cache"]

    def ok(cond):
        return "met" if cond else "NOT met"

    return [
        f"- twin's 40-pose design <= {DESIGN_TARGET_S:.0f} s and efficiency >= {EFFICIENCY_TARGET}: "
        f"measured {warm['wall_s']:.0f} s warm ({summary['cold cache']['wall_s']:.0f} s with a cold "
        f"certificate cache), efficiency {warm['efficiency']:.3f} "
        f"({ok(warm['wall_s'] <= DESIGN_TARGET_S and warm['efficiency'] >= EFFICIENCY_TARGET)})",
        f"- twin's warm `next` step <= {NEXT_TARGET_S:.0f} s: measured {summary['next_s']:.1f} s "
        f"({ok(summary['next_s'] <= NEXT_TARGET_S)})",
        f"- twin's 400-pose diagnosis <= {DIAGNOSE_TARGET_S:.0f} s: slowest measured "
        f"{summary['diagnose_s']:.1f} s ({ok(summary['diagnose_s'] <= DIAGNOSE_TARGET_S)})",
    ]


def section_lines(rows: list[str], summary: dict) -> list[str]:
    """The whole Markdown section."""
    return [
        SECTION,
        "",
        *rows,
        "",
        *targets_lines(summary),
        "",
        f"One run of each job in this process (`bench/twin_bench.py`). Load average after these rows: "
        f"{os.getloadavg()[0]:.2f}.",
        "",
    ]
