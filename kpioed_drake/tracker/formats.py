"""Measurement files of other layouts: a small YAML *format file* says how to read them.

Other tools write laser-tracker data with their own column names, units, separators and frames.
A format file (documented in ``docs/data-formats.md``) maps such a file onto the one
:class:`~kpioed_drake.tracker.data.Measurements` type (the measurements eta of paper eq. 3):

- ``joints``: the joint columns, one per joint (or controller axis), in ``angle_unit`` (``deg`` or
  ``rad``; a prismatic joint's in ``length_unit``); with
  ``angles: controller`` (the default) the robot file's ``joint_map``
  (:mod:`kpioed_drake.robot.jointmap`) turns them into model angles, so controller angles go in
  unchanged;
- ``position``: ``x``, ``y``, ``z``, each a column or a sum/difference of columns written with
  spaces around the operator (``x_t - x_dif``: target minus difference), in ``length_unit``
  (``mm``, ``m`` or ``um``);
- ``frame``: ``tracker`` (positions in the tracker frame) or ``base`` (already in the robot base
  frame W; the residual frame error is still estimated as a rigid tracker pose);
- ``separator`` and ``decimal`` (``,`` or ``.``; a decimal comma needs another separator);
- optional ``time`` (with ``time_unit`` ``s``, ``min``, ``h`` or ``order``: an order number, one
  unit per pose, taken as seconds), ``temperature`` [C] and ``payload`` [kg] columns;
- optional ``target``: the column of the target (SMR) number, 1..T (several targets per pose), or
  labels of the file's own (``0``, ``1``, ... or names) mapped by ``target_labels`` (label -> the
  robot file's target number);
- ``header: false`` with ``columns: [...]``: a file without a header row, its columns named in the
  format; ``separator: whitespace``: fields separated by any run of spaces or tabs;
- ``targets: {1: {x: x1, y: y1, z: z1}, 2: {...}}``: several targets measured in one row (the keys
  the robot file's target numbers); each row then gives one pose and one point per target.

:func:`read_data` reads either layout: the SPEC file without a format, a foreign one with it.
"""

import dataclasses
import re
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import N_JOINTS, Robot, load_yaml_typed
from kpioed_drake.tracker.csvio import WHITESPACE, check_joint_angles, q_to_file, read_csv_table
from kpioed_drake.tracker.data import FRAMES, Measurements, check_pose_count, parse_targets, read_measurements

LENGTH_UNITS = {"mm": 1.0, "m": 1000.0, "um": 1e-3}
"""Length units of a format file and their size in millimetres."""
ANGLE_UNITS = {"deg": np.pi / 180.0, "rad": 1.0}
"""Angle units and their size in radians."""
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "order": 1.0}
"""Time units and their size in seconds (``order``: a measurement order number, 1 per pose)."""
ANGLE_SOURCES = ("controller", "model")
"""``controller``: apply the robot's joint map; ``model``: the angles are the model's already."""
_OPERATOR = re.compile(r"\s+([+-])\s+")


@dataclasses.dataclass
class PositionSpec:
    """The three position expressions of a format file."""

    x: str = ""
    y: str = ""
    z: str = ""


@dataclasses.dataclass
class DataFormat:
    """A format file (``--format F.yaml``); fields as in ``docs/data-formats.md``."""

    description: str = ""
    separator: str = ","
    decimal: str = "."
    length_unit: str = "mm"
    angle_unit: str = "deg"
    frame: str = "tracker"
    angles: str = "controller"
    joints: list[str] = dataclasses.field(default_factory=list)
    position: PositionSpec = dataclasses.field(default_factory=PositionSpec)
    time: str = ""
    time_unit: str = "s"
    temperature: str = ""
    payload: str = ""
    target: str = ""
    target_labels: dict[str, int] = dataclasses.field(default_factory=dict)
    header: bool = True
    columns: list[str] = dataclasses.field(default_factory=list)
    targets: dict[str, PositionSpec] = dataclasses.field(default_factory=dict)


def _one_of(where: str, field: str, value: str, allowed) -> None:
    if value not in allowed:
        raise InputError(f"{where}: field {field!r}: {value!r} is not one of {', '.join(allowed)}")


def check_format(fmt: DataFormat, where: str = "format") -> DataFormat:
    """Validate a :class:`DataFormat`.

    Raises:
        InputError: naming ``where`` and the field: unknown unit, frame or angle source, not six
            joint columns, an empty position expression, a separator that is not one character,
            a decimal mark other than ``.``/``,`` or equal to the separator.
    """
    _one_of(where, "length_unit", fmt.length_unit, LENGTH_UNITS)
    _one_of(where, "angle_unit", fmt.angle_unit, ANGLE_UNITS)
    _one_of(where, "time_unit", fmt.time_unit, TIME_UNITS)
    _one_of(where, "frame", fmt.frame, FRAMES)
    _one_of(where, "angles", fmt.angles, ANGLE_SOURCES)
    _one_of(where, "decimal", fmt.decimal, (".", ","))
    sep_ok = fmt.separator == WHITESPACE or (len(fmt.separator) == 1 and fmt.separator not in "\"'\r\n")
    if not sep_ok or fmt.separator == fmt.decimal:
        raise InputError(
            f"{where}: field 'separator': {fmt.separator!r} must be one character other than a quote "
            f"and other than the decimal mark {fmt.decimal!r}, or {WHITESPACE!r}"
        )
    if fmt.header == bool(fmt.columns):
        raise InputError(
            f"{where}: field 'columns': "
            + (
                "a file with a header names its own columns (set header: false)"
                if fmt.header
                else "a file without a header (header: false) needs its column names"
            )  # fmt: skip
        )
    _check_targets(fmt, where)
    if not fmt.joints or not all(c.strip() for c in fmt.joints):
        raise InputError(f"{where}: field 'joints': expected {N_JOINTS} column names, got {fmt.joints!r}")
    if not fmt.targets:
        for axis in "xyz":
            if not getattr(fmt.position, axis).strip():
                raise InputError(
                    f"{where}: field 'position.{axis}': missing (a column or e.g. 'x_t - x_dif')"
                )
    return fmt


def _check_targets(fmt: DataFormat, where: str) -> None:
    """The several-targets fields: ``targets`` keys are target numbers >= 1 with x, y and z, not
    together with ``position`` or ``target``; ``target_labels`` map to numbers >= 1."""
    for label, number in fmt.target_labels.items():
        if not isinstance(number, int) or number < 1:
            raise InputError(
                f"{where}: field 'target_labels.{label}': expected a target number >= 1, got {number!r}"
            )
    if fmt.target_labels and not fmt.target:
        raise InputError(f"{where}: field 'target_labels': goes with a 'target' column")
    if not fmt.targets:
        return
    if fmt.target or any(getattr(fmt.position, a).strip() for a in "xyz"):
        raise InputError(f"{where}: field 'targets': several targets per row replace 'position' and 'target'")
    for key, spec in fmt.targets.items():
        if not str(key).isdigit() or int(key) < 1:
            raise InputError(
                f"{where}: field 'targets.{key}': keys are the robot file's target numbers 1, 2, ..."
            )
        for axis in "xyz":
            if not getattr(spec, axis).strip():
                raise InputError(f"{where}: field 'targets.{key}.{axis}': missing")


def load_format(path: str | Path) -> DataFormat:
    """Read and validate a format file (YAML; an unknown field is an error naming the file).

    Raises:
        InputError: naming the file and the field.
    """
    path = Path(path)
    return check_format(load_yaml_typed(path, DataFormat), where=str(path))


class _Columns:
    """Numeric columns of a table, parsed on demand with the format's decimal mark."""

    def __init__(self, path: Path, header, data, lines, decimal: str):
        self.path, self.header, self.data, self.lines, self.decimal = path, header, data, lines, decimal

    def column(self, name: str, field: str) -> np.ndarray:
        if name not in self.header:
            raise InputError(
                f"{self.path}: format field {field!r} names column {name!r}, which the file does not have "
                f"(columns: {', '.join(self.header)})"
            )
        j = self.header.index(name)
        out = np.empty(len(self.data))
        for i, (line, r) in enumerate(zip(self.lines, self.data, strict=True)):
            cell = r[j].strip()
            text = cell.replace(",", ".") if self.decimal == "," else cell
            try:
                out[i] = float(text)
            except ValueError:
                raise InputError(
                    f"{self.path}: row {line}, column {name!r}: {cell!r} is not a number"
                ) from None
            if not np.isfinite(out[i]):
                raise InputError(f"{self.path}: row {line}, column {name!r}: {cell!r} is not a finite number")
        return out

    def expression(self, expr: str, field: str) -> np.ndarray:
        """A column, or columns joined by `` + `` / `` - `` (spaces around the operator)."""
        parts = _OPERATOR.split(expr.strip())
        value = self.column(parts[0], field)
        for op, name in zip(parts[1::2], parts[2::2], strict=True):
            value = value + self.column(name, field) if op == "+" else value - self.column(name, field)
        return value


def read_foreign(path: str | Path, robot: Robot, fmt: DataFormat | str | Path) -> Measurements:
    """Read a measurement file of another layout, described by a format file.

    Args:
        path: the data file.
        robot: the robot (its joint map, limits and parameter count).
        fmt: a :class:`DataFormat` or the path of a format file.

    Returns:
        :class:`Measurements` in internal units (model angles [rad], positions [mm]) with
        ``frame`` as the format says.

    Raises:
        InputError: naming the file, row and column or format field: a column the file does not
            have, text in a number field, angles outside the limits after the joint map (or
            degrees given as radians), a negative payload, too few poses.
    """
    path = Path(path)
    fmt = check_format(fmt) if isinstance(fmt, DataFormat) else load_format(fmt)
    header, data = read_csv_table(
        path, (), delimiter=fmt.separator, columns=None if fmt.header else fmt.columns
    )
    if not data:
        raise InputError(f"{path}: no data rows (expected a header and one row per pose)")
    jmap = robot.joint_map if fmt.angles == "controller" else None
    n_cols, what = (jmap.n_axes, "controller axes") if jmap is not None else (robot.n_joints, "joints")
    if len(fmt.joints) != n_cols:
        raise InputError(
            f"{path}: the format's field 'joints' names {len(fmt.joints)} columns, {robot.name} has "
            f"{n_cols} {what}"
        )
    cols = _Columns(path, header, data, data.lines, fmt.decimal)
    J = np.stack([cols.column(c, f"joints[{i}]") for i, c in enumerate(fmt.joints)], axis=1)
    # a prismatic joint's column is a length (the format's length unit); an axis is one if it drives one
    linear = robot.prismatic if jmap is None else np.any(jmap.A[np.asarray(robot.prismatic)] != 0, axis=0)
    q = J * np.where(linear, LENGTH_UNITS[fmt.length_unit], ANGLE_UNITS[fmt.angle_unit])
    if jmap is not None:
        q = jmap.to_model(q)
    rows = np.asarray(cols.lines)
    check_joint_angles(path, q_to_file(robot, q), robot, rows=rows)
    extra = _conditions(path, fmt, cols, rows, robot)
    if fmt.targets:
        return _several_per_row(path, fmt, cols, q, rows, extra, robot)
    eta = np.stack([cols.expression(getattr(fmt.position, a), f"position.{a}") for a in "xyz"], axis=1)
    eta = eta * LENGTH_UNITS[fmt.length_unit]
    check_pose_count(path, len(rows), robot)
    return Measurements.from_arrays(q, eta, source=str(path), rows=rows, frame=fmt.frame, **extra)


def _conditions(path: Path, fmt: DataFormat, cols: _Columns, rows, robot: Robot) -> dict:
    """The rows' time, temperature, payload and target columns (internal units)."""
    extra = {}
    if fmt.time:
        extra["time_s"] = cols.column(fmt.time, "time") * TIME_UNITS[fmt.time_unit]
    if fmt.temperature:
        extra["temperature_C"] = cols.column(fmt.temperature, "temperature")
    if fmt.payload:
        extra["payload_kg"] = cols.column(fmt.payload, "payload")
        if np.any(extra["payload_kg"] < 0):
            row = rows[int(np.flatnonzero(extra["payload_kg"] < 0)[0])]
            raise InputError(f"{path}: row {row}, column {fmt.payload!r}: a payload cannot be negative")
    if fmt.target:
        numbers = (
            _target_numbers(path, fmt, cols, rows) if fmt.target_labels else cols.column(fmt.target, "target")
        )
        extra["target"] = parse_targets(path, numbers, rows, column=fmt.target, robot=robot)
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


def _several_per_row(
    path: Path, fmt: DataFormat, cols: _Columns, q, rows, extra: dict, robot: Robot
) -> Measurements:
    """Measurements of rows that hold one point per target (``targets``): T rows per pose,
    pose-major, each with its target."""
    keys = sorted(fmt.targets, key=lambda k: int(k))
    numbers = np.array([int(k) for k in keys])
    if numbers.max() > robot.n_targets:
        raise InputError(
            f"{path}: format field 'targets' names target {numbers.max()}, but the robot model defines "
            f"{robot.n_targets} (add them to its targets_mm)"
        )
    points = [
        np.stack([cols.expression(getattr(fmt.targets[k], a), f"targets.{k}.{a}") for a in "xyz"], axis=1)
        for k in keys
    ]
    T = len(keys)
    eta = np.stack(points, axis=1).reshape(-1, 3) * LENGTH_UNITS[fmt.length_unit]
    extra = {k: np.repeat(v, T, axis=0) for k, v in extra.items()}
    check_pose_count(path, len(rows), robot)
    return Measurements.from_arrays(
        np.repeat(q, T, axis=0),
        eta,
        source=str(path),
        rows=np.repeat(rows, T),
        frame=fmt.frame,
        target=np.tile(numbers - 1, len(rows)),
        **extra,
    )


def read_data(
    path: str | Path, robot: Robot, data_format: DataFormat | str | Path | None = None
) -> Measurements:
    """A measurement file of the SPEC layout (no ``data_format``) or of another layout (with it)."""
    if data_format is None:
        return read_measurements(path, robot)
    return read_foreign(path, robot, data_format)
