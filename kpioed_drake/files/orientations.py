"""Orientation conventions: Euler angles, quaternions and rotation matrices -> rotation matrices.

Every function returns ``R`` (n, 3, 3) with the meaning of
:attr:`~kpioed_drake.tracker.data.Measurements.R_TP`: the probe frame P's orientation in the
tracker frame T, its columns the probe's axes in tracker coordinates (an active rotation,
``v_T = R v_P``). Pure numpy, vectorised over rows; scipy is not used, so that the tests, which
compare with ``scipy.spatial.transform.Rotation``, are an independent check.

- **Euler angles** (:func:`euler_to_matrix`): a ``sequence`` of three axis letters in capitals (one
  of :data:`SEQUENCES`) and a ``kind`` named explicitly (:data:`KINDS`), never read from the letter
  case. ``intrinsic`` ``"ABC"``: ``R = R_A(a1) R_B(a2) R_C(a3)`` (turn about A, then about the new B,
  then the newer C; scipy ``from_euler("ABC")``); ``extrinsic`` ``"ABC"``: ``R = R_C(a3) R_B(a2)
  R_A(a1)`` (turn about the fixed A, then the fixed B, then the fixed C; scipy ``from_euler("abc")``).
  The two differ for any sequence unless the angles are small.
- **quaternions** (:func:`quaternion_to_matrix`): Hamilton's, with the scalar's position named
  (``scalar``: ``first`` = ``w x y z``, ``last`` = ``x y z w``); a row whose norm is off 1 by more
  than :data:`QUATERNION_TOLERANCE` is an error naming it, the others are normalised.
- **matrices** (:func:`matrix_from_columns`): nine numbers per row in a named ``order``
  (``row_major``: r11 r12 r13 r21 ... r33; ``column_major``: r11 r21 r31 r12 ... r33); a row
  further than :data:`MATRIX_TOLERANCE` from orthonormal, or a reflection, is an error naming it,
  the others are replaced by the nearest rotation (polar factor, SVD).
- **Euler-angle sigmas** (:func:`euler_sigma_to_rotation_sigma`): per-row standard deviations of
  the three Euler angles -> the standard deviations of the small rotation about the tracker's x, y,
  z axes (:attr:`~kpioed_drake.tracker.data.Measurements.sigma_rot_rad`), through the Jacobian of
  the Euler map (:func:`euler_rate_jacobian`).

Messages name ``where`` (a file, or a label), the row (``rows``: the numbers to name, default
1..n) and the columns.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from kpioed_drake.errors import InputError

SEQUENCES = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ")
"""The twelve Euler sequences: six Tait-Bryan (three different axes) and six proper Euler."""
KINDS = ("intrinsic", "extrinsic")
"""Turns about the moving (body) axes, or about the fixed (tracker) axes."""
SCALAR_POSITIONS = ("first", "last")
"""Where a quaternion's scalar part is: ``first`` (w x y z) or ``last`` (x y z w)."""
MATRIX_ORDERS = ("row_major", "column_major")
"""The order of a matrix's nine numbers: row by row (r11 r12 r13 r21 ...) or column by column."""
ANGLE_UNITS = {"deg": np.pi / 180.0, "rad": 1.0}
"""Angle units and their size in radians."""
QUATERNION_TOLERANCE = 1e-3
"""A quaternion's largest ``|norm - 1|``: a larger one is not a unit quaternion written with six or
more digits (a wrong column, a missing sign), and is an error instead of being normalised."""
MATRIX_TOLERANCE = 1e-3
"""A matrix's largest ``|R^T R - I|`` entry: a larger one is no rotation written with six or more
digits; a smaller one is rounded to the nearest rotation."""
_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclasses.dataclass(frozen=True)
class Cells:
    """Where a block of values stands, for messages: ``where`` the file or label they begin with,
    ``rows`` the numbers to name the rows by (default 1..n), ``columns`` the columns' names."""

    where: str
    rows: ArrayLike | None = None
    columns: Sequence[str] = ()


def _label(cells: Cells, rows: np.ndarray, k: int) -> str:
    """``where: row r, columns 'a', 'b'`` of row ``k`` (0-based) of the block ``cells``."""
    columns = cells.columns
    cols = f", column{'s' if len(columns) > 1 else ''} {', '.join(map(repr, columns))}" if columns else ""
    return f"{cells.where}: row {rows[k]}{cols}"


def _rows(rows: ArrayLike | None, n: int) -> np.ndarray:
    return np.arange(1, n + 1) if rows is None else np.asarray(rows)


def _values(values: ArrayLike, width: int, what: str, cells: Cells) -> tuple[np.ndarray, np.ndarray]:
    """``values`` as an (n, width) float array (one row given as (width,)), every entry finite, and
    the (n,) numbers naming its rows."""
    where = cells.where
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InputError(f"{where}: expected {what} as (n, {width}) numbers, got shape {np.shape(values)}")
    rows = _rows(cells.rows, arr.shape[0])
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{_label(cells, rows, k)}: {what} {arr[k].tolist()} is not finite")
    return arr, rows


def _check_named(value: str, allowed: Iterable[str], where: str, field: str, say: str) -> None:
    """A convention field ``value`` among ``allowed``, else an error naming ``where``, the field and
    what to ``say``."""
    if value not in allowed:
        raise InputError(f"{where}: {field}: {missing_or(value, allowed)}; {say}")


def missing_or(value: str, allowed: Iterable[str]) -> str:
    """``missing (one of a, b, c)`` or ``'v' is not one of a, b, c``: a convention field's message."""
    return (
        f"missing (one of {', '.join(allowed)})"
        if not value
        else f"{value!r} is not one of {', '.join(allowed)}"
    )


def check_euler(
    sequence: str, kind: str, unit: str = "rad", where: str = "euler angles", field: str = ""
) -> None:
    """An Euler convention named in full.

    Args:
        sequence, kind, unit: the convention (:func:`euler_to_matrix`).
        where: the file or label messages begin with; field: the block the names belong to (a
            format file's ``orientation``: messages then name ``field 'orientation.kind'``).

    Raises:
        InputError: naming ``where`` and the field: a sequence not in :data:`SEQUENCES` (lowercase
            letters too: the kind is the field ``kind``, not the letter case), a missing or unknown
            ``kind``, a missing angle unit or one other than ``deg`` and ``rad``.
    """

    def name(n: str) -> str:
        return f"field '{field}.{n}'" if field else n

    if sequence not in SEQUENCES:
        hint = ""
        if sequence.upper() in SEQUENCES:
            hint = (
                f"; write the axes in capitals ({sequence.upper()!r}): intrinsic or extrinsic is "
                "the field 'kind', not the letter case (scipy's lowercase is extrinsic)"
            )
        raise InputError(f"{where}: {name('sequence')}: {missing_or(sequence, SEQUENCES)}{hint}")
    if kind not in KINDS:
        raise InputError(
            f"{where}: {name('kind')}: {missing_or(kind, KINDS)}; say intrinsic (turns about the moving "
            "axes, scipy 'XYZ') or extrinsic (about the fixed tracker axes, scipy 'xyz')"
        )
    if unit not in ANGLE_UNITS:
        raise InputError(f"{where}: {name('angle_unit')}: {missing_or(unit, ANGLE_UNITS)}")


def axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by ``angle`` (n,) [rad] about the axis ``X``, ``Y`` or ``Z``."""
    i = _AXES[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((np.size(angle), 3, 3))
    R[:, i, i] = 1.0
    R[:, j, j], R[:, k, k] = c, c
    R[:, k, j], R[:, j, k] = s, -s
    return R


def _factors(angles: np.ndarray, sequence: str, kind: str) -> list[np.ndarray]:
    """The three axis rotations in the order they multiply (left to right)."""
    factors = [axis_rotation(a, angles[:, m]) for m, a in enumerate(sequence)]
    return factors if kind == "intrinsic" else factors[::-1]


def euler_to_matrix(
    angles: ArrayLike, sequence: str, kind: str, unit: str = "rad", *, at: Cells | None = None
) -> np.ndarray:
    """(n, 3, 3) rotation matrices of Euler angles (module docstring for the conventions).

    Args:
        angles: (n, 3) or (3,) the angles of the sequence's first, second, third axis, in ``unit``.
        sequence: one of :data:`SEQUENCES`; kind: ``intrinsic`` or ``extrinsic``; unit: deg or rad.
        at: where the values stand, for messages (:class:`Cells`).

    Raises:
        InputError: an unknown sequence, kind or unit; a non-finite angle (row and columns named).
    """
    c = at or Cells("euler angles")
    check_euler(sequence, kind, unit, c.where)
    a, _ = _values(angles, 3, "Euler angles", c)
    f = _factors(a * ANGLE_UNITS[unit], sequence, kind)
    return f[0] @ f[1] @ f[2]


def euler_rate_jacobian(angles: ArrayLike, sequence: str, kind: str, unit: str = "rad") -> np.ndarray:
    """(n, 3, 3) ``J``: the angular velocity in the tracker frame per Euler-angle rate,
    ``omega_T = J d(angles)/dt`` [rad/s per rad/s], i.e. ``dR R^T = [J da]x``.

    Column m is the axis of the m-th turn in tracker coordinates: intrinsic
    ``R = A(a1) B(a2) C(a3)``: ``e_A, A e_B, A B e_C``; extrinsic ``R = C(a3) B(a2) A(a1)``:
    ``C B e_A, C e_B, e_C``.
    """
    check_euler(sequence, kind, unit)
    a, _ = _values(angles, 3, "Euler angles", Cells("euler angles"))
    a = a * ANGLE_UNITS[unit]
    n = a.shape[0]
    e = [np.broadcast_to(np.eye(3)[_AXES[c]], (n, 3)) for c in sequence]
    R1, R2, R3 = (axis_rotation(c, a[:, m]) for m, c in enumerate(sequence))
    if kind == "intrinsic":
        cols = [e[0], np.einsum("nij,nj->ni", R1, e[1]), np.einsum("nij,nj->ni", R1 @ R2, e[2])]
    else:
        cols = [np.einsum("nij,nj->ni", R3 @ R2, e[0]), np.einsum("nij,nj->ni", R3, e[1]), e[2]]
    return np.stack(cols, axis=2)


def euler_sigma_to_rotation_sigma(
    angles: ArrayLike, sigma: ArrayLike, sequence: str, kind: str, unit: str, *, at: Cells | None = None
) -> np.ndarray:
    """(n, 3) standard deviations [rad] of the small rotation about the tracker's x, y, z axes, from
    the standard deviations of the three Euler angles (independent, per row).

    The rotation's covariance is ``J diag(sigma^2) J^T`` with ``J`` of :func:`euler_rate_jacobian`
    at the row's angles (first order: a small change of the angles turns the frame by ``J da``
    about the tracker axes); the square roots of its diagonal are returned, its correlations are
    dropped (:attr:`~kpioed_drake.tracker.data.Measurements.sigma_rot_rad` holds three per row).
    The Jacobian itself is finite everywhere, so the mapping holds at gimbal lock too.

    Args:
        angles: (n, 3) the Euler angles; sigma: (n, 3) or (3,) their standard deviations; both in
            ``unit``. sequence, kind: as :func:`euler_to_matrix`.

    Raises:
        InputError: a non-finite or negative sigma, or sigmas that give no rotation noise (row and
            columns named).
    """
    c = at or Cells("euler angle sigmas")
    a, rows = _values(angles, 3, "Euler angles", Cells(c.where, c.rows))
    s = np.broadcast_to(np.asarray(sigma, dtype=float), a.shape)
    s, _ = _values(s, 3, "sigmas", c)
    bad = np.flatnonzero(np.any(s < 0, axis=1))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{_label(c, rows, k)}: sigmas {s[k].tolist()} must be >= 0")
    J = euler_rate_jacobian(a, sequence, kind, unit)
    s = s * ANGLE_UNITS[unit]
    out = np.sqrt(np.einsum("nij,nj->ni", J**2, s**2))
    bad = np.flatnonzero(np.any(out <= 0, axis=1))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{_label(c, rows, k)}: sigmas {s[k].tolist()} leave an axis without noise")
    return out


def quaternion_to_matrix(quaternions: ArrayLike, scalar: str, *, at: Cells | None = None) -> np.ndarray:
    """(n, 3, 3) rotation matrices of Hamilton quaternions (normalised).

    Args:
        quaternions: (n, 4) or (4,); scalar: ``first`` (w x y z) or ``last`` (x y z w).
        at: where the values stand, for messages (:class:`Cells`).

    Raises:
        InputError: an unknown scalar position; a non-finite entry or a norm off 1 by more than
            :data:`QUATERNION_TOLERANCE` (row and columns named).
    """
    c = at or Cells("quaternions")
    say = "say where the scalar part is (first: w x y z; last: x y z w)"
    _check_named(scalar, SCALAR_POSITIONS, c.where, "scalar", say)
    q, rows = _values(quaternions, 4, "quaternion", c)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_TOLERANCE)
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{_label(c, rows, k)}: quaternion {q[k].tolist()} has norm {norm[k]:.6g}, "
            f"not 1 (tolerance {QUATERNION_TOLERANCE:g}): a wrong column or a missing digit?"
        )
    q = q / norm[:, None]
    w, x, y, z = (
        (q[:, 0], q[:, 1], q[:, 2], q[:, 3]) if scalar == "first" else (q[:, 3], q[:, 0], q[:, 1], q[:, 2])
    )
    R = np.empty((q.shape[0], 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


def matrix_to_quaternion(R: ArrayLike, scalar: str = "first") -> np.ndarray:
    """(n, 4) unit Hamilton quaternions of rotation matrices (n, 3, 3), the scalar part >= 0.

    Shepperd's method: the largest of ``w, x, y, z`` is taken from the diagonal, the others from
    the off-diagonal sums, so no row loses precision.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    big = np.argmax(d, axis=1)
    q = np.empty((R.shape[0], 4))
    s21, s12 = R[:, 2, 1] - R[:, 1, 2], R[:, 2, 1] + R[:, 1, 2]
    s02, s20 = R[:, 0, 2] - R[:, 2, 0], R[:, 0, 2] + R[:, 2, 0]
    s10, s01 = R[:, 1, 0] - R[:, 0, 1], R[:, 1, 0] + R[:, 0, 1]
    for m in range(4):
        k = big == m
        if not k.any():
            continue
        r = np.sqrt(np.maximum(1.0 + 2.0 * d[k, m] - tr[k], 0.0)) if m else np.sqrt(1.0 + tr[k])
        f = 0.5 / r
        if m == 0:
            q[k] = np.stack([0.5 * r, s21[k] * f, s02[k] * f, s10[k] * f], axis=1)
        elif m == 1:
            q[k] = np.stack([s21[k] * f, 0.5 * r, s01[k] * f, s20[k] * f], axis=1)
        elif m == 2:
            q[k] = np.stack([s02[k] * f, s01[k] * f, 0.5 * r, s12[k] * f], axis=1)
        else:
            q[k] = np.stack([s10[k] * f, s20[k] * f, s12[k] * f, 0.5 * r], axis=1)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q if scalar == "first" else q[:, [1, 2, 3, 0]]


def matrix_from_columns(values: ArrayLike, order: str, *, at: Cells | None = None) -> np.ndarray:
    """(n, 3, 3) rotation matrices from nine numbers per row in ``order`` (:data:`MATRIX_ORDERS`).

    A row within :data:`MATRIX_TOLERANCE` of orthonormal is replaced by its nearest rotation (the
    rounding of a printed matrix); a farther one, or a reflection (determinant -1), is an error.

    Raises:
        InputError: an unknown order; a non-finite entry; a row that is no rotation (row named).
    """
    c = at or Cells("matrices")
    say = (
        "say how the nine numbers are ordered (row_major: r11 r12 r13 r21 ... r33; column_major: r11 r21 "
        "r31 r12 ... r33)"
    )
    _check_named(order, MATRIX_ORDERS, c.where, "order", say)
    v, rows = _values(values, 9, "matrix", c)
    M = v.reshape(-1, 3, 3)
    if order == "column_major":
        M = M.transpose(0, 2, 1)
    err = np.abs(np.einsum("nji,njk->nik", M, M) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(M)
    bad = np.flatnonzero((err > MATRIX_TOLERANCE) | (det < 0))
    if bad.size:
        k = int(bad[0])
        what = "a reflection (determinant < 0)" if det[k] < 0 else f"R^T R - I reaches {err[k]:.3g}"
        raise InputError(
            f"{_label(c, rows, k)}: the matrix is not a rotation: {what} "
            f"(tolerance {MATRIX_TOLERANCE:g}; order {order})"
        )
    U, _, Vt = np.linalg.svd(M)
    return U @ Vt


def rotation_angle(R_a: ArrayLike, R_b: ArrayLike) -> np.ndarray:
    """(n,) the angle [rad] of the rotation ``R_a^T R_b`` between two orientations, row by row.

    The angle between two measured orientations of one rigid probe equals the angle between the
    flange's orientations at the two poses whatever the probe's mounting and the tracker's pose:
    the check of an Euler convention on data (``docs/data-formats.md``).
    """
    M = np.swapaxes(np.asarray(R_a, dtype=float), -1, -2) @ np.asarray(R_b, dtype=float)
    cos = (np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    sin = (
        np.linalg.norm(
            np.stack(
                [M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]],
                axis=-1,
            ),
            axis=-1,
        )
        / 2.0
    )
    return np.arctan2(sin, cos)
