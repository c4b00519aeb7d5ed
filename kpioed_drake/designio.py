"""Reading and writing design and result files, with validation and atomic writes.

A design file is a CSV with a header and one row per pose, columns ``q1_deg`` ... ``q6_deg``
(other columns are kept but ignored). Errors name the file, the row (1-based, header = row 1)
and the column.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.models import N_JOINTS, Robot

Q_COLUMNS = tuple(f"q{i}_deg" for i in range(1, N_JOINTS + 1))


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_json(path: str | Path, data) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


class DataRows(list):
    """Data rows of a CSV table (lists of strings) with their line numbers in the file (``lines``)."""

    lines: list[int]


def row_numbers(data) -> list[int]:
    """File line numbers of the data rows (header = line 1 when the file has no blank lines)."""
    return list(getattr(data, "lines", range(2, len(data) + 2)))


def read_csv_table(path: str | Path, required: tuple[str, ...]) -> tuple[list[str], list[list[str]]]:
    """Read a CSV file with a header; check that ``required`` columns are present exactly once.

    Returns:
        header and the data rows (strings).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    text = path.read_text(encoding="utf-8-sig", errors="replace")
    rows, lines = [], []
    reader = csv.reader(io.StringIO(text))
    for r in reader:
        if any(c.strip() for c in r):  # blank lines are skipped but keep their line numbers
            rows.append(r)
            lines.append(reader.line_num)
    if not rows:
        raise InputError(f"{path}: the file is empty (expected a header with {', '.join(required)})")
    header = [h.strip() for h in rows[0]]
    dup = sorted({h for h in header if header.count(h) > 1 and h})
    if dup:
        raise InputError(f"{path}: row 1 (header): column {dup[0]!r} appears more than once")
    missing = [c for c in required if c not in header]
    if missing:
        others = [h for h in header if h not in required]
        close = difflib.get_close_matches(missing[0], others, n=1, cutoff=0.6)
        hint = f" (found {close[0]!r}; expected exactly {missing[0]!r})" if close else ""
        raise InputError(f"{path}: row 1 (header): missing column {missing[0]!r}{hint}")
    data = DataRows(rows[1:])
    data.lines = lines[1:]
    for k, r in zip(data.lines, data, strict=True):
        if len(r) != len(header):
            raise InputError(f"{path}: row {k}: {len(r)} fields, the header has {len(header)}")
    return header, data


def parse_float_column(path, header, data, column: str) -> np.ndarray:
    """Column ``column`` as floats; text, empty cells, NaN and infinities are errors."""
    j = header.index(column)
    out = np.empty(len(data))
    for i, (k, r) in enumerate(zip(row_numbers(data), data, strict=True)):
        cell = r[j].strip()
        try:
            v = float(cell)
        except ValueError:
            raise InputError(f"{path}: row {k}, column {column!r}: {cell!r} is not a number") from None
        if not np.isfinite(v):
            raise InputError(f"{path}: row {k}, column {column!r}: {cell!r} is not a finite number")
        out[i] = v
    return out


def check_joint_angles(path, q_deg: np.ndarray, robot: Robot, *, rows=None) -> None:
    """Angles within the robot's limits; a table that looks like radians gets a clear message.

    Args:
        rows: file line numbers of the rows (default 2, 3, ...).
    """
    rows = list(range(2, len(q_deg) + 2)) if rows is None else list(rows)
    lo, up = np.rad2deg(robot.lower), np.rad2deg(robot.upper)
    # Joints 4 and 6 range over +-350 deg, i.e. up to 6.1 rad: a table entirely within +-2 pi
    # (with some spread, more than three poses) is taken for radians.
    if len(q_deg) > 3 and np.ptp(q_deg) > 0 and np.all(np.abs(q_deg) <= 2.0 * np.pi + 1e-9):
        raise InputError(
            f"{path}: every joint value is within +-2 pi: the angles look like radians; "
            "columns q*_deg must hold degrees"
        )
    tol = 1e-6
    for k, row in zip(rows, q_deg, strict=True):
        for j in range(N_JOINTS):
            if not lo[j] - tol <= row[j] <= up[j] + tol:
                raise InputError(
                    f"{path}: row {k}, column {Q_COLUMNS[j]!r}: {row[j]:g} deg is outside "
                    f"the joint range [{lo[j]:g}, {up[j]:g}] of {robot.name}"
                )


def read_design(path: str | Path, robot: Robot, *, check_limits: bool = True) -> np.ndarray:
    """Read a design CSV.

    Returns:
        q: (n, 6) joint angles [rad].

    Raises:
        InputError: missing file or column, text or NaN in a cell, angles outside the limits.
    """
    header, data = read_csv_table(path, Q_COLUMNS)
    if not data:
        raise InputError(f"{path}: no poses (the file has only a header)")
    q_deg = np.stack([parse_float_column(path, header, data, c) for c in Q_COLUMNS], axis=1)
    if check_limits:
        check_joint_angles(path, q_deg, robot, rows=row_numbers(data))
    return np.deg2rad(q_deg)


def design_csv_text(q: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> str:
    """CSV text of (n, 6) poses [rad] in degrees, with optional extra columns."""
    q_deg = np.rad2deg(np.atleast_2d(q))
    cols = list(Q_COLUMNS) + list(extra or {})
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


def write_design(path: str | Path, q: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write (n, 6) poses [rad] as a design CSV in degrees, atomically."""
    atomic_write_text(path, design_csv_text(q, extra))


def parse_q_work(text: str, robot: Robot) -> np.ndarray:
    """``--q-work q1,...,q6`` in degrees -> (6,) [rad], checked against the joint limits."""
    try:
        vals = np.array([float(x) for x in text.split(",")])
    except ValueError:
        raise InputError(f"--q-work: expected 6 comma-separated numbers in degrees, got {text!r}") from None
    if vals.shape != (N_JOINTS,) or not np.all(np.isfinite(vals)):
        raise InputError(f"--q-work: expected 6 finite comma-separated numbers in degrees, got {text!r}")
    lo, up = np.rad2deg(robot.lower), np.rad2deg(robot.upper)
    for j in range(N_JOINTS):
        if not lo[j] <= vals[j] <= up[j]:
            raise InputError(
                f"--q-work: joint {j + 1} = {vals[j]:g} deg is outside [{lo[j]:g}, {up[j]:g}] of {robot.name}"
            )
    return np.deg2rad(vals)
