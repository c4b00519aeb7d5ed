"""Capsule clearances with exact joint-angle gradients (paper section 2.2, eqs. 20-23).

Every collision constraint of the design problem (paper Table 5) is a clearance that must be
``>= 0`` [mm]:

- floor and wall: for each moving robot capsule and each end point,
  ``z - r - floor_z`` and ``x - r - wall_x`` (the extreme of a capsule against a plane is at an
  end point, so this is exact);
- robot capsule vs fixed obstacle capsule (mount, car), robot self pairs of non-neighbour links,
  and the laser beam (a thin capsule from the reflector to the tracker; several targets: one beam
  per target, :func:`beam_targets`) vs robot links and the car: segment-segment distance minus
  the radii (eq. 20, 21).

Segment-segment distances use the clamped closed form (Lumelsky; Ericson 5.1.9), vectorised
over poses and pairs. The gradient with respect to the joint angles follows from the envelope
theorem: with closest points ``c_A(s*)``, ``c_B(t*)`` and unit normal ``n = (c_A - c_B)/|.|``,
``d dist/dq = n . (dc_A/dq - dc_B/dq)`` at fixed ``s*, t*``.

These functions serve the optimiser. The independent feasibility check
(:mod:`kpioed_drake.tracker.feasibility`) uses Drake's own signed-distance queries instead.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.robot.kinematics import Frames, cross, forward_kinematics
from kpioed_drake.robot.models import Cell, Robot

_EPS = 1e-12


def segment_distance(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points between segments p1-q1 and p2-q2 (broadcast over leading axes).

    Returns:
        dist: (...) distance [mm]; s, t: (...) parameters of the closest points on each segment.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    denom = a * e - b * b
    a_s, e_s = np.maximum(a, _EPS), np.maximum(e, _EPS)
    s = np.where(denom > 1e-9 * a_s * e_s, np.clip((b * f - c * e) / np.maximum(denom, _EPS), 0, 1), 0.0)
    t = (b * s + f) / e_s
    s = np.where(t < 0, np.clip(-c / a_s, 0, 1), np.where(t > 1, np.clip((b - c) / a_s, 0, 1), s))
    t = np.clip(t, 0, 1)
    # Degenerate segments (points).
    s = np.where(a <= _EPS, 0.0, s)
    t = np.where(e <= _EPS, 0.0, np.where(a <= _EPS, np.clip(f / e_s, 0, 1), t))
    cA = p1 + s[..., None] * d1
    cB = p2 + t[..., None] * d2
    return np.linalg.norm(cA - cB, axis=-1), s, t


def beam_targets(robot: Robot, cell: Cell) -> list[tuple[str, np.ndarray, int]]:
    """The laser beams of a pose, one per target: ``(label, p_FQ, link)`` with ``p_FQ`` (3,) [mm]
    in the frame of link ``link`` (the flange; a tree robot's targets sit on several links).

    A pose measures every target, so each target's beam (reflector to tracker) must be clear.
    Target 1 is the cell's reflector ``cell.p_FQ``, targets 2..T the robot file's ``targets_mm``
    (as in :func:`kpioed_drake.tracker.measurement.nominal_model`). Labels: ``beam`` for one target,
    ``beam1`` .. ``beamT`` for several (as the incidence rows ``incidence1`` ..).
    """
    offsets = [np.asarray(cell.p_FQ, float)]
    offsets += [np.asarray(robot.targets[t], float) for t in range(1, robot.n_targets)]
    links = robot.target_frames.tolist()
    if len(offsets) == 1:
        return [("beam", offsets[0], links[0])]
    return [(f"beam{t + 1}", p, f) for t, (p, f) in enumerate(zip(offsets, links, strict=True))]


@dataclasses.dataclass(frozen=True)
class ClearanceRows:
    """The clearance rows of one pose, in evaluation order."""

    names: tuple[str, ...]
    """Row names, e.g. ``upper_arm.a vs floor``, ``forearm vs car_body``, ``beam vs wrist``
    (several targets: ``beam1 vs wrist``, ``beam2 vs wrist``, ...)."""
    kinds: tuple[str, ...]
    """Per row: ``floor``, ``wall``, ``obstacle``, ``self`` or ``beam``."""


@dataclasses.dataclass
class ClearanceEval:
    """Clearances of n poses and the data of their gradients (see ``ClearanceModel._rows``).

    Attributes:
        frames: forward kinematics of the poses.
        values: (n, m) clearances [mm].
        E: (n, m, 4, 3) gradient points [mm]; W: (n, m, 4) their weights; N: (n, m, 3) unit normals.
    """

    frames: Frames
    values: np.ndarray
    E: np.ndarray
    W: np.ndarray
    N: np.ndarray


class ClearanceModel:
    """All clearance constraints of a robot in a cell, evaluated for many poses at once.

    Args:
        robot: robot (nominal geometry unless ``geometry`` is given at evaluation).
        cell: measuring cell.
        collision: include robot-vs-world and self rows.
        beam: include laser-beam rows.
    """

    def __init__(self, robot: Robot, cell: Cell, *, collision: bool = True, beam: bool = True):
        self.robot, self.cell = robot, cell
        caps = list(robot.capsules)
        moving = [k for k, c in enumerate(caps) if c.frame >= 1]
        # Point rows (floor/wall): (capsule index, end 0/1, axis, offset)
        pts, names, kinds = [], [], []
        if collision:
            for axis, off, tag in ((2, cell.floor_z, "floor"), (0, cell.wall_x, "wall")):
                for k in moving:
                    for end in (0, 1):
                        pts.append((k, end, axis, off))
                        names.append(f"{caps[k].name}.{'ab'[end]} vs {tag}")
                        kinds.append(tag)
        self._pts = pts
        # Segment pairs: each side is (frame1, local1, frame2, local2), radius sum.
        segs = []
        if collision:
            for k in moving:
                for ob in cell.obstacles:
                    segs.append(self._cap(caps[k]) + self._world(ob.a, ob.b) + (caps[k].radius + ob.radius,))
                    names.append(f"{caps[k].name} vs {ob.name}")
                    kinds.append("obstacle")
            for i, j in robot.self_pairs:
                for ci in (c for c in caps if c.frame == i):
                    for cj in (c for c in caps if c.frame == j):
                        segs.append(self._cap(ci) + self._cap(cj) + (ci.radius + cj.radius,))
                        names.append(f"{ci.name} vs {cj.name}")
                        kinds.append("self")
        for label, p_FQ, link in beam_targets(robot, cell) if beam else ():
            beam_side = (link, p_FQ, 0, np.asarray(cell.p_WT, float))
            for c in caps:
                if c.frame in robot.beam_links:
                    segs.append(beam_side + self._cap(c) + (c.radius + cell.beam_radius,))
                    names.append(f"{label} vs {c.name}")
                    kinds.append("beam")
            for ob in cell.obstacles:
                if ob.moves_with_car:
                    segs.append(beam_side + self._world(ob.a, ob.b) + (ob.radius + cell.beam_radius,))
                    names.append(f"{label} vs {ob.name}")
                    kinds.append("beam")
        self._segs = segs
        self.rows = ClearanceRows(tuple(names), tuple(kinds))
        # Pre-stack arrays for vectorised evaluation.
        if segs:
            self._sf = np.array([[s[0], s[2], s[4], s[6]] for s in segs], dtype=int)  # (m,4)
            self._sl = np.array([[s[1], s[3], s[5], s[7]] for s in segs], dtype=float)  # (m,4,3)
            self._sr = np.array([s[8] for s in segs], dtype=float)
        if pts:
            self._pk = np.array([p[0] for p in pts], dtype=int)
            self._pe = np.array([p[1] for p in pts], dtype=int)
            self._pa = np.array([p[2] for p in pts], dtype=int)
            self._po = np.array([p[3] for p in pts], dtype=float)
            self._pf = np.array([caps[k].frame for k in self._pk], dtype=int)
            self._pl = np.array([[caps[k].a, caps[k].b][e] for k, e in zip(self._pk, self._pe, strict=True)])
            self._prad = np.array([caps[k].radius for k in self._pk])
        # Frame of each of the (up to) four gradient points of every row (see _rows), rows in order.
        F = np.zeros((len(names), 4), dtype=int)
        if pts:
            F[: len(pts), 0] = self._pf
        if segs:
            F[len(pts) :] = self._sf
        self._frames = F

    @staticmethod
    def _cap(c):
        return (c.frame, c.a, c.frame, c.b)

    @staticmethod
    def _world(a, b):
        return (0, np.asarray(a, float), 0, np.asarray(b, float))

    @property
    def n_rows(self) -> int:
        return len(self.rows.names)

    def values(
        self, q: np.ndarray, *, geometry: np.ndarray | None = None, frames: Frames | None = None
    ) -> np.ndarray:
        """Clearances only: (n, m) [mm] (>= 0 is free). Arguments as :meth:`evaluate`."""
        return self.compute(q, geometry=geometry, frames=frames).values

    def evaluate(
        self,
        q: np.ndarray,
        *,
        geometry: np.ndarray | None = None,
        frames: Frames | None = None,
        rows: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Clearances and their joint-angle Jacobian.

        Args:
            q: (n, nj) joint angles [rad] (ignored when ``frames`` is given).
            geometry: (nj, P) kinematic parameters (default: the robot's nominal ones).
            frames: forward kinematics of ``q``, if already computed.
            rows: (n, k) row indices: the Jacobian is computed for these rows of each pose only
                (default: every row).

        Returns:
            values: (n, m) clearances [mm] (>= 0 is free), every row;
            jac: (n, m, nj), or (n, k, nj) for ``rows``: derivative of the (selected) rows w.r.t.
            the pose's own joint angles [mm/rad].
        """
        ev = self.compute(q, geometry=geometry, frames=frames)
        return ev.values, self.jacobian(ev, rows)

    def compute(
        self, q: np.ndarray, *, geometry: np.ndarray | None = None, frames: Frames | None = None
    ) -> ClearanceEval:
        """Every row's clearance and what its gradient needs (:meth:`jacobian`); see :meth:`evaluate`."""
        return ClearanceEval(*self._rows(q, geometry, frames))

    def jacobian(self, ev: ClearanceEval, rows: np.ndarray | None = None) -> np.ndarray:
        """Jacobian (n, m, nj) of every row, or (n, k, nj) of the rows ``rows`` (n, k) [mm/rad]."""
        n = ev.values.shape[0]
        if ev.values.shape[1] == 0:
            return np.zeros((n, 0, self.robot.n_joints))
        E, W, N, F = ev.E, ev.W, ev.N, self._frames
        if rows is not None:
            rows = np.asarray(rows, dtype=int)
            E = np.take_along_axis(E, rows[:, :, None, None], axis=1)
            W = np.take_along_axis(W, rows[:, :, None], axis=1)
            N = np.take_along_axis(N, rows[:, :, None], axis=1)
            F = F[rows]  # (n, k, 4)
        return self._jacobian(ev.frames, E, W, N, F)

    def _rows(self, q, geometry, frames):
        """Values of all rows and, per row, the points, weights and normal of its gradient.

        Every row's gradient has the form ``d v/d q_j = sum_k W_k N . dE_k/dq_j`` with four points
        ``E_k`` (each fixed to frame ``F_k``; unused points have weight 0): for a segment pair the
        end points with weights ``(1-s, s, -(1-t), -t)`` and the unit normal between the closest
        points (envelope theorem); for a floor/wall row the capsule end point, weight 1 and the
        plane's normal axis.
        """
        if frames is None:
            frames = forward_kinematics(self.robot, q, geometry)
        n = frames.R.shape[0]
        m = self.n_rows
        vals = np.empty((n, m))
        E = np.zeros((n, m, 4, 3))
        W = np.zeros((n, m, 4))
        N = np.zeros((n, m, 3))
        k = len(self._pts)
        if k:
            P = frames.o[:, self._pf] + np.einsum("nmij,mj->nmi", frames.R[:, self._pf], self._pl)
            vals[:, :k] = P[:, np.arange(k), self._pa] - self._prad - self._po
            E[:, :k, 0] = P
            W[:, :k, 0] = 1.0
            N[:, np.arange(k), self._pa] = 1.0
        if self._segs:
            f, loc = self._sf, self._sl
            Es = frames.o[:, f] + np.einsum("nmkij,mkj->nmki", frames.R[:, f], loc)  # (n,m,4,3)
            dist, s, t = segment_distance(Es[:, :, 0], Es[:, :, 1], Es[:, :, 2], Es[:, :, 3])
            cA = Es[:, :, 0] + s[..., None] * (Es[:, :, 1] - Es[:, :, 0])
            cB = Es[:, :, 2] + t[..., None] * (Es[:, :, 3] - Es[:, :, 2])
            vals[:, k:] = dist - self._sr
            E[:, k:] = Es
            W[:, k:, 0], W[:, k:, 1], W[:, k:, 2], W[:, k:, 3] = 1 - s, s, t - 1, -t
            N[:, k:] = (cA - cB) / np.maximum(dist, _EPS)[..., None]
        return frames, vals, E, W, N

    @staticmethod
    def _jacobian(frames: Frames, E, W, N, F) -> np.ndarray:
        """``sum_k W_k [j moves F_k] N . (w_j x (E_k - o_j))`` = ``sum_k W_k [..] (E_k - o_j) . (N x w_j)``;
        a prismatic joint j moves every point by ``w_j``: ``sum_k W_k [j moves F_k] N . w_j``
        (``[j moves F_k]``: ``j < F_k`` for a serial robot, :attr:`Frames.path` for a tree).

        Shapes: E (n, k, 4, 3), W (n, k, 4), N (n, k, 3), F (k, 4) or (n, k, 4); returns (n, k, nj).
        """
        w, o = frames.joint_axes, frames.joint_points  # (n, nj, 3)
        T = cross(N[:, :, None, :], w[:, None, :, :])  # (n, k, nj, 3)
        moves = frames.path[np.asarray(F)]  # (.., k, 4, nj): joint j moves frame F_k
        WM = W[..., None] * moves  # (n, k, 4, nj)
        ET = np.einsum("nkpi,nkji->nkpj", E, T)  # (n, k, 4, nj)
        oT = np.einsum("nji,nkji->nkj", o, T)  # (n, k, nj)
        rev = np.einsum("nkpj,nkpj->nkj", WM, ET) - WM.sum(axis=2) * oT
        if not frames.prismatic.any():
            return rev
        Nw = np.einsum("nki,nji->nkj", N, w)  # (n, k, nj)
        return np.where(frames.prismatic, WM.sum(axis=2) * Nw, rev)
