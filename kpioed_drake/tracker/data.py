"""Measured laser-tracker data: the one :class:`Measurements` type, its validation, and the read of a
measurement file into it.

The file formats (the native CSV of SPEC, files of other layouts through a format file) and their
row/column messages are the file layer's (:mod:`kpioed_drake.files.tables`): :func:`read_data` takes
its arrays, checks that the poses are enough for the parameters, and validates them as
:class:`Measurements` (reflector positions eta of paper eq. 3 [mm], joint values [rad; mm]).
Inside, targets are 0-based; row numbers follow :data:`~kpioed_drake.files.tables.ROW_CONVENTION`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake.errors import InputError
from kpioed_drake.files.formats import FRAMES, DataFormat, as_format
from kpioed_drake.files.orientation_columns import NATIVE_COLUMNS, native_columns, native_orientation
from kpioed_drake.files.tables import (
    OPTIONAL_COLUMNS,
    TARGET_COLUMN,
    XYZ_COLUMNS,
    parse_targets,
    read_measurement_table,
)
from kpioed_drake.robot.jointmap import check_joint_angles, q_columns, q_from_file, q_to_file
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.parameters import parameter_layout

PLAUSIBLE = {
    "x_mm": (-1e6, 1e6, "mm"),
    "y_mm": (-1e6, 1e6, "mm"),
    "z_mm": (-1e6, 1e6, "mm"),
    "temperature_C": (-273.15, 1e3, "C"),
    "time_s": (-1e11, 1e11, "s"),
    "payload_kg": (0.0, 1e5, "kg"),
}
"""Bounds of a measured value no real measurement leaves (low, high, unit): a reflector within a
kilometre of the tracker (trackers reach some 80 m), a temperature above absolute zero, a time
within some thousand years of its origin (Unix seconds included), a payload under 100 t. A value
beyond them is a broken row (an overflowed or mistyped number), named by its row and column
before any statistic sees it."""


@dataclasses.dataclass(frozen=True)
class Measurements:
    """A validated measurement table in internal units.

    Build it with :func:`read_measurements` (a file), :meth:`from_table` (a DataFrame in the file
    format) or :meth:`from_arrays` (arrays in internal units); each validates.

    Attributes:
        q: (n, 6) commanded joint angles [rad].
        eta: (n, 3) reflector positions in the tracker frame [mm] (``frame`` = ``"tracker"``), or
            already in the base frame W (``frame`` = ``"base"``; a small residual frame error is
            still estimated as the tracker pose).
        temperature_C: (n,) [C] or None when the column is absent.
        time_s: (n,) [s] or None.
        payload_kg: (n,) [kg] or None.
        source: the file (or a label for in-memory data), for messages and reports.
        rows: (n,) row numbers as in :data:`ROW_CONVENTION` (default 2, 3, ...).
        frame: ``"tracker"`` or ``"base"``, the frame of ``eta`` (:data:`FRAMES`).
        target: (n,) 0-based target (reflector) of each row, or None (every row target 0).
        extra: ``((name, (n,) values), ...)``: the file's numeric columns that no part of the model
            reads (another branch's joints, a temperature under another name), kept so that the
            diagnosis can test the unexplained rest against them and nothing in the file is lost.
        R_TP: (n, 3, 3) measured orientation of the probe frame P in the tracker frame (a 6-DoF
            probe; columns = the probe's axes in tracker coordinates), or None (points only).
        sigma_rot_rad: (n, 3) standard deviations of the orientation's small rotation about the
            tracker's x, y, z axes [rad] (per row), or None (the command's default).
    """

    q: np.ndarray
    eta: np.ndarray
    temperature_C: np.ndarray | None = None
    time_s: np.ndarray | None = None
    payload_kg: np.ndarray | None = None
    source: str = "data"
    rows: np.ndarray | None = None
    frame: str = "tracker"
    target: np.ndarray | None = None
    extra: tuple[tuple[str, np.ndarray], ...] = ()
    R_TP: np.ndarray | None = None
    sigma_rot_rad: np.ndarray | None = None

    def __post_init__(self):
        if self.rows is None:
            object.__setattr__(self, "rows", np.arange(2, self.q.shape[0] + 2))

    @property
    def n(self) -> int:
        """Number of poses."""
        return int(self.q.shape[0])

    @property
    def n_targets(self) -> int:
        """Targets the rows use: the largest target index + 1 (1 without a target column)."""
        return 1 if self.target is None or self.target.size == 0 else int(self.target.max()) + 1

    @property
    def path(self) -> str:
        """The source (a file path for read data)."""
        return self.source

    @classmethod
    def from_arrays(
        cls,
        q: np.ndarray,
        eta: np.ndarray,
        *,
        temperature_C: np.ndarray | float | None = None,
        time_s: np.ndarray | float | None = None,
        payload_kg: np.ndarray | float | None = None,
        source: str = "data",
        rows: np.ndarray | Sequence[int] | None = None,
        frame: str = "tracker",
        target: np.ndarray | Sequence[int] | None = None,
        extra: Mapping[str, np.ndarray] | Sequence[tuple[str, np.ndarray]] = (),
        R_TP: np.ndarray | None = None,
        sigma_rot_rad: np.ndarray | None = None,
    ) -> Measurements:
        """Validated measurements from arrays in internal units (q [rad], eta [mm]).

        ``target``: (n,) 0-based target index of each row (None: all target 0). ``extra``:
        ``{name: (n,)}`` or pairs, numeric columns the model does not read. ``R_TP`` (n, 3, 3) and
        ``sigma_rot_rad`` (n, 3): a 6-DoF probe's measured orientations and their noise.

        Raises:
            InputError: shapes other than (n, 6), (n, 3) and (n,), a non-finite value, a
                frame other than ``"tracker"`` and ``"base"``, or target indices that are not
                integers >= 0.
        """

        def arr(x):
            return None if x is None else np.asarray(x, dtype=float)

        data = cls(
            q=np.asarray(q, dtype=float),
            eta=np.asarray(eta, dtype=float),
            temperature_C=arr(temperature_C),
            time_s=arr(time_s),
            payload_kg=arr(payload_kg),
            source=str(source),
            rows=None if rows is None else np.asarray(rows),
            frame=frame,
            target=None if target is None else np.asarray(target),
            extra=tuple((str(k), np.asarray(v, dtype=float)) for k, v in dict(extra).items()),
            R_TP=arr(R_TP),
            sigma_rot_rad=arr(sigma_rot_rad),
        )
        data.check()
        if data.target is not None:
            object.__setattr__(data, "target", data.target.astype(int))
        return data

    @classmethod
    def from_table(
        cls, table: pd.DataFrame, robot: Robot | None = None, *, source: str = "data"
    ) -> Measurements:
        """From a DataFrame in the file format (degrees), e.g. from :func:`simulation.simulate`; a
        6-DoF probe's native orientation columns (``qw, qx, qy, qz``, ``sigma_r*_deg``) too.

        Raises:
            InputError: a missing column, a non-finite value, angles outside the robot's limits, an
                orientation that is not a unit quaternion.
        """
        qcols = q_columns(robot)
        for c in qcols + XYZ_COLUMNS:
            if c not in table:
                raise InputError(f"{source}: missing column {c!r} (SPEC measurement format)")
        q_deg = np.column_stack([np.asarray(table[c], dtype=float) for c in qcols])
        eta = np.column_stack([np.asarray(table[c], dtype=float) for c in XYZ_COLUMNS])
        if not (np.all(np.isfinite(q_deg)) and np.all(np.isfinite(eta))):
            raise InputError(f"{source}: non-finite joint angle or position")
        if robot is not None:
            check_joint_angles(source, q_deg, robot)
        opt = {c: np.asarray(table[c], dtype=float) if c in table else None for c in OPTIONAL_COLUMNS}
        target = None
        rows = np.arange(2, len(q_deg) + 2)
        if TARGET_COLUMN in table:
            values = np.asarray(table[TARGET_COLUMN], dtype=float)
            n_targets, model = (None, "") if robot is None else (robot.n_targets, robot.source or robot.name)
            target = parse_targets(source, values, rows, n_targets=n_targets, model=model)
        header = [str(c) for c in table.columns]
        orientation = {c: _finite(table, c, source) for c in NATIVE_COLUMNS if c in header}
        opt |= native_orientation(source, header, orientation, rows)
        known = set(qcols) | set(XYZ_COLUMNS) | set(OPTIONAL_COLUMNS) | {TARGET_COLUMN} | set(NATIVE_COLUMNS)
        extra = {}
        for c in table.columns:
            if str(c) not in known:
                v = pd.to_numeric(table[c], errors="coerce").to_numpy(dtype=float)
                if np.all(np.isfinite(v)):
                    extra[str(c)] = v
        return cls.from_arrays(
            q_from_file(robot, q_deg), eta, source=source, target=target, extra=extra, **opt
        )

    def check(self) -> None:
        """Shapes and finiteness.

        Raises:
            InputError: naming the source and the column.
        """
        n = self.n
        if self.frame not in FRAMES:
            raise InputError(f"{self.source}: frame must be one of {', '.join(FRAMES)}, got {self.frame!r}")
        if self.q.ndim != 2 or self.q.shape[0] != n or not self.q.shape[1] or self.eta.shape != (n, 3):
            raise InputError(f"{self.source}: expected q (n, n_joints) and positions (n, 3)")
        for name in ("q", "eta") + OPTIONAL_COLUMNS:
            v = getattr(self, name)
            if v is not None and v.shape != (n,) and name in OPTIONAL_COLUMNS:
                raise InputError(f"{self.source}: column {name} must have one value per pose")
            if v is not None and not np.all(np.isfinite(v)):
                raise InputError(f"{self.source}: column {name} has a non-finite value")
        for name, v in self.extra:
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise InputError(f"{self.source}: column {name}: expected one finite number per row")
        self._check_plausible()
        self._check_orientation()
        t = self.target
        if t is not None:
            ok = t.shape == (n,) and np.all(np.isfinite(t)) and np.all(t == np.round(t)) and np.all(t >= 0)
            if not ok:
                raise InputError(f"{self.source}: target: expected (n,) integer indices >= 0 (0-based)")

    def _check_orientation(self) -> None:
        """A 6-DoF probe's orientations: (n, 3, 3) rotation matrices, sigmas (n, 3) finite and > 0."""
        n, R, s = self.n, self.R_TP, self.sigma_rot_rad
        if R is not None:
            if R.shape != (n, 3, 3) or not np.all(np.isfinite(R)):
                raise InputError(f"{self.source}: orientations: expected (n, 3, 3) finite rotation matrices")
            err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
            bad = np.flatnonzero((err > 1e-6) | (np.linalg.det(R) < 0))
            if bad.size:
                raise InputError(
                    f"{self.source}: row {self.rows[bad[0]]}: the orientation is not a rotation "
                    f"(R^T R - I up to {err[bad[0]]:.2g}, or a reflection)"
                )
        if s is not None:
            if R is None:
                raise InputError(f"{self.source}: orientation sigmas without orientations")
            if s.shape != (n, 3) or not np.all(np.isfinite(s)) or np.any(s <= 0):
                raise InputError(f"{self.source}: orientation sigmas: expected (n, 3) finite values > 0")

    def _check_plausible(self) -> None:
        """Every measured value within :data:`PLAUSIBLE` (the first one beyond named by row and column)."""
        columns = {c: self.eta[:, k] for k, c in enumerate(XYZ_COLUMNS)}
        columns |= {c: getattr(self, c) for c in OPTIONAL_COLUMNS if getattr(self, c) is not None}
        for name, values in columns.items():
            low, high, unit = PLAUSIBLE[name]
            for k in np.flatnonzero((values < low) | (values > high))[:1]:
                raise InputError(
                    f"{self.source}: row {self.rows[k]}, column {name!r}: {values[k]:g} {unit} is no "
                    f"measured value (expected {low:g} .. {high:g} {unit}); check the row"
                )

    def subset(self, idx: np.ndarray | slice) -> Measurements:
        """The poses ``idx`` (indices or a boolean mask), rows kept."""

        def pick(x):
            return None if x is None else x[idx]

        return dataclasses.replace(
            self,
            q=self.q[idx],
            eta=self.eta[idx],
            temperature_C=pick(self.temperature_C),
            time_s=pick(self.time_s),
            payload_kg=pick(self.payload_kg),
            rows=self.rows[idx],
            target=pick(self.target),
            extra=tuple((k, v[idx]) for k, v in self.extra),
            R_TP=pick(self.R_TP),
            sigma_rot_rad=pick(self.sigma_rot_rad),
        )

    def to_frame(self, robot: Robot | None = None) -> pd.DataFrame:
        """A DataFrame in the file format (degrees, mm; ``robot``'s joint columns, default six revolute;
        a 6-DoF probe's orientation as the native ``qw, qx, qy, qz`` and ``sigma_r*_deg`` columns)."""
        q = q_to_file(robot, self.q)
        cols = {c: q[:, i] for i, c in enumerate(q_columns(robot))}
        cols.update({c: self.eta[:, i] for i, c in enumerate(XYZ_COLUMNS)})
        for c in OPTIONAL_COLUMNS:
            if getattr(self, c) is not None:
                cols[c] = getattr(self, c)
        if self.target is not None:
            cols[TARGET_COLUMN] = self.target + 1
        cols.update(native_columns(self.R_TP, self.sigma_rot_rad))
        cols.update({k: v for k, v in self.extra if k not in cols})
        return pd.DataFrame(cols)


def _finite(table: pd.DataFrame, name: str, source: str) -> np.ndarray:
    """Column ``name`` of ``table`` as finite numbers (the first other value named by its row)."""
    v = pd.to_numeric(table[name], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        raise InputError(f"{source}: row {bad[0] + 2}, column {name!r}: not a finite number")
    return v


def per_pose(value: float | np.ndarray | Sequence[float], n: int, name: str) -> np.ndarray:
    """(n,) values of a per-pose quantity given as one number or one per pose.

    Raises:
        InputError: another shape or a non-finite value (``name`` says which quantity).
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected one finite number or {n} (one per pose)")
    return arr


def check_pose_count(path: str | Path, n: int, robot: Robot) -> None:
    """Enough rows (poses x targets) for the robot's estimated parameters (27 parameters: 9 rows).

    Raises:
        InputError: naming the file, the rows and the parameters.
    """
    n_free = parameter_layout(robot).n_free
    need = int(np.ceil(n_free / 3))
    if n < need:
        raise InputError(
            f"{path}: {n} rows (data rows 2..{n + 1}) are too few: the {n_free} estimated "
            f"parameters need at least {need} rows (poses x targets, 3 coordinates each), and more than "
            f"{need} for a goodness-of-fit test; about 60 poses are usual"
        )


def read_data(
    path: str | Path, robot: Robot, data_format: DataFormat | str | Path | None = None
) -> Measurements:
    """Read and validate a measurement file: the native CSV (no ``data_format``) or a file of another
    layout (``data_format``: a :class:`~kpioed_drake.files.formats.DataFormat` or a format file).

    Raises:
        InputError: naming the file, row (header = row 1) and column, or the format field: missing
            file, empty file, duplicated or missing (misspelled) column, text/NaN/infinity in a
            number field, joint angles that look like radians or lie outside the robot's limits,
            negative payload, a target column that is not numbered 1..T without gaps or names a
            target the robot model does not define, fewer poses than the estimated parameters need
            (27 parameters: 9 poses), a measured value no measurement gives.
    """
    fmt = None if data_format is None else as_format(data_format)
    arrays = read_measurement_table(path, robot, fmt)
    check_pose_count(Path(path), len(np.unique(arrays["rows"])), robot)
    return Measurements.from_arrays(**arrays)


def read_measurements(path: str | Path, robot: Robot) -> Measurements:
    """Read and validate a native measurement CSV (:func:`read_data` without a format)."""
    return read_data(path, robot)


def as_measurements(data: Measurements | str | Path, robot: Robot) -> Measurements:
    """``data`` itself if it is :class:`Measurements`, else the file it names (:func:`read_measurements`).

    Raises:
        InputError: anything else (build other data with :meth:`Measurements.from_arrays` or
            :meth:`Measurements.from_table`).
    """
    if isinstance(data, Measurements):
        return data
    if isinstance(data, str | Path):
        return read_measurements(data, robot)
    raise InputError(
        f"data: expected Measurements or a measurement CSV path, got {type(data).__name__} "
        "(use Measurements.from_table or Measurements.from_arrays)"
    )


def n_poses(data: Measurements) -> int:
    """The distinct poses of the data (the rows of one pose's targets share its joint values)."""
    return int(len(np.unique(data.q, axis=0))) if data.n else 0


def counted(data: Measurements) -> str:
    """``"30 poses"``, or ``"30 poses (90 rows, 3 targets)"`` with several targets per pose."""
    poses = n_poses(data)
    return f"{poses} poses" if poses == data.n else f"{poses} poses ({data.n} rows, {data.n_targets} targets)"


def poses_and_rows(n_poses: int, n_rows: int) -> str:
    """``"30 poses"``, or ``"30 poses (90 rows)"`` when the poses have several rows (their targets):
    how every message counts measurements, so that rows are never called poses."""
    return f"{n_poses} poses" if n_poses == n_rows else f"{n_poses} poses ({n_rows} rows)"


def counted_rows(q: np.ndarray) -> str:
    """:func:`poses_and_rows` of the rows ``q`` (n, n_joints) (rows with equal values are one pose's)."""
    q = np.asarray(q)
    return poses_and_rows(int(len(np.unique(q, axis=0))) if len(q) else 0, len(q))
