"""The orientation columns of a measurement file -> a 6-DoF probe's ``R_TP`` and ``sigma_rot_rad``.

Two layouts, as for the positions (:mod:`kpioed_drake.files.tables`):

- the native CSV: optional columns ``qw, qx, qy, qz`` (:data:`QUATERNION_COLUMNS`: a unit Hamilton
  quaternion, scalar first, of the probe frame P's orientation in the tracker frame T) and
  ``sigma_rx_deg, sigma_ry_deg, sigma_rz_deg`` (:data:`SIGMA_COLUMNS`: standard deviations of the
  small rotation about the tracker's x, y, z axes [deg]); all four or none, all three or none, and
  sigmas only with a quaternion. :meth:`~kpioed_drake.tracker.data.Measurements.to_frame` writes
  them (the quaternion's scalar >= 0);
- a format file's ``orientation`` block (:class:`~kpioed_drake.files.formats.OrientationSpec`):
  Euler angles, a quaternion or a matrix in the conventions it names
  (:mod:`kpioed_drake.files.orientations`), with per-row sigma columns (of the Euler angles, mapped
  to the tracker axes, or of the tracker axes) or one constant sigma.

Both give ``{"R_TP": (n, 3, 3), "sigma_rot_rad": (n, 3)}`` (without sigmas no ``sigma_rot_rad``,
without orientation an empty dict), keyword arguments of
:meth:`~kpioed_drake.tracker.data.Measurements.from_arrays`.
The caller reads the columns (file, row and column in its messages) and passes their numbers, so
this module reads no file itself.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files.formats import OrientationSpec
from kpioed_drake.files.orientations import (
    ANGLE_UNITS,
    Cells,
    euler_sigma_to_rotation_sigma,
    euler_to_matrix,
    matrix_from_columns,
    matrix_to_quaternion,
    quaternion_to_matrix,
)

QUATERNION_COLUMNS = ("qw", "qx", "qy", "qz")
"""The native file's orientation: a unit quaternion, scalar first (R_TP, Hamilton)."""
SIGMA_COLUMNS = ("sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg")
"""The native file's orientation noise: standard deviations about the tracker's x, y, z axes [deg]."""
NATIVE_COLUMNS = QUATERNION_COLUMNS + SIGMA_COLUMNS
"""Every native orientation column (none of them is an unused column of the file)."""


def _positive(path: str | Path, values: np.ndarray, rows: np.ndarray, columns: Sequence[str]) -> None:
    """Sigmas are > 0 (the first other one named by row and column)."""
    bad = np.argwhere(~(values > 0))
    if bad.size:
        k, j = (int(i) for i in bad[0])
        raise InputError(
            f"{path}: row {rows[k]}, column {columns[j]!r}: {values[k, j]:g} is no standard deviation "
            "(expected > 0)"
        )


def native_orientation(
    path: str | Path, header: Sequence[str], values: Mapping[str, np.ndarray], rows: np.ndarray
) -> dict:
    """The native columns :data:`QUATERNION_COLUMNS` and :data:`SIGMA_COLUMNS` of a file.

    Args:
        path: the file (for messages); header: its columns; values: ``{column: (n,)}`` the
            orientation columns it has, as numbers; rows: (n,) the row numbers.

    Returns:
        ``{}`` without a quaternion, else ``R_TP`` and, with the sigma columns, ``sigma_rot_rad``.

    Raises:
        InputError: part of a group of columns, sigmas without a quaternion, a quaternion whose norm
            is not 1, a sigma that is not > 0 (file, row and columns named).
    """
    for group in (QUATERNION_COLUMNS, SIGMA_COLUMNS):
        given = [c in header for c in group]
        if any(given) and not all(given):
            missing = group[given.index(False)]
            raise InputError(
                f"{path}: row 1 (header): missing column {missing!r} (an orientation's columns are "
                f"{', '.join(group)}, all or none)"
            )
    if SIGMA_COLUMNS[0] in header and QUATERNION_COLUMNS[0] not in header:
        raise InputError(
            f"{path}: row 1 (header): orientation sigmas ({', '.join(SIGMA_COLUMNS)}) without an "
            f"orientation ({', '.join(QUATERNION_COLUMNS)})"
        )
    if QUATERNION_COLUMNS[0] not in header:
        return {}
    quat = np.stack([values[c] for c in QUATERNION_COLUMNS], axis=1)
    R = quaternion_to_matrix(quat, "first", at=Cells(str(path), rows, QUATERNION_COLUMNS))
    if SIGMA_COLUMNS[0] not in header:
        return {"R_TP": R}
    sigma = np.stack([values[c] for c in SIGMA_COLUMNS], axis=1)
    _positive(path, sigma, rows, SIGMA_COLUMNS)
    return {"R_TP": R, "sigma_rot_rad": np.deg2rad(sigma)}


def native_columns(R_TP: np.ndarray | None, sigma_rot_rad: np.ndarray | None) -> dict:
    """``{column: (n,)}``: the native orientation columns of ``R_TP`` and ``sigma_rot_rad`` (either
    may be None): what :func:`native_orientation` reads back."""
    out: dict[str, np.ndarray] = {}
    if R_TP is not None:
        quat = matrix_to_quaternion(R_TP, "first")
        out |= {c: quat[:, i] for i, c in enumerate(QUATERNION_COLUMNS)}
    if sigma_rot_rad is not None:
        out |= {c: np.rad2deg(sigma_rot_rad[:, i]) for i, c in enumerate(SIGMA_COLUMNS)}
    return out


def format_orientation(
    path: str | Path, spec: OrientationSpec, values: Mapping[str, np.ndarray], rows: np.ndarray
) -> dict:
    """A format file's ``orientation`` block read from the data file.

    Args:
        path: the data file; spec: the checked block; values: ``{column: (n,)}`` its columns
            and sigma columns as numbers (read by the caller, whose messages name the format
            field of a column the file lacks); rows: (n,) the row numbers.

    Returns:
        ``R_TP`` (n, 3, 3) and, with a sigma, ``sigma_rot_rad`` (n, 3) [rad].

    Raises:
        InputError: naming the file, row and columns (a non-finite angle, a quaternion that is not a
            unit one, a matrix that is no rotation, a sigma that is not > 0).
    """
    where, cols = str(path), list(spec.columns)
    v = np.stack([values[c] for c in cols], axis=1)
    args = (spec.sequence, spec.kind, spec.angle_unit)
    if spec.representation == "euler":
        R = euler_to_matrix(v, *args, at=Cells(where, rows, cols))
    elif spec.representation == "quaternion":
        R = quaternion_to_matrix(v, spec.scalar, at=Cells(where, rows, cols))
    else:
        R = matrix_from_columns(v, spec.order, at=Cells(where, rows, cols))
    n = len(rows)
    sigma = None
    if spec.sigma_columns:
        names = list(spec.sigma_columns)
        s = np.stack([values[c] for c in names], axis=1)
        _positive(path, s, rows, names)
        if spec.sigma_of == "euler_angles":
            sigma = euler_sigma_to_rotation_sigma(v, s, *args, at=Cells(where, rows, names))
        else:
            sigma = s * ANGLE_UNITS[spec.angle_unit]
    elif spec.sigma_deg is not None:
        sigma = np.full((n, 3), np.deg2rad(spec.sigma_deg))
    elif spec.sigma_rad is not None:
        sigma = np.full((n, 3), float(spec.sigma_rad))
    return {"R_TP": R} if sigma is None else {"R_TP": R, "sigma_rot_rad": sigma}
