"""Measured distances and plane contacts: the data types :class:`DistanceData` and :class:`PlaneData`.

Measurements without a laser tracker (:mod:`kpioed_drake.tracker.contacts`):

- a *distance* row is a measured length [mm] between the tool points of two poses (a length bar
  whose ends the tool touches, a ballbar between two poses) or between the tool point of one pose
  and a fixed *pivot* (a draw-wire sensor, a ballbar's centre cup); rows may share a *bar*, whose
  length error (one unknown correction ``dL`` [mm] added to every measured length of its rows) is
  estimated;
- a *plane* row is a pose whose tool point touches plane ``k`` (a touch probe), with the measured
  signed distance to the plane (0 for a touch; a deflection reading otherwise) [mm].

Both are built with ``from_arrays`` in internal units (joint values [rad; prismatic mm], lengths
[mm]) and checked there: every message names the data's ``source``, the row and the field. Indices
(pivot, bar, plane, target) are 0-based; ``rows`` are the numbers the messages give (default
1, 2, ...).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.files.contacts import read_distance_file, read_plane_file

ArrayLike = np.ndarray | Sequence[float] | float


def _per_row(value, n: int, name: str, source: str) -> np.ndarray:
    """(n,) floats from one number or one per row; InputError naming the field otherwise."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise InputError(f"{source}: {name}: expected one number or {n} (one per row), got shape {arr.shape}")
    return arr


def _indices(value, n: int, name: str, source: str, rows: np.ndarray, *, minimum: int) -> np.ndarray:
    """(n,) integer indices >= ``minimum`` (None: zeros); InputError naming the first bad row."""
    if value is None:
        return np.zeros(n, dtype=int)
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,):
        raise InputError(f"{source}: {name}: expected (n,) = ({n},) indices, got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr) | (arr != np.round(arr)) | (arr < minimum))
    if bad.size:
        k = bad[0]
        raise InputError(
            f"{source}: row {rows[k]}, {name}: {arr[k]:g} is no whole number >= {minimum} (0-based)"
        )
    return arr.astype(int)


def _check_rows(
    source: str, rows: np.ndarray, q: np.ndarray, sigma: np.ndarray, n_joints: int | None
) -> None:
    """Joint values (n, n_joints) finite and sigmas finite and > 0, the first bad row named."""
    n = q.shape[0]
    if q.ndim != 2 or (n_joints is not None and q.shape[1] != n_joints) or q.shape[1] == 0:
        want = "n_joints" if n_joints is None else n_joints
        raise InputError(f"{source}: q: expected (n, {want}) joint values, got shape {q.shape}")
    if rows.shape != (n,):
        raise InputError(f"{source}: rows: expected one row number per row, got shape {rows.shape}")
    for k in np.flatnonzero(~np.all(np.isfinite(q), axis=1))[:1]:
        raise InputError(f"{source}: row {rows[k]}, q: a joint value is not a finite number")
    for k in np.flatnonzero(~np.isfinite(sigma) | (sigma <= 0))[:1]:
        raise InputError(f"{source}: row {rows[k]}, sigma_mm: {sigma[k]:g} mm; expected a number > 0")


def _checked(
    q, sigma_mm: ArrayLike, target, n_joints: int | None, source: str, rows
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """What every contact row has, checked: the poses (n, n_joints), the row numbers (n,) (default
    1, 2, ...), the sigmas (n,) [mm] and the 0-based targets (n,) or None."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    rows_ = np.arange(1, n + 1) if rows is None else np.asarray(rows)
    sigma = _per_row(sigma_mm, n, "sigma_mm", source)
    _check_rows(source, rows_, q, sigma, n_joints)
    target_ = None if target is None else _indices(target, n, "target", source, rows_, minimum=0)
    return q, rows_, sigma, target_


def _unused(idx: np.ndarray, count: int) -> list[int]:
    """The 0-based indices below ``count`` no row uses."""
    return sorted(set(range(count)) - set(idx.tolist()))


@dataclasses.dataclass(frozen=True)
class DistanceData:
    """Measured distances between tool points (pairs of poses) or to fixed pivots.

    Attributes:
        q: (n, n_joints) the pose of each row [rad; mm].
        length: (n,) measured distances [mm] (> 0).
        q_other: (n, n_joints) the second pose of pair rows (pivot rows: ignored, NaN allowed).
        pivot: (n,) 0-based pivot of each pivot row, -1 for pair rows.
        bar: (n,) 0-based bar whose length correction the row's length shares, -1: the length is
            known (no correction).
        sigma: (n,) noise of the measured lengths [mm].
        target: (n,) 0-based target (tool point) of each row, or None (target 0).
        source: a label for messages.
        rows: (n,) row numbers for messages.
    """

    q: np.ndarray
    length: np.ndarray
    q_other: np.ndarray
    pivot: np.ndarray
    bar: np.ndarray
    sigma: np.ndarray
    target: np.ndarray | None = None
    source: str = "distances"
    rows: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def is_pair(self) -> np.ndarray:
        """(n,) True for rows between two poses, False for rows to a pivot."""
        return self.pivot < 0

    @property
    def n_pivots(self) -> int:
        return int(self.pivot.max(initial=-1)) + 1

    @property
    def n_bars(self) -> int:
        return int(self.bar.max(initial=-1)) + 1

    @classmethod
    def from_arrays(
        cls,
        q: np.ndarray,
        length_mm: ArrayLike,
        *,
        q_other: np.ndarray | None = None,
        pivot: Sequence[int] | np.ndarray | None = None,
        bar: Sequence[int] | np.ndarray | None = None,
        sigma_mm: ArrayLike = 0.01,
        target: Sequence[int] | np.ndarray | None = None,
        n_joints: int | None = None,
        source: str = "distances",
        rows: Sequence[int] | np.ndarray | None = None,
    ) -> DistanceData:
        """Checked distance rows.

        Args:
            q: (n, n_joints) the pose of each row [rad; mm].
            length_mm: (n,) measured distances [mm].
            q_other: (n, n_joints) the second poses (None: every row is a pivot row).
            pivot: (n,) 0-based pivot per row, -1 for a pair row (None: every row is a pair row).
            bar: (n,) 0-based bar per row, -1 for a known length (None: every length known).
            sigma_mm: the lengths' noise, one number or one per row [mm].
            target: (n,) 0-based tool target per row (None: target 0).
            n_joints: the robot's joint count (checked when given).
            source, rows: the label and row numbers messages name (rows default 1, 2, ...).

        Raises:
            InputError: naming the row and field: shapes, non-finite values, a length <= 0, a pair
                row without its second pose, a pivot or bar index that no row uses below the
                largest, a sigma <= 0.
        """
        q, rows_, sigma, target_ = _checked(q, sigma_mm, target, n_joints, source, rows)
        n = q.shape[0]
        length = _per_row(length_mm, n, "length_mm", source)
        pivot_ = np.full(n, -1) if pivot is None else _indices(pivot, n, "pivot", source, rows_, minimum=-1)
        if pivot is None and q_other is None:
            raise InputError(f"{source}: give q_other (pairs of poses), pivot (distances to pivots) or both")
        bar_ = np.full(n, -1) if bar is None else _indices(bar, n, "bar", source, rows_, minimum=-1)
        other = np.full_like(q, np.nan) if q_other is None else np.asarray(q_other, dtype=float)
        if other.shape != q.shape:
            raise InputError(f"{source}: q_other: expected shape {q.shape} like q, got {other.shape}")
        pair = pivot_ < 0
        for k in np.flatnonzero(pair & ~np.all(np.isfinite(other), axis=1))[:1]:
            raise InputError(
                f"{source}: row {rows_[k]}, q_other: a pair row (pivot -1) needs its second pose"
            )
        for k in np.flatnonzero(~np.isfinite(length) | (length <= 0))[:1]:
            raise InputError(
                f"{source}: row {rows_[k]}, length_mm: {length[k]:g} mm; expected a distance > 0"
            )
        data = cls(q, length, other, pivot_, bar_, sigma, target_, str(source), rows_)
        for name, idx, count in (("pivot", pivot_, data.n_pivots), ("bar", bar_, data.n_bars)):
            if missing := _unused(idx, count):
                raise InputError(
                    f"{source}: {name} {missing[0]} (0-based) has no row, but {name} {count - 1} has: "
                    f"number the {name}s 0, 1, ... without gaps"
                )
        return data


@dataclasses.dataclass(frozen=True)
class PlaneData:
    """Poses whose tool point touches one of several planes.

    Attributes:
        q: (n, n_joints) the pose of each row [rad; mm].
        plane: (n,) 0-based plane each row touches.
        distance: (n,) measured signed distance of the tool point to the plane [mm] (0: a touch).
        sigma: (n,) noise of the contact along the normal [mm].
        target: (n,) 0-based target (tool point), or None (target 0).
        source: a label for messages.
        rows: (n,) row numbers for messages.
    """

    q: np.ndarray
    plane: np.ndarray
    distance: np.ndarray
    sigma: np.ndarray
    target: np.ndarray | None = None
    source: str = "planes"
    rows: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @property
    def n_planes(self) -> int:
        return int(self.plane.max(initial=-1)) + 1

    @classmethod
    def from_arrays(
        cls,
        q: np.ndarray,
        plane: Sequence[int] | np.ndarray,
        *,
        distance_mm: ArrayLike = 0.0,
        sigma_mm: ArrayLike = 0.01,
        target: Sequence[int] | np.ndarray | None = None,
        n_joints: int | None = None,
        source: str = "planes",
        rows: Sequence[int] | np.ndarray | None = None,
    ) -> PlaneData:
        """Checked plane-contact rows.

        Args:
            q: (n, n_joints) the pose of each row [rad; mm].
            plane: (n,) 0-based plane per row.
            distance_mm: measured signed distances, one number or one per row [mm] (default 0).
            sigma_mm: the contacts' noise, one number or one per row [mm].
            target: (n,) 0-based tool target per row (None: target 0).
            n_joints: the robot's joint count (checked when given).
            source, rows: the label and row numbers messages name (rows default 1, 2, ...).

        Raises:
            InputError: naming the row and field: shapes, non-finite values, a sigma <= 0, a plane
                index that no row uses below the largest, a plane with fewer than 3 rows.
        """
        q, rows_, sigma, target_ = _checked(q, sigma_mm, target, n_joints, source, rows)
        distance = _per_row(distance_mm, q.shape[0], "distance_mm", source)
        plane_ = _indices(plane, q.shape[0], "plane", source, rows_, minimum=0)
        for k in np.flatnonzero(~np.isfinite(distance))[:1]:
            raise InputError(f"{source}: row {rows_[k]}, distance_mm: not a finite number")
        data = cls(q, plane_, distance, sigma, target_, str(source), rows_)
        counts = np.bincount(plane_, minlength=data.n_planes)
        for k in np.flatnonzero(counts < 3)[:1]:
            raise InputError(
                f"{source}: plane {k} (0-based) has {counts[k]} rows; a plane needs at least 3 contact "
                "points not on one line"
            )
        return data


def _renumbered(ids: np.ndarray) -> np.ndarray:
    """Ids >= 0 numbered 0, 1, ... in their order (-1 stays -1)."""
    out = ids.copy()
    used = ids >= 0
    out[used] = np.unique(ids[used], return_inverse=True)[1]
    return out


def _row_fields(f: dict, robot) -> dict:
    """The ``from_arrays`` arguments every contact file gives alike (sigmas, targets, source, rows),
    from a file reader's dict, and the robot's joint count."""
    keys = {"sigma_mm": "sigma", "target": "target", "source": "source", "rows": "rows"}
    return {name: f[key] for name, key in keys.items()} | {"n_joints": robot.n_joints}


def read_planes(path, robot, *, n_planes: int | None = None, renumber: bool = False) -> PlaneData:
    """A plane-contact file (:func:`kpioed_drake.files.contacts.read_plane_file`) as :class:`PlaneData`:
    checked as a fit needs its rows (``n_planes`` None), or held-out rows of ``n_planes`` known planes
    (ids up to them, any count per plane); ``renumber``: the planes the rows touch numbered 0, 1, ...
    (rows of some planes only, whose planes are fitted to them; 3 rows a plane at least)."""
    f = read_plane_file(path, robot, n_planes=n_planes, gaps=renumber)
    if n_planes is not None:
        return PlaneData(**f)
    if renumber:
        f["plane"] = _renumbered(f["plane"])
    return PlaneData.from_arrays(f["q"], f["plane"], distance_mm=f["distance"], **_row_fields(f, robot))


def read_distances(
    path, robot, *, n_pivots: int | None = None, n_bars: int | None = None, renumber: bool = False
) -> DistanceData:
    """A distance file (:func:`kpioed_drake.files.contacts.read_distance_file`) as :class:`DistanceData`:
    checked as a fit needs its rows (counts None), or held-out rows of a model file's pivots and bars;
    ``renumber``: the pivots and bars the rows use numbered 0, 1, ... (fitted to them)."""
    f = read_distance_file(path, robot, n_pivots=n_pivots, n_bars=n_bars, gaps=renumber)
    if n_pivots is not None or n_bars is not None:
        return DistanceData(**f)
    if renumber:
        f["pivot"], f["bar"] = _renumbered(f["pivot"]), _renumbered(f["bar"])
    pair = f["pivot"] < 0
    return DistanceData.from_arrays(
        f["q"],
        f["length"],
        q_other=f["q_other"] if pair.any() else None,
        pivot=f["pivot"],
        bar=f["bar"],
        **_row_fields(f, robot),
    )
