"""The one reader of tables of joint columns and optional columns (CSV text -> arrays).

Every table the package reads goes through :func:`read_joint_table`: measurement files, design
files, programs and target files of ``kpioed compensate``, a plan's condition offsets. A table is
UTF-8 text with a header and one row per pose; joint columns ``q{i}_deg`` [deg] (prismatic
``q{i}_mm`` [mm], :func:`kpioed_drake.robot.jointmap.q_columns`); inside, radians and millimetres.

Measurement files (:func:`read_measurement_table`) come in two formats of the one reader
(:data:`MEASUREMENT_FORMATS`): the native CSV of SPEC (joint columns, ``x_mm``, ``y_mm``, ``z_mm``
in the tracker frame T [mm] (eta of paper eq. 3), optional ``temperature_C``, ``time_s``,
``payload_kg`` and ``target``: the target (SMR) numbered 1..T without gaps, 0-based inside) and a
layout a format file describes (:mod:`kpioed_drake.files.formats`); a 6-DoF probe's orientation
columns, in either: :mod:`kpioed_drake.files.orientation_columns`. Messages name the file, the row
(:data:`ROW_CONVENTION`) and the column.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import io
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files import orientation_columns as oc
from kpioed_drake.files.formats import ANGLE_UNITS, LENGTH_UNITS, TIME_UNITS, WHITESPACE, DataFormat
from kpioed_drake.robot.jointmap import FileJoints, file_joints, joints_from_file
from kpioed_drake.robot.models import Robot

XYZ_COLUMNS = ("x_mm", "y_mm", "z_mm")
"""The reflector position columns of the native measurement file [mm]."""
OPTIONAL_COLUMNS = ("temperature_C", "time_s", "payload_kg")
"""The measurement conditions a native file (and a program) may carry."""
TARGET_COLUMN = "target"
"""Optional integer column: the target (SMR) of the row, 1..T in files, 0-based inside."""
ROW_CONVENTION = "CSV record number, header = row 1 (data row k is row k + 1; blank lines not counted)"
NO_ROWS = "no data rows (the file has only a header)"
_OPERATOR = re.compile(r"\s+([+-])\s+")


class DataRows(list):
    """Data rows of a CSV table (lists of strings) with their line numbers in the file (``lines``)."""

    lines: list[int]


def row_numbers(data: list) -> list[int]:
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
            :data:`~kpioed_drake.files.formats.WHITESPACE`).
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
            sep = f" (separator {delimiter!r}; check the format file's 'separator' and 'decimal')"
            hint = "" if delimiter == "," else sep
            names = "the format's columns name" if columns is not None else "the header has"
            raise InputError(f"{path}: row {k}: {len(r)} fields, {names} {len(header)}{hint}")
    return header, data


def _numbers(path, header, data, column: str, decimal: str = ".") -> np.ndarray:
    """Column ``column`` as floats (a decimal comma read as a point with ``decimal=","``).

    Raises:
        InputError: text, an empty cell, NaN or an infinity (file, row and column named).
    """
    j = header.index(column)
    out = np.empty(len(data))
    for i, (k, r) in enumerate(zip(row_numbers(data), data, strict=True)):
        cell = r[j].strip()
        try:
            out[i] = float(cell.replace(",", ".") if decimal == "," else cell)
        except ValueError:
            raise InputError(f"{path}: row {k}, column {column!r}: {cell!r} is not a number") from None
        if not np.isfinite(out[i]):
            raise InputError(f"{path}: row {k}, column {column!r}: {cell!r} is not a finite number")
    return out


def parse_targets(
    path: str | Path,
    values: np.ndarray,
    rows: np.ndarray,
    *,
    column: str = TARGET_COLUMN,
    n_targets: int | None = None,
    model: str = "",
) -> np.ndarray:
    """(n,) 0-based target indices of a file's target column (numbered 1..T without gaps).

    Args:
        path: the file (for messages); values: (n,) the column as read; rows: (n,) row numbers.
        column: the column's name in the file; n_targets: the targets the robot model defines
            (None: not checked), model: its file or name, for messages.

    Raises:
        InputError: naming the file, row and column: a value that is not a whole number >= 1, a
            gap in the numbering, or a target beyond the model's ``targets_mm``.
    """
    values = np.asarray(values, dtype=float)
    bad = np.flatnonzero(~np.isfinite(values) | (values != np.round(values)) | (values < 1))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{path}: row {rows[k]}, column {column!r}: {values[k]:g} is not a target number "
            "(whole numbers 1, 2, ..., T)"
        )
    t = values.astype(int)
    missing = sorted(set(range(1, int(t.max()) + 1)) - set(t.tolist())) if t.size else []
    if missing:
        k = int(np.flatnonzero(t > missing[0])[0])
        raise InputError(
            f"{path}: row {rows[k]}, column {column!r}: target {t[k]} is used but target {missing[0]} "
            f"is not: targets are numbered 1..T without gaps"
        )
    if n_targets is not None and t.size and t.max() > n_targets:
        k = int(np.argmax(t))
        raise InputError(
            f"{path}: row {rows[k]}, column {column!r}: target {t[k]}, but the robot model "
            f"{model} defines {n_targets} target(s) (field targets_mm)"
        )
    return t - 1


def _near_name(a: str, b: str) -> bool:
    """Case/underscore-insensitive equality or one edit apart (a likely misspelling)."""
    a2, b2 = a.lower().replace(" ", "").replace("-", "_"), b.lower()
    if a2 == b2:
        return True
    if abs(len(a2) - len(b2)) > 1:
        return False
    if len(a2) == len(b2):
        return sum(x != y for x, y in zip(a2, b2, strict=True)) <= 1
    short, long_ = (a2, b2) if len(a2) < len(b2) else (b2, a2)
    return any(long_[:i] + long_[i + 1 :] == short for i in range(len(long_)))


def _check_names(path, header, known, suggest: tuple[str, ...]) -> None:
    """No unknown column one edit from a ``suggest`` column (a misspelled optional column)."""
    for h in header:
        near = next((s for s in suggest if h not in known and _near_name(h, s)), None)
        if near is not None:
            raise InputError(
                f"{path}: row 1 (header): unknown column {h!r}; did you mean {near!r}? "
                f"(optional columns: {', '.join(suggest)})"
            )


def _check_payload(path, payload, rows, column: str) -> None:
    if payload is not None and np.any(payload < 0):
        row = rows[int(np.flatnonzero(payload < 0)[0])]
        raise InputError(f"{path}: row {row}, column {column!r}: a payload cannot be negative")


@dataclasses.dataclass(frozen=True)
class JointTable:
    """A table of joint columns and other columns (:func:`read_joint_table`).

    Attributes:
        path: the file; header: its columns; data: its rows as text (``.lines``: line numbers).
        rows: (n,) row numbers (:data:`ROW_CONVENTION`).
        q: (n, n_joints) model joint values [rad; prismatic mm], or None without joint columns.
        values: ``{column: (n,)}`` the other columns read, as numbers in file units.
        target: (n,) 0-based targets of a ``target`` column, or None.
        joints: the robot's :class:`~kpioed_drake.robot.jointmap.FileJoints` (None without a robot).
    """

    path: str
    header: list[str]
    data: list[list[str]]
    rows: np.ndarray
    q: np.ndarray | None
    values: dict
    target: np.ndarray | None
    joints: FileJoints | None


def read_joint_table(
    path: str | Path,
    robot: Robot | None,
    *,
    joints: str = "required",
    required: tuple[str, ...] = (),
    optional: tuple[str, ...] = (),
    angles: str = "model",
    check_limits: bool = True,
    empty: str | None = NO_ROWS,
    suggest: tuple[str, ...] = (),
) -> JointTable:
    """Read a table of the robot's joint columns (:func:`~kpioed_drake.robot.jointmap.q_columns`)
    and other number columns.

    Args:
        path: the CSV file; robot: the model (None with ``joints="none"``).
        joints: ``"required"``, ``"optional"`` (all joint columns or none) or ``"none"``.
        required: other columns the file must have; optional: columns read where present (a
            ``target`` column as target numbers, ``payload_kg`` >= 0).
        angles: ``"model"`` or ``"controller"`` (the joint map turns them into the model's).
        check_limits: check the joint values against the robot's limits.
        empty: the message of a file without data rows (None: such a file is read).
        suggest: optional columns whose misspelling (one edit) in the header is an error.

    Raises:
        InputError: naming the file, row and column (missing, misspelled, duplicated column; text,
            NaN or infinity in a number field; angles outside the limits or that look like radians;
            a negative payload; target numbers with gaps or beyond the model's).
    """
    spec = None if joints == "none" else file_joints(robot)
    qcols = spec.columns if spec is not None else ()
    header, data = read_csv_table(path, (qcols if joints == "required" else ()) + tuple(required))
    _check_names(path, header, {*qcols, *required, *optional}, suggest)
    if empty and not data:
        raise InputError(f"{path}: {empty}")
    rows = np.asarray(row_numbers(data))
    given = [c for c in qcols if c in header]
    if given and len(given) < len(qcols):
        missing = next(c for c in qcols if c not in header)
        raise InputError(
            f"{path}: row 1 (header): missing column {missing!r} "
            f"(start joints need all of {', '.join(qcols)})"
        )
    q_file = np.stack([_numbers(path, header, data, c) for c in qcols], axis=1) if given else None
    read = [*required, *(c for c in optional if c in header and c != TARGET_COLUMN)]
    values = {c: _numbers(path, header, data, c) for c in read}
    target = None
    if spec is not None and TARGET_COLUMN in optional and TARGET_COLUMN in header:
        numbers = _numbers(path, header, data, TARGET_COLUMN)
        target = parse_targets(path, numbers, rows, n_targets=spec.n_targets, model=spec.label)
    _check_payload(path, values.get("payload_kg"), rows, "payload_kg")
    q = None
    if q_file is not None:
        controller = angles == "controller"
        q = joints_from_file(robot, q_file, path=path, rows=rows, controller=controller, check=check_limits)
    return JointTable(str(path), header, data, rows, q, values, target, spec)


def _native(path: Path, robot, fmt: None) -> dict:
    """The native measurement CSV (module docstring): :meth:`Measurements.from_arrays` arguments."""
    optional = (*OPTIONAL_COLUMNS, TARGET_COLUMN, *oc.NATIVE_COLUMNS)
    suggest = OPTIONAL_COLUMNS + oc.SIGMA_COLUMNS
    t = read_joint_table(path, robot, required=XYZ_COLUMNS, optional=optional, suggest=suggest)
    known = {*(t.joints.columns if t.joints else ()), *XYZ_COLUMNS, *optional}
    extra = {}
    for c in t.header:
        if c not in known:  # a numeric column the model does not read is kept; a text column is not data
            try:
                extra[c] = _numbers(path, t.header, t.data, c)
            except InputError:
                pass
    eta = np.stack([t.values[c] for c in XYZ_COLUMNS], axis=1)
    opt = {c: t.values.get(c) for c in OPTIONAL_COLUMNS}
    if set(oc.NATIVE_COLUMNS) & set(t.header):  # a 6-DoF probe's orientation
        opt |= oc.native_orientation(path, t.header, t.values, t.rows)
    if t.target is not None:
        opt["target"] = t.target
    return dict(q=t.q, eta=eta, source=str(path), rows=t.rows, extra=extra, **opt)


class _Columns:
    """Number columns of a foreign table, parsed on demand with the format's decimal mark."""

    def __init__(self, path: Path, header, data, decimal: str):
        self.path, self.header, self.data, self.decimal = path, header, data, decimal

    def column(self, name: str, field: str) -> np.ndarray:
        if name not in self.header:
            raise InputError(
                f"{self.path}: format field {field!r} names column {name!r}, which the file does not have "
                f"(columns: {', '.join(self.header)})"
            )
        return _numbers(self.path, self.header, self.data, name, self.decimal)

    def expression(self, expr: str, field: str) -> np.ndarray:
        """A column, or columns joined by `` + `` / `` - `` (spaces around the operator)."""
        parts = _OPERATOR.split(expr.strip())
        value = self.column(parts[0], field)
        for op, name in zip(parts[1::2], parts[2::2], strict=True):
            value = value + self.column(name, field) if op == "+" else value - self.column(name, field)
        return value


def _foreign(path: Path, robot, fmt: DataFormat) -> dict:
    """A file of another layout, described by a checked format file: :meth:`Measurements.from_arrays`
    arguments (model angles [rad], positions [mm] in the format's ``frame``)."""
    controller = fmt.angles == "controller"
    spec = file_joints(robot, controller=controller)
    header, data = read_csv_table(
        path, (), delimiter=fmt.separator, columns=None if fmt.header else fmt.columns
    )
    if not data:
        raise InputError(f"{path}: no data rows (expected a header and one row per pose)")
    if len(fmt.joints) != spec.n_columns:
        raise InputError(
            f"{path}: the format's field 'joints' names {len(fmt.joints)} columns, {spec.name} has "
            f"{spec.n_columns} {spec.what}"
        )
    cols = _Columns(path, header, data, fmt.decimal)
    J = np.stack([cols.column(c, f"joints[{i}]") for i, c in enumerate(fmt.joints)], axis=1)
    rows = np.asarray(row_numbers(data))
    # a prismatic joint's column is a length (the format's length unit); an axis is one if it drives one
    scale = np.where(spec.linear, LENGTH_UNITS[fmt.length_unit], ANGLE_UNITS[fmt.angle_unit])
    q = joints_from_file(robot, J, path=path, rows=rows, scale=scale, controller=controller)
    extra = _conditions(path, fmt, cols, rows, spec)
    if fmt.orientation is not None:  # a 6-DoF probe's orientation: its columns read here, turned there
        o, names = fmt.orientation, ("columns", "sigma_columns")
        fields = {f"orientation.{k}[{i}]": c for k in names for i, c in enumerate(getattr(o, k))}
        extra |= oc.format_orientation(path, o, {c: cols.column(c, f) for f, c in fields.items()}, rows)
    if fmt.targets:
        return _several_per_row(path, fmt, cols, q, rows, extra, spec)
    eta = np.stack([cols.expression(getattr(fmt.position, a), f"position.{a}") for a in "xyz"], axis=1)
    eta = eta * LENGTH_UNITS[fmt.length_unit]
    return dict(q=q, eta=eta, source=str(path), rows=rows, frame=fmt.frame, **extra)


def _conditions(path: Path, fmt: DataFormat, cols: _Columns, rows, spec: FileJoints) -> dict:
    """The rows' time, temperature, payload and target columns (internal units)."""
    extra = {}
    if fmt.time:
        extra["time_s"] = cols.column(fmt.time, "time") * TIME_UNITS[fmt.time_unit]
    if fmt.temperature:
        extra["temperature_C"] = cols.column(fmt.temperature, "temperature")
    if fmt.payload:
        extra["payload_kg"] = cols.column(fmt.payload, "payload")
        _check_payload(path, extra["payload_kg"], rows, fmt.payload)
    if fmt.target:
        numbers = (
            _target_numbers(path, fmt, cols, rows) if fmt.target_labels else cols.column(fmt.target, "target")
        )
        extra["target"] = parse_targets(
            path, numbers, rows, column=fmt.target, n_targets=spec.n_targets, model=spec.label
        )
    return extra


def _target_numbers(path: Path, fmt: DataFormat, cols: _Columns, rows) -> np.ndarray:
    """The robot file's target numbers of a ``target`` column of labels (``target_labels``)."""
    labels = {str(k): v for k, v in fmt.target_labels.items()}
    if fmt.target not in cols.header:
        cols.column(fmt.target, "target")  # the error naming the missing column
    j = cols.header.index(fmt.target)
    out = np.empty(len(rows))
    for i, (line, r) in enumerate(zip(rows, cols.data, strict=True)):
        label = r[j].strip()
        if label not in labels:
            raise InputError(
                f"{path}: row {line}, column {fmt.target!r}: label {label!r} is not in the format's "
                f"target_labels ({', '.join(labels)})"
            )
        out[i] = labels[label]
    return out


def _several_per_row(path: Path, fmt: DataFormat, cols: _Columns, q, rows, extra: dict, spec) -> dict:
    """Rows that hold one point per target (``targets``): T measurements per pose, pose-major, each
    with its target."""
    keys = sorted(fmt.targets, key=lambda k: int(k))
    numbers = np.array([int(k) for k in keys])
    if numbers.max() > spec.n_targets:
        raise InputError(
            f"{path}: format field 'targets' names target {numbers.max()}, but the robot model defines "
            f"{spec.n_targets} (add them to its targets_mm)"
        )
    points = [
        np.stack([cols.expression(getattr(fmt.targets[k], a), f"targets.{k}.{a}") for a in "xyz"], axis=1)
        for k in keys
    ]
    T = len(keys)
    eta = np.stack(points, axis=1).reshape(-1, 3) * LENGTH_UNITS[fmt.length_unit]
    extra = {k: np.repeat(v, T, axis=0) for k, v in extra.items()}
    target = np.tile(numbers - 1, len(rows))
    q, rows = np.repeat(q, T, axis=0), np.repeat(rows, T)
    return dict(q=q, eta=eta, source=str(path), rows=rows, frame=fmt.frame, target=target, **extra)


MEASUREMENT_FORMATS: dict[str, Callable[..., dict]] = {"csv": _native, "format": _foreign}
"""The formats of a measurement file: the native CSV, and a layout a format file describes."""


def read_measurement_table(path: str | Path, robot: Robot, data_format: DataFormat | None = None) -> dict:
    """The arrays of a measurement file, as :meth:`~kpioed_drake.tracker.data.Measurements.from_arrays`
    takes them: ``q`` (n, n_joints) [rad; mm], ``eta`` (n, 3) [mm], ``rows`` (n,), conditions (n,),
    ``target`` (n,) 0-based, ``frame``, ``extra`` and ``source``.

    Args:
        path: the data file; robot: the model (joint columns, limits, joint map, targets).
        data_format: a checked :class:`~kpioed_drake.files.formats.DataFormat` (None: the native CSV).

    Raises:
        InputError: naming the file, row and column, or the format field.
    """
    kind = "csv" if data_format is None else "format"
    return MEASUREMENT_FORMATS[kind](Path(path), robot, data_format)
