"""Format files: a small YAML file that says how to read a measurement file of another layout.

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
  the robot file's target numbers); each row then gives one pose and one point per target;
- optional ``orientation``: a 6-DoF probe's measured orientation (:class:`OrientationSpec`): its
  columns and their representation (Euler angles with sequence, kind and unit; a quaternion with
  the scalar's position; a matrix with the order of its nine numbers,
  :mod:`kpioed_drake.files.orientations`), and per-row sigma columns or one constant sigma.

This module holds the format file's schema and its checks; :mod:`kpioed_drake.files.tables` reads
the data file it describes.
"""

import dataclasses
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files.orientations import (
    ANGLE_UNITS,
    MATRIX_ORDERS,
    SCALAR_POSITIONS,
    check_euler,
    missing_or,
)
from kpioed_drake.robot.models import N_JOINTS, load_yaml_typed

LENGTH_UNITS = {"mm": 1.0, "m": 1000.0, "um": 1e-3}
"""Length units of a format file and their size in millimetres."""
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "order": 1.0}
"""Time units and their size in seconds (``order``: a measurement order number, 1 per pose)."""
ANGLE_SOURCES = ("controller", "model")
"""``controller``: apply the robot's joint map; ``model``: the angles are the model's already."""
FRAMES = ("tracker", "base")
"""Frames measured positions can be given in: the tracker frame T, or the robot base frame W."""
WHITESPACE = "whitespace"
"""The separator of a file whose fields are separated by any run of spaces or tabs."""
ORIENTATION_COLUMNS = {"euler": 3, "quaternion": 4, "matrix": 9}
"""The representations of an orientation and the columns each takes."""
SIGMA_OF = ("euler_angles", "tracker_axes")
"""What per-row orientation sigma columns are the standard deviations of: the three Euler angles
(mapped to the tracker axes, :func:`~kpioed_drake.files.orientations.euler_sigma_to_rotation_sigma`),
or the small rotation about the tracker's x, y, z axes."""


@dataclasses.dataclass
class PositionSpec:
    """The three position expressions of a format file."""

    x: str = ""
    y: str = ""
    z: str = ""


@dataclasses.dataclass
class OrientationSpec:
    """A format file's ``orientation`` block: the probe frame's orientation in the tracker frame.

    Attributes:
        representation: ``euler``, ``quaternion`` or ``matrix`` (:data:`ORIENTATION_COLUMNS`).
        columns: its columns in the file: euler the three angles in the sequence's order, quaternion
            the four numbers as the file holds them (``scalar`` says where w is), matrix the nine
            numbers in ``order``.
        sequence, kind: euler: one of the twelve sequences in capitals, ``intrinsic``/``extrinsic``.
        angle_unit: ``deg`` or ``rad``: of the Euler angles and of the sigma columns.
        scalar: quaternion: ``first`` (w x y z) or ``last`` (x y z w).
        order: matrix: ``row_major`` (r11 r12 r13 r21 ...) or ``column_major`` (r11 r21 r31 ...).
        sigma_columns: three per-row standard deviations, of ``sigma_of`` (:data:`SIGMA_OF`).
        sigma_deg, sigma_rad: one standard deviation of the rotation about each tracker axis for the
            whole file (instead of sigma columns).
    """

    representation: str = ""
    columns: list[str] = dataclasses.field(default_factory=list)
    sequence: str = ""
    kind: str = ""
    angle_unit: str = ""
    scalar: str = ""
    order: str = ""
    sigma_columns: list[str] = dataclasses.field(default_factory=list)
    sigma_of: str = ""
    sigma_deg: float | None = None
    sigma_rad: float | None = None


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
    orientation: OrientationSpec | None = None


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
    if fmt.orientation is not None:
        check_orientation(fmt.orientation, where)
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


def _empty(where: str, spec: OrientationSpec, fields: tuple[str, ...], goes_with: str) -> None:
    for name in fields:
        if getattr(spec, name):
            raise InputError(f"{where}: field 'orientation.{name}': goes with {goes_with}")


def check_orientation(spec: OrientationSpec, where: str = "format") -> None:
    """The ``orientation`` block: a known representation with its columns and every convention
    field it needs, named; no field of another representation; at most one kind of sigma.

    Raises:
        InputError: naming ``where`` and the field ``orientation.<name>``.
    """
    rep = spec.representation
    if rep not in ORIENTATION_COLUMNS:
        got = missing_or(rep, ORIENTATION_COLUMNS)
        raise InputError(f"{where}: field 'orientation.representation': {got}")
    width = ORIENTATION_COLUMNS[rep]
    if len(spec.columns) != width or not all(str(c).strip() for c in spec.columns):
        raise InputError(
            f"{where}: field 'orientation.columns': representation {rep} takes {width} column names, "
            f"got {spec.columns!r}"
        )
    if rep == "euler":
        check_euler(spec.sequence, spec.kind, spec.angle_unit, where, field="orientation")
    else:
        _empty(where, spec, ("sequence", "kind"), "representation: euler")
    if rep == "quaternion" and spec.scalar not in SCALAR_POSITIONS:
        raise InputError(
            f"{where}: field 'orientation.scalar': {missing_or(spec.scalar, SCALAR_POSITIONS)}; say "
            "where the scalar part is: first (w x y z) or last (x y z w)"
        )
    if rep != "quaternion":
        _empty(where, spec, ("scalar",), "representation: quaternion")
    if rep == "matrix" and spec.order not in MATRIX_ORDERS:
        raise InputError(
            f"{where}: field 'orientation.order': {missing_or(spec.order, MATRIX_ORDERS)}; say how "
            "the nine numbers are ordered: row_major (r11 r12 r13 r21 ... r33) or column_major "
            "(r11 r21 r31 r12 ... r33)"
        )
    if rep != "matrix":
        _empty(where, spec, ("order",), "representation: matrix")
    _check_orientation_sigma(spec, where)


def _check_orientation_sigma(spec: OrientationSpec, where: str) -> None:
    given = [n for n in ("sigma_columns", "sigma_deg", "sigma_rad") if getattr(spec, n) not in (None, [])]
    if len(given) > 1:
        raise InputError(f"{where}: field 'orientation.{given[1]}': give only one of {', '.join(given)}")
    for name in ("sigma_deg", "sigma_rad"):
        value = getattr(spec, name)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"{where}: field 'orientation.{name}': expected a number > 0, got {value!r}")
    if not spec.sigma_columns:
        _empty(where, spec, ("sigma_of",), "sigma_columns")
        if spec.representation != "euler":
            _empty(where, spec, ("angle_unit",), "Euler angles or sigma_columns")
        return
    if len(spec.sigma_columns) != 3 or not all(str(c).strip() for c in spec.sigma_columns):
        raise InputError(f"{where}: field 'orientation.sigma_columns': expected 3 column names")
    if spec.sigma_of not in SIGMA_OF:
        raise InputError(
            f"{where}: field 'orientation.sigma_of': {missing_or(spec.sigma_of, SIGMA_OF)}; say "
            "whether the sigma columns are of the Euler angles or of the rotation about the tracker's "
            "x, y, z axes"
        )
    if spec.sigma_of == "euler_angles" and spec.representation != "euler":
        raise InputError(
            f"{where}: field 'orientation.sigma_of': euler_angles goes with representation: euler"
        )
    if spec.angle_unit not in ANGLE_UNITS:
        got = missing_or(spec.angle_unit, ANGLE_UNITS)
        raise InputError(f"{where}: field 'orientation.angle_unit': {got} (the unit of the sigma columns)")


def load_format(path: str | Path) -> DataFormat:
    """Read and validate a format file (YAML; an unknown field is an error naming the file).

    Raises:
        InputError: naming the file and the field.
    """
    path = Path(path)
    return check_format(load_yaml_typed(path, DataFormat), where=str(path))


def as_format(data_format: DataFormat | str | Path) -> DataFormat:
    """A checked :class:`DataFormat`: ``data_format`` itself (checked) or the format file it names.

    Raises:
        InputError: naming the file (or ``format``) and the field.
    """
    if isinstance(data_format, DataFormat):
        return check_format(data_format)
    return load_format(data_format)
