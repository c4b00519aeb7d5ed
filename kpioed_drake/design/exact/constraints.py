"""The constraints of the design problem (paper eq. 24b), pose by pose, with their Jacobians.

For every pose, one incidence row ``cos(beta) - cos(beta_max) >= 0`` (paper eq. 4; with several
targets one row per target, the beam to each must meet it) and, with
collision avoidance, the capsule clearances of :class:`~kpioed_drake.robot.geometry.ClearanceModel`
``>= 0`` [mm] (paper eq. 20-22; 51 rows for the KUKA robots). Each row depends only on its own
pose's six joint angles. The solver is given, per pose, the incidence row and only the pose's ``m``
smallest clearances (:meth:`DesignConstraints.evaluate_active`): "every clearance >= 0" and "the m
smallest clearances >= 0" are the same condition. Derivatives are closed form: ``d z/d q_j = w_j x
z`` and ``d p/d q_j = w_j x (p - o_{j-1})`` for the incidence row (joint axis ``w_j`` through
``o_{j-1}``, in W); the clearance gradients come from :mod:`kpioed_drake.robot.geometry`.

Units: rows are cosine differences [-] and clearances [mm]; before they reach the solver they are
scaled by :meth:`DesignConstraints.row_scale` and bounded below by small inward margins
(:meth:`DesignConstraints.lower_bounds`).
"""

from __future__ import annotations

import math

import numpy as np

from kpioed_drake.design.settings import (
    CLEARANCE_MARGIN_MM,
    CLEARANCE_ROW_SCALE,
    INCIDENCE_MARGIN_DEG,
    as_poses,
)
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.jointmap import commandable_motions
from kpioed_drake.robot.kinematics import Frames, cross, flange_point, forward_kinematics
from kpioed_drake.tracker.feasibility import TOL_DEG


def incidence_row_beyond(max_incidence: float, deg: float) -> float:
    """The incidence row ``cos(beta) - cos(beta_max)`` at ``beta = beta_max + deg`` (``deg`` [deg]
    beyond the limit; negative: inside it)."""
    return math.cos(max_incidence + math.radians(deg)) - math.cos(max_incidence)


def incidence_rows(
    problem: Problem, q: np.ndarray, *, frames: Frames | None = None, target: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Incidence constraint ``cos(beta) - cos(beta_max)`` (>= 0 is feasible) and its gradient.

    With ``z`` the reflector axis (flange z), ``p`` the reflector, ``p_WT`` the tracker (all in W
    [mm]), ``g = p_WT - p`` and ``g^ = g/|g|``: ``c = z . g^``; ``dz/dq_j = w_j x z``;
    ``dp/dq_j = w_j x (p - o_{j-1})``; ``dc/dq_j = (w_j x z) . g^ - (z - c g^) . dp/dq_j / |g|``
    (a prismatic joint: ``dz/dq_j = 0``, ``dp/dq_j = w_j``).

    Args:
        q: (n, nj) [rad].
        target: the 0-based target whose beam is tested (None: the reflector, target 0).

    Returns:
        values: (n,) [-]; jac: (n, nj) [1/rad].
    """
    q = as_poses(q, problem.robot.n_joints)
    frames = problem.model.frames(q) if frames is None else frames
    model = problem.model
    link = None if target is None else model.target_links(np.full(q.shape[0], target))
    R_F = frames.at_link(link)[0]
    z = R_F[:, :, 2]  # (n,3)
    p_FQ = model.p_FQ if target is None else model.target_offsets[target]
    p = flange_point(frames, p_FQ, link)  # (n,3)
    g = problem.model.p_WT - p
    dist = np.linalg.norm(g, axis=1)
    gh = g / dist[:, None]
    c = np.einsum("ni,ni->n", z, gh)
    dz = np.where(frames.prismatic[:, None], 0.0, cross(frames.joint_axes, z[:, None, :]))
    dp = frames.joint_motion(p)
    on = frames.point_path(link)  # the joints moving the target (None: all)
    if on is not None:
        dz, dp = dz * on[:, :, None], dp * on[:, :, None]
    perp = z - c[:, None] * gh  # (n,3)
    jac = np.einsum("nji,ni->nj", dz, gh) - np.einsum("nji,ni->nj", dp, perp) / dist[:, None]
    return c - math.cos(problem.cell.max_incidence), jac


class DesignConstraints:
    """All constraint rows of every pose: incidence, then (with ``collision``) the clearances.

    Args:
        problem: the identification problem (robot, cell, model).
        collision: include the clearance rows of :class:`~kpioed_drake.robot.geometry.ClearanceModel`.

    Attributes:
        clearance: the clearance model (None without ``collision``).
        row_names: names of a pose's rows: ``incidence`` (several targets: ``incidence1`` ..
            ``incidenceT``), then the clearance rows' names.
        n_incidence: incidence rows per pose (one per target).
    """

    def __init__(self, problem: Problem, *, collision: bool = True):
        self.problem, self.collision = problem, collision
        self.clearance = ClearanceModel(problem.robot, problem.cell) if collision else None
        self.n_incidence = T = problem.n_targets
        inc = ["incidence"] if T == 1 else [f"incidence{t + 1}" for t in range(T)]
        names = inc + (list(self.clearance.rows.names) if self.clearance else [])
        self.row_names = tuple(names)

    def incidence(self, q: np.ndarray, frames: Frames) -> tuple[np.ndarray, np.ndarray]:
        """Incidence rows of every target: values (n, T) [-] and jac (n, T, 6) [1/rad]."""
        if self.n_incidence == 1:
            c, dc = incidence_rows(self.problem, q, frames=frames)
            return c[:, None], dc[:, None, :]
        rows = [incidence_rows(self.problem, q, frames=frames, target=t) for t in range(self.n_incidence)]
        return np.stack([r[0] for r in rows], axis=1), np.stack([r[1] for r in rows], axis=1)

    @property
    def rows_per_pose(self) -> int:
        """Rows of one pose: incidence plus every clearance."""
        return len(self.row_names)

    def frames(self, q: np.ndarray) -> Frames:
        """Forward kinematics of ``q`` (n, 6) as every evaluator of the design problem uses it."""
        robot = self.problem.robot
        return forward_kinematics(robot, as_poses(q, robot.n_joints), self.problem.model.geometry)

    def evaluate(self, q: np.ndarray, *, frames: Frames | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Constraint values and their per-pose Jacobian.

        Args:
            q: (n, 6) [rad].
            frames: :meth:`frames` of ``q``, if already computed.

        Returns:
            values: (n, r) (row 0 cosine difference [-], rows 1.. clearances [mm]; >= 0 feasible);
            jac: (n, r, 6) derivative w.r.t. the pose's own joint angles [per rad].
        """
        q = as_poses(q, self.problem.robot.n_joints)
        frames = self.frames(q) if frames is None else frames
        c, dc = self.incidence(q, frames)
        if self.clearance is None:
            return c, dc
        v, J = self.clearance.evaluate(q, frames=frames)
        return np.concatenate([c, v], axis=1), np.concatenate([dc, J], axis=1)

    def evaluate_active(
        self, q: np.ndarray, active: np.ndarray | None, m: int, *, frames: Frames | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Incidence and the ``m`` smallest clearances of every pose, with their Jacobian.

        "All clearances >= b" holds exactly when "the m smallest clearances >= b" does, so these
        rows define the same feasible set as :meth:`evaluate`'s. The clearance rows kept for a pose
        are held in ``m`` slots: a row keeps its slot while it stays among the pose's ``m``
        smallest, and a row that enters takes the slot of one that left (see
        :func:`update_active_rows`). Only the kept rows' Jacobian is computed.

        Args:
            q: (n, 6) [rad].
            active: (n, m) clearance row indices (0-based, into ``clearance.rows``) held in the slots
                so far, or None (start: the m smallest, in increasing order of clearance).
            m: slots per pose (1 <= m <= number of clearance rows).
            frames: :meth:`frames` of ``q``, if already computed.

        Returns:
            values: (n, T + m); jac: (n, T + m, 6) (T incidence rows, one per target); active:
            (n, m) the rows now in the slots.
        """
        q = as_poses(q, self.problem.robot.n_joints)
        frames = self.frames(q) if frames is None else frames
        c, dc = self.incidence(q, frames)
        ev = self.clearance.compute(q, frames=frames)
        active = update_active_rows(ev.values, active, m)
        J = self.clearance.jacobian(ev, active)
        values = np.concatenate([c, np.take_along_axis(ev.values, active, axis=1)], axis=1)
        return values, np.concatenate([dc, J], axis=1), active

    def row_scale(self, r: int | None = None) -> np.ndarray:
        """(r,) factors applied to the first ``r`` rows (default: all) before they reach the solver."""
        s = np.full(self.rows_per_pose if r is None else r, CLEARANCE_ROW_SCALE)
        s[: self.n_incidence] = 1.0
        return s

    def lower_bounds(self, r: int | None = None) -> np.ndarray:
        """(r,) lower bounds of the first ``r`` unscaled rows (default: all; small inward margins,
        :data:`~kpioed_drake.design.settings.INCIDENCE_MARGIN_DEG` and ``CLEARANCE_MARGIN_MM``)."""
        lb = np.full(self.rows_per_pose if r is None else r, CLEARANCE_MARGIN_MM)
        lb[: self.n_incidence] = incidence_row_beyond(self.problem.cell.max_incidence, -INCIDENCE_MARGIN_DEG)
        return lb


def update_active_rows(values: np.ndarray, active: np.ndarray | None, m: int) -> np.ndarray:
    """The ``m`` smallest rows of every pose, each kept in its slot while it stays among them.

    Args:
        values: (n, R) clearances of every row.
        active: (n, m) the row indices in the slots so far, or None. A pose whose slots are all -1
            has none yet (as with None).
        m: number of slots.

    Returns:
        (n, m) row indices: the set is the m smallest of each pose; a row that was in ``active`` and
        still belongs to the set keeps its position, the rows that enter fill the freed positions
        in increasing row index. A pose without slots gets its m smallest in increasing order.
    """
    n, R = values.shape
    if not 1 <= m <= R:
        raise ValueError(f"the number of active rows must be in 1..{R}, got {m}")
    if active is None:
        return np.argsort(values, axis=1, kind="stable")[:, :m]
    unset = active[:, 0] < 0
    if unset.any():
        out = np.empty((n, m), dtype=np.intp)
        out[unset] = update_active_rows(values[unset], None, m)
        if not unset.all():
            out[~unset] = update_active_rows(values[~unset], active[~unset], m)
        return out
    best = (
        np.sort(np.argpartition(values, m - 1, axis=1)[:, :m], axis=1)
        if m < R
        else np.tile(np.arange(R), (n, 1))
    )
    stays = (active[:, :, None] == best[:, None, :]).any(axis=2)  # (n, m) slot keeps its row
    enters = ~(best[:, :, None] == active[:, None, :]).any(axis=2)  # (n, m) best row not yet in a slot
    out = active.copy()
    # Both masks have the same count per pose; nonzero() lists them pose by pose, in order.
    out[np.nonzero(~stays)] = best[np.nonzero(enters)]
    return out


RESTORE_MAX_DEG = 0.01
"""Largest incidence overshoot [deg] :func:`restore_incidence` pulls back: a solver's tolerance, not
a design choice (SNOPT's feasibility tolerance is relative to the solution vector's size, so a
robot with a joint in mm, e.g. lift7's column, can end 2e-4 deg beyond the limit at "optimality
conditions satisfied"; docs/design.md)."""


def restore_incidence(problem: Problem, q: np.ndarray) -> np.ndarray:
    """``q`` (n, nj) with every pose whose incidence is beyond the limit by more than the independent
    check's tolerance (:data:`~kpioed_drake.tracker.feasibility.TOL_DEG`) but at most
    :data:`RESTORE_MAX_DEG` moved back to the optimiser's bound (the limit minus
    :data:`~kpioed_drake.design.settings.INCIDENCE_MARGIN_DEG`) by Gauss-Newton steps along the
    incidence row's gradient (projected on the motions the joint map's couplings allow), inside the
    joint box. Every other pose is returned unchanged, so a design that passes the check is not
    touched; one that is further out stays as it is."""
    q = np.array(as_poses(q, problem.robot.n_joints), dtype=float)
    mi = problem.cell.max_incidence
    lb = incidence_row_beyond(mi, -INCIDENCE_MARGIN_DEG)  # the optimiser's bound (lower_bounds)
    fails, worst = incidence_row_beyond(mi, TOL_DEG), incidence_row_beyond(mi, RESTORE_MAX_DEG)
    targets = [None] if problem.n_targets == 1 else list(range(problem.n_targets))
    P = commandable_motions(problem.robot)
    for t in targets:
        c, jac = incidence_rows(problem, q, target=t)
        fix = (c < fails) & (c >= worst)
        for _ in range(5):
            if not np.any(fix):
                break
            g = jac[fix] @ P  # along motions the controller can command (the couplings kept)
            step = (lb - c[fix]) / np.maximum(np.sum(g**2, axis=1), 1e-300)
            q[fix] = np.clip(q[fix] + step[:, None] * g, problem.robot.lower, problem.robot.upper)
            c, jac = incidence_rows(problem, q, target=t)
            fix &= c < lb
    return q
