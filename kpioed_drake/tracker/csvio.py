"""Reading and writing design and result files, with validation (writes: :mod:`kpioed_drake.outputs`).

A design file is a CSV with a header and one row per pose, columns ``q1_deg`` ... ``q6_deg``
(other columns are kept but ignored). Errors name the file, the row (1-based, header = row 1)
and the column.
"""

from __future__ import annotations

import csv
import difflib
import io
import re
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.outputs import atomic_write_text
from kpioed_drake.robot.models import N_JOINTS, Robot

__all__ = [
    "Q_COLUMNS",
    "check_joint_angles",
    "design_csv_text",
    "jsonable",
    "parse_float_column",
    "parse_q_work",
    "q_columns",
    "q_from_file",
    "q_to_file",
    "OFFSET_COLUMNS",
    "read_condition_offsets",
    "read_csv_table",
    "read_design",
    "row_numbers",
    "write_design",
]

Q_COLUMNS = tuple(f"q{i}_deg" for i in range(1, N_JOINTS + 1))
"""Joint columns of the six-joint (revolute) robots."""
OFFSET_COLUMNS = {
    "temperature_C": "temperature_offset_K",
    "time_s": "time_offset_s",
    "payload_kg": "payload_offset_kg",
}
"""Columns of a measurement plan's design CSV (``kpioed design --discriminate`` for a temperature,
time or payload plan): each row's planned condition relative to block 1's, per measurement
condition (the payload: the mass added at the reflector point)."""


def q_columns(robot: Robot | None) -> tuple[str, ...]:
    """Joint columns of a robot's files: ``q{i}_deg`` (revolute, degrees) or ``q{i}_mm`` (prismatic,
    millimetres), one per joint; :data:`Q_COLUMNS` for None."""
    if robot is None:
        return Q_COLUMNS
    return tuple(f"q{i}_{'mm' if p else 'deg'}" for i, p in enumerate(robot.prismatic, start=1))


def q_from_file(robot: Robot | None, values) -> np.ndarray:
    """Joint values in file units (deg; prismatic mm) -> internal units (rad; mm)."""
    values = np.asarray(values, dtype=float)
    if robot is None:
        return np.deg2rad(values)
    return np.where(robot.prismatic, values, np.deg2rad(values))


def q_to_file(robot: Robot | None, q) -> np.ndarray:
    """Joint values in internal units (rad; prismatic mm) -> file units (deg; mm)."""
    q = np.asarray(q, dtype=float)
    if robot is None:
        return np.rad2deg(q)
    return np.where(robot.prismatic, q, np.rad2deg(q))


def jsonable(obj):
    """``obj`` as plain JSON data: numpy arrays and scalars to Python, NaN/inf to None, keys to str.

    JSON has no NaN; every result record of the package goes through this one function.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


class DataRows(list):
    """Data rows of a CSV table (lists of strings) with their line numbers in the file (``lines``)."""

    lines: list[int]


def row_numbers(data) -> list[int]:
    """File line numbers of the data rows (header = line 1 when the file has no blank lines)."""
    return list(getattr(data, "lines", range(2, len(data) + 2)))


def _read_text(path: Path) -> str:
    """The text of a UTF-8 file (a byte-order mark is dropped); other encodings are errors."""
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected a CSV file")
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    raw = path.read_bytes()
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in raw[:1000]:
        raise InputError(
            f"{path}: the file is UTF-16 (or binary); expected UTF-8 or ASCII text: save it as UTF-8"
        )
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(
            f"{path}: row {line}: not UTF-8 text (byte {raw[exc.start]:#04x}); save it as UTF-8"
        ) from None


WHITESPACE = "whitespace"
"""The separator of a file whose fields are separated by any run of spaces or tabs."""


def _split(text: str, delimiter: str) -> tuple[list[list[str]], list[int]]:
    """The non-blank rows of ``text`` split into fields, and their line numbers."""
    rows, lines = [], []
    if delimiter == WHITESPACE:
        for k, line in enumerate(text.splitlines(), 1):
            if line.split():
                rows.append(line.split())
                lines.append(k)
        return rows, lines
    reader = csv.reader(io.StringIO(text), delimiter=delimiter)
    for r in reader:
        if any(c.strip() for c in r):  # blank lines are skipped but keep their line numbers
            rows.append(r)
            lines.append(reader.line_num)
    return rows, lines


def _is_number(text: str) -> bool:
    try:
        float(text.replace(",", "."))
    except ValueError:
        return False
    return True


def read_csv_table(
    path: str | Path,
    required: tuple[str, ...],
    *,
    delimiter: str = ",",
    columns: list[str] | None = None,
) -> tuple[list[str], list[list[str]]]:
    """Read a CSV file with a header; check that ``required`` columns are present exactly once.

    Args:
        path: the file (UTF-8). required: column names that must be there.
        delimiter: the field separator (``","``; a format file may name another, or
            :data:`WHITESPACE`).
        columns: the column names of a file without a header row (then every row is data).

    Returns:
        header and the data rows (strings; ``.lines`` holds their file line numbers).

    Raises:
        InputError: an empty file, a first row of numbers where a header is expected (the file has
            no header), duplicate or missing columns, rows of another length.
    """
    text = _read_text(Path(path))
    rows, lines = _split(text, delimiter)
    if columns is not None:
        rows, lines = [list(columns), *rows], [0, *lines]
    if not rows:
        expected = f" with {', '.join(required)}" if required else ""
        raise InputError(f"{path}: the file is empty (expected a header{expected})")
    header = [h.strip() for h in rows[0]]
    tokens = [t for t in re.split(r"[\s;,]+", " ".join(header)) if t]
    if columns is None and tokens and all(_is_number(t) for t in tokens):
        raise InputError(
            f"{path}: row 1 is numbers ({', '.join(tokens[:3])}, ...), not a header: the file has no "
            "header row; describe it in a format file with header: false and columns: [...] "
            "(docs/data-formats.md)"
        )
    dup = sorted({h for h in header if header.count(h) > 1 and h})
    if dup:
        where = "format field 'columns'" if columns is not None else "row 1 (header)"
        raise InputError(f"{path}: {where}: column {dup[0]!r} appears more than once")
    missing = [c for c in required if c not in header]
    if missing and delimiter == "," and len(header) == 1 and ";" in header[0]:
        comma = " with decimal commas" if re.search(r"\d,\d", text) else ""
        raise InputError(
            f"{path}: row 1 (header): the columns are separated by ';'{comma}; expected a "
            "comma-separated file with decimal points (e.g. save it from the spreadsheet as CSV "
            "with ',' as separator)"
        )
    if missing:
        others = [h for h in header if h not in required]
        close = difflib.get_close_matches(missing[0], others, n=1, cutoff=0.6)
        hint = f" (found {close[0]!r}; expected exactly {missing[0]!r})" if close else ""
        raise InputError(f"{path}: row 1 (header): missing column {missing[0]!r}{hint}")
    data = DataRows(rows[1:])
    data.lines = lines[1:]
    for k, r in zip(data.lines, data, strict=True):
        if len(r) != len(header):
            hint = (
                ""
                if delimiter == ","
                else f" (separator {delimiter!r}; check the format file's 'separator' and 'decimal')"
            )
            names = "the format's columns name" if columns is not None else "the header has"
            raise InputError(f"{path}: row {k}: {len(r)} fields, {names} {len(header)}{hint}")
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
    lo, up = q_to_file(robot, robot.lower), q_to_file(robot, robot.upper)
    cols = q_columns(robot)
    rev = np.asarray(q_deg)[:, ~robot.prismatic]
    # Joints 4 and 6 range over +-350 deg, i.e. up to 6.1 rad: a table entirely within +-2 pi
    # (with some spread, more than three poses) is taken for radians.
    if len(q_deg) > 3 and np.ptp(rev) > 0 and np.all(np.abs(rev) <= 2.0 * np.pi + 1e-9):
        raise InputError(
            f"{path}: every joint value is within +-2 pi: the angles look like radians; "
            "columns q*_deg must hold degrees"
        )
    tol = 1e-6
    for k, row in zip(rows, q_deg, strict=True):
        for j in range(robot.n_joints):
            if not lo[j] - tol <= row[j] <= up[j] + tol:
                raise InputError(
                    f"{path}: row {k}, column {cols[j]!r}: {row[j]:g} {cols[j][-3:].strip('_')} is "
                    f"outside the joint range [{lo[j]:g}, {up[j]:g}] of {robot.name}"
                )


def read_design(path: str | Path, robot: Robot, *, check_limits: bool = True) -> np.ndarray:
    """Read a design CSV.

    Returns:
        q: (n, n_joints) joint values [rad; mm for prismatic joints].

    Raises:
        InputError: missing file or column, text or NaN in a cell, angles outside the limits.
    """
    qcols = q_columns(robot)
    header, data = read_csv_table(path, qcols)
    if not data:
        raise InputError(f"{path}: no poses (the file has only a header)")
    q_deg = np.stack([parse_float_column(path, header, data, c) for c in qcols], axis=1)
    if check_limits:
        check_joint_angles(path, q_deg, robot, rows=row_numbers(data))
    return q_from_file(robot, q_deg)


def read_condition_offsets(path: str | Path) -> dict[str, np.ndarray]:
    """A measurement plan's condition offsets in a design CSV (:data:`OFFSET_COLUMNS`).

    Returns:
        ``{"temperature_C": (n,) [K], "time_s": (n,) [s], "payload_kg": (n,) [kg]}``, only the
        columns the file has (``{}`` for a design without a plan).

    Raises:
        InputError: a cell of such a column that is not a finite number (file, row and column named).
    """
    header, data = read_csv_table(path, ())
    return {
        cond: parse_float_column(path, header, data, col)
        for cond, col in OFFSET_COLUMNS.items()
        if col in header
    }


def design_csv_text(
    q: np.ndarray, extra: dict[str, np.ndarray] | None = None, *, robot: Robot | None = None
) -> str:
    """CSV text of (n, n_joints) poses [rad] in degrees (prismatic joints in mm; ``robot`` None:
    six revolute joints), with optional extra columns."""
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
