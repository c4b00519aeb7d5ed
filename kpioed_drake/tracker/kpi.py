"""The KPI's inputs (paper eq. 12, 24e, Outlook) and what a pose measures, checked once for
:func:`kpioed_drake.estimation.problem.make_problem`: the cell with its incidence limit, the working
poses (K, n_joints) and their weights, the KPI point, the measurement (``point`` or a 6-DoF probe's
``pose``), its orientation noise and the orientation's weight in the KPI (the length L [mm] at which
an angle counts as the displacement ``L * angle``).

Units: working poses [rad], noise of the orientation [deg] as given, L [mm].
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Cell, Robot, load_cell

KPI_AGGREGATES = ("mean", "max")
"""How the variances of several working poses make the KPI: weighted mean or the worst."""
KPI_POINTS = ("reflector", "flange")
"""Where the KPI point sits: the reflector (plus ``tool_offset``; SPEC) or the flange origin (the
paper's TCP frame k, which does not move with the reflector offset)."""
MEASURES = ("point", "pose")
"""What a pose measures: the reflector's position (3 rows) or a 6-DoF probe's pose (6 rows)."""
SIGMA_ROT_DEG = 0.005
"""Default noise of a 6-DoF probe's orientation per tracker axis [deg] (docs/design.md, "pose
measurements")."""


def checked_cell(robot: Robot, cell_path: Path | str | None, max_incidence_deg: float | None) -> Cell:
    """The robot's cell, with ``max_incidence_deg`` (checked in (0, 90) deg) if given."""
    cell = load_cell(cell_path, robot=robot)
    if max_incidence_deg is not None:
        if not 0 < max_incidence_deg < 90:
            raise InputError(f"max_incidence_deg must be in (0, 90) deg, got {max_incidence_deg!r}")
        cell = dataclasses.replace(cell, max_incidence=float(np.deg2rad(max_incidence_deg)))
    return cell


def checked_q_work(robot: Robot, q_work: np.ndarray | None) -> np.ndarray:
    """The working pose(s) [rad], (n_joints,) or (K, n_joints), within the joint limits (default: the
    model file's)."""
    if q_work is None:
        if robot.q_work is None:
            where = "q_work in its sidecar" if robot.urdf is not None else "working pose"
            raise InputError(
                f"{robot.name}: the model file has no {where}; pass q_work_deg", fields=("q_work_deg",)
            )
        q_work = robot.q_work
    q_work = np.asarray(q_work, dtype=float)
    if q_work.ndim == 2 and q_work.shape[0] == 1:
        q_work = q_work[0]
    nj = robot.n_joints
    if q_work.shape[-1:] != (nj,) or q_work.ndim > 2 or not np.all(np.isfinite(q_work)):
        raise InputError(
            f"{robot.name}: q_work must be ({nj},) or (K, {nj}) finite angles [rad], got {q_work.shape}"
        )
    if np.any(q_work < robot.lower - 1e-9) or np.any(q_work > robot.upper + 1e-9):
        raise InputError(f"{robot.name}: q_work is outside the joint limits")
    return q_work


def kpi_weights_checked(kpi_weights, k: int, aggregate: str) -> np.ndarray | None:
    """Checked, normalised (K,) weights of K working poses (None for one pose with no weights)."""
    if aggregate not in KPI_AGGREGATES:
        raise InputError(
            f"kpi_aggregate must be one of {', '.join(KPI_AGGREGATES)}, got {aggregate!r}",
            fields=("kpi_aggregate",),
        )
    if kpi_weights is None:
        return None if k == 1 else np.full(k, 1.0 / k)
    w = np.asarray(kpi_weights, dtype=float).reshape(-1)
    if w.shape != (k,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise InputError(
            f"kpi_weights: expected {k} positive numbers (one per working pose), got {w.tolist()}",
            fields=("kpi_weights",),
        )
    if aggregate == "max" and not np.allclose(w, w[0]):
        raise InputError(
            "kpi_weights: the worst case (kpi_aggregate max) takes no weights",
            fields=("kpi_weights", "kpi_aggregate"),
        )
    return w / w.sum()


def check_kpi_point(kpi_point: str, tool_offset_mm: Sequence[float] | np.ndarray) -> None:
    """InputError for an unknown KPI point, or a tool offset with the flange as KPI point."""
    if kpi_point not in KPI_POINTS:
        raise InputError(f"kpi_point must be one of {', '.join(KPI_POINTS)}, got {kpi_point!r}")
    if kpi_point == "flange" and np.any(np.asarray(tool_offset_mm, dtype=float) != 0):
        raise InputError("kpi_point 'flange' is the flange origin itself: it takes no tool offset")


def check_measure(
    measure: str, sigma_deg: float | None, kpi_orientation_mm: float, *, n_targets: int, n_effects: int
) -> float | None:
    """The orientation noise [rad] of ``pose`` measurements (default :data:`SIGMA_ROT_DEG`; None
    for ``point``), after checking the measurement, the noise (> 0 [deg]) and L (>= 0 [mm]).

    Raises:
        InputError: an unknown measurement, a bad noise or L, or ``pose`` with several targets or
            model extensions (their orientation rows are not modelled).
    """
    if measure not in MEASURES:
        raise InputError(
            f"measure must be one of {', '.join(MEASURES)}, got {measure!r}", fields=("measure",)
        )
    L = float(kpi_orientation_mm) if isinstance(kpi_orientation_mm, int | float) else math.nan
    if not (math.isfinite(L) and L >= 0):
        raise InputError(
            f"kpi_orientation_mm must be a length >= 0 [mm], got {kpi_orientation_mm!r}",
            fields=("kpi_orientation_mm",),
        )
    if L > 0 and n_effects:
        raise InputError(
            "kpi_orientation_mm: the TCP's orientation with model extensions is not modelled",
            fields=("kpi_orientation_mm", "extend"),
        )
    if measure == "point":
        if sigma_deg is not None:
            raise InputError(
                "sigma_deg is the orientation noise of pose measurements", fields=("sigma_deg", "measure")
            )
        return None
    s = SIGMA_ROT_DEG if sigma_deg is None else sigma_deg
    if not (isinstance(s, int | float) and math.isfinite(s) and s > 0):
        raise InputError(
            f"sigma_deg must be a positive number of degrees, got {sigma_deg!r}", fields=("sigma_deg",)
        )
    if n_targets > 1 or n_effects:
        raise InputError(
            "pose measurements: one probe (no further targets) and no model extensions (their "
            "orientation rows are not modelled)",
            fields=("measure", "extend"),
        )
    return math.radians(float(s))
