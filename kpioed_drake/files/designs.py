"""Design files: the poses of an experiment, one per row, and a measurement plan's condition offsets.

A design file is a CSV with a header and one row per pose, columns ``q1_deg`` ... ``q6_deg`` (a
prismatic joint ``q{i}_mm``; other columns are kept but ignored), read through the one table reader
(:func:`kpioed_drake.files.tables.read_joint_table`): errors name the file, the row (1-based,
header = row 1) and the column. Writes are atomic (:mod:`kpioed_drake.outputs`).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files.tables import read_joint_table
from kpioed_drake.outputs import atomic_write_text
from kpioed_drake.robot.jointmap import q_columns, q_from_file, q_to_file
from kpioed_drake.robot.models import Robot

OFFSET_COLUMNS = {
    "temperature_C": "temperature_offset_K",
    "time_s": "time_offset_s",
    "payload_kg": "payload_offset_kg",
}
"""Columns of a measurement plan's design CSV (``kpioed design --discriminate`` for a temperature,
time or payload plan): each row's planned condition relative to block 1's, per measurement
condition (the payload: the mass added at the reflector point)."""
NO_POSES = "no poses (the file has only a header)"


def read_design(path: str | Path, robot: Robot, *, check_limits: bool = True) -> np.ndarray:
    """Read a design CSV.

    Returns:
        q: (n, n_joints) joint values [rad; mm for prismatic joints].

    Raises:
        InputError: missing file or column, text or NaN in a cell, angles outside the limits.
    """
    q = read_joint_table(path, robot, empty=NO_POSES, check_limits=check_limits).q
    assert q is not None  # the joint columns are required
    return q


def read_condition_offsets(path: str | Path) -> dict[str, np.ndarray]:
    """A measurement plan's condition offsets in a design CSV (:data:`OFFSET_COLUMNS`).

    Returns:
        ``{"temperature_C": (n,) [K], "time_s": (n,) [s], "payload_kg": (n,) [kg]}``, only the
        columns the file has (``{}`` for a design without a plan).

    Raises:
        InputError: a cell of such a column that is not a finite number (file, row and column named).
    """
    values = read_joint_table(path, None, joints="none", optional=tuple(OFFSET_COLUMNS.values()), empty=None)
    return {cond: values.values[col] for cond, col in OFFSET_COLUMNS.items() if col in values.values}


def design_csv_text(
    q: np.ndarray, extra: dict[str, np.ndarray] | None = None, *, robot: Robot | None = None
) -> str:
    """CSV text of (n, n_joints) poses [rad] in degrees (prismatic joints in mm; ``robot`` None:
    six revolute joints), with optional extra columns."""
    extra = extra or {}
    q_deg = q_to_file(robot, np.atleast_2d(q))
    cols = list(q_columns(robot)) + list(extra or {})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for k, row in enumerate(q_deg):
        vals = [f"{v:.6f}" for v in row]
        for name in extra or {}:
            x = extra[name][k]
            vals.append(str(x) if not isinstance(x, float | np.floating) else f"{x:.6g}")
        w.writerow(vals)
    return buf.getvalue()


def write_design(
    path: str | Path, q: np.ndarray, extra: dict[str, np.ndarray] | None = None, *, robot: Robot | None = None
) -> None:
    """Write (n, n_joints) poses [rad] as a design CSV in degrees (prismatic mm), atomically."""
    atomic_write_text(path, design_csv_text(q, extra, robot=robot))


def parse_q_work(text: str, robot: Robot) -> np.ndarray:
    """``--q-work q1,...,qn`` in degrees (prismatic mm) -> (n,) [rad, mm], checked against the limits."""
    nj = robot.n_joints
    try:
        vals = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise InputError(
            f"q_work_deg: expected {nj} comma-separated numbers (degrees), got {text!r}",
            fields=("q_work_deg",),
        ) from None
    if vals.shape != (nj,) or not np.all(np.isfinite(vals)):
        raise InputError(
            f"q_work_deg: expected {nj} finite comma-separated numbers in degrees, got {text!r}",
            fields=("q_work_deg",),
        )
    lo, up = q_to_file(robot, robot.lower), q_to_file(robot, robot.upper)
    for j in range(nj):
        if not lo[j] <= vals[j] <= up[j]:
            raise InputError(
                f"q_work_deg: joint {j + 1} = {vals[j]:g} deg is outside [{lo[j]:g}, {up[j]:g}] of "
                f"{robot.name}",
                fields=("q_work_deg",),
            )
    return q_from_file(robot, vals)
