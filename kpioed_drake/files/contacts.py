"""Plane-contact and distance files (docs/contacts.md): CSV text -> checked arrays, which
:func:`kpioed_drake.tracker.contactdata.read_planes` and ``read_distances`` turn into
:class:`~kpioed_drake.tracker.contactdata.PlaneData` and ``DistanceData``.

- a *plane-contact file*: the robot's joint columns (``q1_deg``, ... as a measurement file, model
  angles; a prismatic joint's ``qK_mm``), ``plane`` (1..P), optional ``target`` (the touching tool
  point, 1..T of the robot file's targets), ``distance_mm`` (the measured signed distance, default
  0: a touch), ``sigma_mm`` (the contact's noise along the normal);
- a *distance file*, one of two layouts: pair rows (two poses' joint columns ``a_q1_deg``, ...
  and ``b_q1_deg``, ..., the length between their tool points) or pivot rows (one pose's joint
  columns and ``pivot``, 1..C, the length to that pivot); both with ``length_mm``, optional ``bar``
  (1..B: rows sharing one estimated length correction; 0: a known length), ``target``,
  ``sigma_mm``.

Ids are 1-based in files and 0-based inside. Every message names the file, the row
(:data:`~kpioed_drake.files.tables.ROW_CONVENTION`) and the column. ``n_planes`` (and ``n_pivots``,
``n_bars``) given: the ids may not exceed them (the planes of a model file) and gaps and planes with
fewer than 3 rows are allowed (held-out rows); without them the ids are numbered without gaps and
every plane has 3 rows at least (the rows a fit estimates the planes from).
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files.tables import TARGET_COLUMN, _numbers, parse_targets, read_joint_table
from kpioed_drake.robot.jointmap import joints_from_file, q_columns
from kpioed_drake.robot.models import Robot

DEFAULT_SIGMA_MM = 0.01
"""A contact's or a length's noise where the file gives no ``sigma_mm`` [mm]."""
PAIR_PREFIXES = ("a_", "b_")
"""The prefixes of a pair row's two poses' joint columns."""


def _ids(
    path,
    values: np.ndarray,
    rows: np.ndarray,
    column: str,
    count: int | None,
    zero_ok: bool,
    gaps: bool = False,
) -> np.ndarray:
    """(n,) 0-based ids of a 1-based id column (``zero_ok``: 0 means none, -1 inside); without a
    ``count`` numbered without gaps unless ``gaps``."""
    v = np.where(np.isnan(values), 0.0, values) if zero_ok else values
    low = 0 if zero_ok else 1
    bad = ~np.isfinite(v) | (v != np.round(v)) | (v < low) | ((v > count) if count is not None else False)
    for k in np.flatnonzero(bad)[:1]:
        top = f"..{count}" if count is not None else ", 2, ..."
        where = " (the model file's)" if count is not None else ""
        raise InputError(
            f"{path}: row {rows[k]}, column '{column}': {values[k]:g}; expected a whole number 1{top}{where}"
            + (" or 0 (none)" if zero_ok else "")
        )
    ids = v.astype(int) - 1
    if count is None and not gaps:
        used = set(ids[ids >= 0].tolist())
        for k in sorted(set(range(max(used, default=-1) + 1)) - used)[:1]:
            raise InputError(
                f"{path}: column '{column}': {column} {k + 1} has no row but {column} {max(used) + 1} has: "
                f"number them 1, 2, ... without gaps"
            )
    return ids


def _optional(table, column: str, default: float) -> np.ndarray:
    return table.values[column] if column in table.values else np.full(table.rows.size, default)


def _sigma(path, table) -> np.ndarray:
    sigma = _optional(table, "sigma_mm", DEFAULT_SIGMA_MM)
    for k in np.flatnonzero(~(sigma > 0))[:1]:
        raise InputError(
            f"{path}: row {table.rows[k]}, column 'sigma_mm': {sigma[k]:g}; expected a number > 0"
        )
    return sigma


def read_plane_file(
    path: str | Path, robot: Robot, *, n_planes: int | None = None, gaps: bool = False
) -> dict:
    """A plane-contact file (module docstring): the fields of ``PlaneData`` (``q`` (n, n_joints)
    [rad; mm], 0-based ``plane`` (n,), ``distance`` and ``sigma`` (n,) [mm], ``target`` or None,
    ``source`` the file, ``rows`` its row numbers).

    Args:
        path: the CSV file; robot: the model (its joint columns and targets).
        n_planes: the planes of a model file (ids checked against them, held-out rows), or None.
        gaps: without ``n_planes``, ids may leave gaps (rows of some planes only, to fit them).

    Raises:
        InputError: naming the file, row and column: a missing column, text or NaN in a number,
            angles outside the limits, a plane id out of range, a gap in the ids, a plane with
            fewer than 3 rows (without ``n_planes``), a sigma <= 0.
    """
    table = read_joint_table(
        path,
        robot,
        required=("plane",),
        optional=(TARGET_COLUMN, "distance_mm", "sigma_mm"),
        suggest=("distance_mm", "sigma_mm"),
    )
    rows = table.rows
    plane = _ids(path, table.values["plane"], rows, "plane", n_planes, zero_ok=False, gaps=gaps)
    sigma = _sigma(path, table)
    if n_planes is None:
        counts = np.bincount(plane)
        for k in np.flatnonzero((counts > 0) & (counts < 3))[:1]:
            raise InputError(
                f"{path}: column 'plane': plane {k + 1} has {counts[k]} rows; a fitted plane needs 3 "
                "(contact points not on one line)"
            )
    return {
        "q": table.q,
        "plane": plane,
        "distance": _optional(table, "distance_mm", 0.0),
        "sigma": sigma,
        "target": table.target,
        "source": str(path),
        "rows": rows,
    }


def read_distance_file(
    path: str | Path,
    robot: Robot,
    *,
    n_pivots: int | None = None,
    n_bars: int | None = None,
    gaps: bool = False,
) -> dict:
    """A distance file (module docstring, pair or pivot layout): the fields of ``DistanceData``
    (pair rows: ``pivot`` -1; pivot rows: ``q_other`` NaN; ``bar`` -1: a known length).

    Args:
        path: the CSV file; robot: the model.
        n_pivots, n_bars: a model file's pivots and bars (ids checked against them), or None.
        gaps: without them, ids may leave gaps.

    Raises:
        InputError: naming the file, row and column (as :func:`read_plane_file`; a length <= 0; a
            file with neither layout's columns).
    """
    cols = q_columns(robot)
    pair = [p + c for p in PAIR_PREFIXES for c in cols]
    probe = read_joint_table(path, None, joints="none", optional=(*pair, *cols, "pivot"))
    has_pair = any(c in probe.header for c in pair)
    if not has_pair and "pivot" not in probe.header:
        raise InputError(
            f"{path}: row 1 (header): missing column {pair[0]!r} (pair rows: {pair[0]}, ... and "
            f"{PAIR_PREFIXES[1]}{cols[0]}, ...) or 'pivot' (pivot rows, with {cols[0]}, ...)"
        )
    extra = ("length_mm",)
    optional = ("bar", "sigma_mm")
    q_other: np.ndarray | None = None
    pivot: np.ndarray | None = None
    target: np.ndarray | None = None
    if has_pair:
        table = read_joint_table(
            path, None, joints="none", required=(*pair, *extra), optional=(*optional, TARGET_COLUMN)
        )
        rows = table.rows
        q2 = [
            joints_from_file(
                robot, np.stack([table.values[p + c] for c in cols], axis=1), path=path, rows=rows
            )
            for p in PAIR_PREFIXES
        ]
        q, q_other = q2
        if TARGET_COLUMN in table.header:
            numbers = _numbers(path, table.header, table.data, TARGET_COLUMN)
            target = parse_targets(
                path, numbers, rows, n_targets=robot.n_targets, model=robot.source or robot.name
            )
    else:
        table = read_joint_table(path, robot, required=("pivot", *extra), optional=(*optional, TARGET_COLUMN))
        rows, q, target = table.rows, cast(np.ndarray, table.q), table.target
        pivot = _ids(path, table.values["pivot"], rows, "pivot", n_pivots, zero_ok=False, gaps=gaps)
    bar = None
    if "bar" in table.values:
        bar = _ids(path, table.values["bar"], rows, "bar", n_bars, zero_ok=True, gaps=gaps)
    length = table.values["length_mm"]
    for k in np.flatnonzero(~(length > 0))[:1]:
        raise InputError(
            f"{path}: row {rows[k]}, column 'length_mm': {length[k]:g} mm; expected a length > 0"
        )
    return {
        "q": q,
        "length": length,
        "q_other": np.full_like(q, np.nan) if q_other is None else q_other,
        "pivot": np.full(rows.size, -1) if pivot is None else pivot,
        "bar": np.full(rows.size, -1) if bar is None else bar,
        "sigma": _sigma(path, table),
        "target": target,
        "source": str(path),
        "rows": rows,
    }
