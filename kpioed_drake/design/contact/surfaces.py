"""The contact systems of a contact design: the surfaces a design pose's tool point lies on.

A contact design keeps each pose's nominal tool point ``p = p_WQ(q)`` (target 0) on one of K
surfaces, one equality ``r_k(p) = 0`` per pose, and measures one number there:

- :class:`Planes` (a touch probe): plane k, ``r = n_k . p - d_k`` (unit normal ``n_k`` towards the
  free side, offset ``d_k`` [mm]); the row is the plane row of :mod:`kpioed_drake.tracker.plane`,
  its environment columns the plane's two tilts and offset;
- :class:`Pivots` (a ballbar): pivot k at ``c_k`` in W with a bar of nominal length ``L_k`` [mm]
  between the pivot's ball and the tool ball, ``r = |p - c_k| - L_k``; the row is the pivot row of
  :mod:`kpioed_drake.tracker.distance` (known length), its environment columns the pivot's position.

Each system gives what the design needs of it: the residual and its gradient ``dr/dp`` (the unit
normal, or ``u = (p - c) / |p - c|`` whose own derivative ``du/dq = (I - u u^T) dp/dq / |p - c|``
enters dF1/dq), the environment columns of a row and their joint derivatives, which surface a
pose is on (the nearest), the rules a pose must keep besides the equality (:meth:`admissible`) and
the cells its poses are checked in (:meth:`cells`; with the bar as the beam for a ballbar).

The ballbar's rules (:data:`BALLBAR`, choices documented in docs/contacts.md): the tool cup holds
the tool ball from the flange's side, so the bar leaves the ball within 70 degrees of the tool's
axis (flange origin to ball); the pivot's cup sits on a stand, so the bar points at most 20 degrees
below the horizontal (a centre pivot admits 220 degree arcs in a vertical plane). With collision
avoidance the bar (a capsule of 10 mm radius from the tool ball to the pivot) is checked as the
laser beam is (the robot's ``beam_links`` and the car), and the stand (a capsule of 25 mm radius
from the pivot down to the floor) is an obstacle of the robot.
Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import ClassVar, Self

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.cell import Obstacle
from kpioed_drake.robot.models import Cell
from kpioed_drake.robot.parameters import ParameterLayout
from kpioed_drake.tracker.plane import tangent_basis

FLANGE_CLEARANCE_MM = 20.0
"""A touch's flange origin stays at least this far on the plane's free side [mm]."""


@dataclasses.dataclass(frozen=True)
class Ballbar:
    """A pivot ballbar's hardware as the design models it (choices, docs/contacts.md).

    Attributes:
        cup_deg: the bar leaves the tool ball within this angle of the tool's axis (flange origin to
            ball) [deg].
        dip_deg: the bar points at most this far below the horizontal from the pivot [deg].
        bar_radius_mm: radius of the bar's capsule (the bar and its cups) [mm].
        stand_radius_mm: radius of the pivot's stand, a capsule from the pivot down to the floor [mm].
    """

    cup_deg: float = 70.0
    dip_deg: float = 20.0
    bar_radius_mm: float = 10.0
    stand_radius_mm: float = 25.0


BALLBAR = Ballbar()
"""The hardware of the ballbar designs."""


@dataclasses.dataclass(frozen=True)
class Words:
    """How messages name a system's designs (``label``), poses (``noun``), where those are (``on``)
    and what to check when too few are feasible (``hint``)."""

    label: str
    noun: str
    on: str
    hint: str


class _Arrays:
    """Surfaces held as arrays of one entry per surface: their count and a subset."""

    def __len__(self) -> int:
        return len(getattr(self, dataclasses.fields(self)[0].name))

    def subset(self, idx: Sequence[int] | np.ndarray) -> Self:
        """The surfaces ``idx`` alone (renumbered 0, 1, ...)."""
        return dataclasses.replace(
            self, **{f.name: getattr(self, f.name)[idx] for f in dataclasses.fields(self)}
        )


@dataclasses.dataclass(frozen=True)
class Planes(_Arrays):
    """K planes ``n_k . x = d_k`` in W: ``normals`` (K, 3) unit, towards the free side, ``offsets``
    (K,) [mm]."""

    normals: np.ndarray
    offsets: np.ndarray
    kind: ClassVar[str] = "plane"
    words: ClassVar[Words] = Words(
        "plane-contact", "touches", "of the planes", "planes (within reach, a free side the flange can be on)"
    )
    curved: ClassVar[bool] = False  # the gradient (the normal) does not turn with the pose
    beam: ClassVar[bool] = False  # no beam is checked

    def residual(self, p: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n,) ``n_k . p - d_k`` [mm] of tool points ``p`` (n, 3) on planes ``k`` (n,)."""
        return np.sum(self.normals[k] * p, axis=1) - self.offsets[k]

    def gradient(self, p: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n, 3) ``dr/dp``: the normals."""
        return self.normals[k]

    def gradient_dq(self, p: np.ndarray, k: np.ndarray, dp: np.ndarray) -> None:
        """A plane's normal does not turn with the pose (None)."""
        return None

    def nearest(self, p: np.ndarray) -> np.ndarray:
        """(n,) the plane each tool point (n, 3) is nearest to."""
        return np.argmin(np.abs(p @ self.normals.T - self.offsets), axis=1)

    def admissible(self, p: np.ndarray, o_F: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n,) the flange origins ``o_F`` (n, 3) at least :data:`FLANGE_CLEARANCE_MM` on the free side."""
        return np.sum(self.normals[k] * o_F, axis=1) - self.offsets[k] >= FLANGE_CLEARANCE_MM

    def columns(self, layout: ParameterLayout, k: np.ndarray) -> np.ndarray:
        """(n, 3) the parameters of planes ``k``: tilts and offset."""
        return layout.plane_columns(k)

    def environment(
        self, p: np.ndarray, k: np.ndarray, dp: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The rows' values in :meth:`columns` (n, 3) and, with ``dp`` (n, nj, 3) = dp/dq, their
        joint derivatives (n, nj, 3): ``(e_i - (n . e_i) n) . p`` for the tilts (at tilts 0), -1."""
        nk, E = self.normals[k], tangent_basis(self.normals)[k]  # (n, 3), (n, 2, 3)
        n_e = np.einsum("nij,nj->ni", E, nk)  # (n, 2), 0 at the reference normal (tilts 0)
        tilt = E - n_e[:, :, None] * nk[:, None, :]  # (n, 2, 3): d(dr/dt_i)/dp
        vals = np.concatenate([np.einsum("nij,nj->ni", tilt, p), np.full((len(p), 1), -1.0)], axis=1)
        if dp is None:
            return vals, None
        dt = np.einsum("nij,nqj->nqi", tilt, dp)  # (n, nj, 2)
        return vals, np.concatenate([dt, np.zeros(dt.shape[:2] + (1,))], axis=2)

    def cells(self, cell: Cell) -> tuple[Cell, ...]:
        """The cell every touch is checked in (the planes are not obstacles; no beam: :attr:`beam`)."""
        return (cell,)

    def record(self) -> list[dict]:
        """The planes as a JSON record (unit normal, offset [mm])."""
        return [
            {"normal": n.tolist(), "offset_mm": float(d)}
            for n, d in zip(self.normals, self.offsets, strict=True)
        ]


@dataclasses.dataclass(frozen=True)
class Pivots(_Arrays):
    """K ballbar pivots: centres ``centres`` (K, 3) in W [mm] and bar lengths ``lengths`` (K,) [mm]."""

    centres: np.ndarray
    lengths: np.ndarray
    kind: ClassVar[str] = "pivot"
    words: ClassVar[Words] = Words(
        "ballbar",
        "poses",
        "on the pivots' spheres",
        "pivots and bar lengths (within reach, room for the bar and its stand)",
    )
    curved: ClassVar[bool] = True  # the gradient (the bar's direction) turns with the pose
    beam: ClassVar[bool] = True  # the bar is checked as the beam

    def residual(self, p: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n,) ``|p - c_k| - L_k`` [mm]."""
        return np.linalg.norm(p - self.centres[k], axis=1) - self.lengths[k]

    def gradient(self, p: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n, 3) ``dr/dp = u``, the unit vector from the pivot to the tool point."""
        diff = p - self.centres[k]
        return diff / np.linalg.norm(diff, axis=1, keepdims=True)

    def gradient_dq(self, p: np.ndarray, k: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """(n, nj, 3) ``du/dq_j = (dp_j - (u . dp_j) u) / |p - c|``."""
        diff = p - self.centres[k]
        d = np.linalg.norm(diff, axis=1)
        u = diff / d[:, None]
        along = np.einsum("nqi,ni->nq", dp, u)
        return (dp - along[:, :, None] * u[:, None, :]) / d[:, None, None]

    def nearest(self, p: np.ndarray) -> np.ndarray:
        """(n,) the pivot whose sphere each tool point (n, 3) is nearest to."""
        dist = np.linalg.norm(p[:, None, :] - self.centres[None], axis=2)
        return np.argmin(np.abs(dist - self.lengths), axis=1)

    def admissible(self, p: np.ndarray, o_F: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(n,) the bar within ``BALLBAR.cup_deg`` of the tool's axis and at most
        ``BALLBAR.dip_deg`` below the horizontal."""
        bar = self.centres[k] - p  # tool ball -> pivot
        L = np.linalg.norm(bar, axis=1)
        tool = p - o_F
        cos_cup = np.sum(bar * tool, axis=1) / (L * np.linalg.norm(tool, axis=1))
        dip = -bar[:, 2] / L  # sine of the bar's elevation seen from the pivot
        return (cos_cup >= np.cos(np.deg2rad(BALLBAR.cup_deg))) & (
            dip >= -np.sin(np.deg2rad(BALLBAR.dip_deg))
        )

    def columns(self, layout: ParameterLayout, k: np.ndarray) -> np.ndarray:
        """(n, 3) the parameters of pivots ``k``: the position."""
        return layout.pivot_columns(k)

    def environment(
        self, p: np.ndarray, k: np.ndarray, dp: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The rows' values in :meth:`columns` (n, 3), ``-u``, and their joint derivatives ``-du/dq``."""
        vals = -self.gradient(p, k)
        return vals, None if dp is None else -self.gradient_dq(p, k, dp)

    def cells(self, cell: Cell) -> tuple[Cell, ...]:
        """One cell per pivot, whose poses are checked in it: the pivot's stand an obstacle, the bar
        the laser beam (the tracker at the pivot, the beam's radius the bar's; :attr:`beam`)."""
        out = []
        for k, c in enumerate(self.centres):
            foot = np.array([c[0], c[1], cell.floor_z])
            stand = Obstacle(f"pivot{k + 1}_stand", BALLBAR.stand_radius_mm, c.copy(), foot)
            out.append(
                dataclasses.replace(
                    cell, p_WT=c.copy(), beam_radius=BALLBAR.bar_radius_mm, obstacles=(*cell.obstacles, stand)
                )
            )
        return tuple(out)

    def record(self) -> list[dict]:
        """The pivots as a JSON record (position [mm], bar length [mm])."""
        return [
            {"pivot_mm": c.tolist(), "bar_length_mm": float(L)}
            for c, L in zip(self.centres, self.lengths, strict=True)
        ]


Surfaces = Planes | Pivots
"""A contact system's surfaces."""


def planes(normals: Sequence[Sequence[float]] | np.ndarray, offsets: Sequence[float] | np.ndarray) -> Planes:
    """Checked :class:`Planes` from normals (K, 3) (normalised here) and offsets (K,) [mm].

    Raises:
        InputError: shapes, a zero or non-finite normal, a non-finite offset.
    """
    N = np.atleast_2d(np.asarray(normals, dtype=float))
    d = np.asarray(offsets, dtype=float).reshape(-1)
    if N.ndim != 2 or N.shape[1] != 3 or N.shape[0] != d.size or d.size == 0:
        raise InputError(f"planes: {N.shape} normals and {d.size} offsets; expected (K, 3) and (K,)")
    norm = np.linalg.norm(N, axis=1)
    if not np.all(norm > 0):
        raise InputError("planes: a normal is zero")
    if not (np.all(np.isfinite(N)) and np.all(np.isfinite(d))):
        raise InputError("planes: a normal or an offset is not a finite number")
    return Planes(N / norm[:, None], d)


def pivots(
    centres: Sequence[float] | Sequence[Sequence[float]] | np.ndarray,
    lengths: float | Sequence[float] | np.ndarray,
) -> Pivots:
    """Checked :class:`Pivots` from centres (K, 3) [mm] and bar lengths (K,) or one [mm].

    Raises:
        InputError: shapes, non-finite numbers, a length <= 0.
    """
    c = np.atleast_2d(np.asarray(centres, dtype=float))
    L = np.asarray(lengths, dtype=float).reshape(-1)
    if L.size == 1 and c.shape[0] > 1:
        L = np.full(c.shape[0], L[0])
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] != L.size or L.size == 0:
        raise InputError(
            f"pivot_mm: {c.shape} pivots and {L.size} bar lengths; expected (K, 3) and (K,)",
            fields=("pivot_mm", "bar_length_mm"),
        )
    if not np.all(np.isfinite(c)):
        raise InputError(f"pivot_mm: expected finite x, y, z [mm], got {c.tolist()}", fields=("pivot_mm",))
    if not np.all(np.isfinite(L) & (L > 0)):
        raise InputError(
            f"bar_length_mm: expected a length > 0 [mm], got {L.tolist()}", fields=("bar_length_mm",)
        )
    return Pivots(c, L)
