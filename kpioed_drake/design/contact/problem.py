"""The identification problem of plane contacts: F1 of touches, one row per pose.

A design pose touches one of K given planes ``n_k . x = d_k`` in W (unit normals ``n_k`` pointing to
the planes' free side, offsets ``d_k`` [mm]): its tool point (target 0) lies on the plane. Its one
row of F1 is the plane row of :mod:`kpioed_drake.tracker.plane` over sigma,

    ``F1_x = [n_k^T dp_WQ/dp,  dr/dt_1, dr/dt_2,  -1] / sigma``    (1, k),

the robot's free columns followed by the planes' (two tilts of the normal [rad] and the offset
[mm] of each plane; only plane k's are nonzero). Which plane a pose touches follows from the pose:
the plane its nominal tool point is nearest to (a design pose lies on its plane, within
:data:`~kpioed_drake.design.contact.poses.ON_PLANE_TOL_MM`; a pose on two planes at once, on their
intersection line, takes the first). The parameters are those of a fit with these planes
(:func:`~kpioed_drake.tracker.contacts.contact_model`): the robot's, each plane's three, and the
contact gauge: the points' gauge, the tracker pose (no tracker rows), the scale (the tool length)
and what the rank test on :data:`GAUGE_POSES` seeded poses on the planes holds.

``dF1/dq`` in closed form: the robot columns ``n_k^T dJ/dq_j`` (:func:`point_jacobian`); the tilt
columns ``(e_i - (n_k . e_i) n_k) . dp/dq_j / |v|``; the offset column is constant. The KPI, its
Jacobian ``Js`` and every criterion are those of :class:`~kpioed_drake.estimation.problem.Problem`
(the TCP in W, the planes' and the held columns dropped). Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.design.contact.poses import plane_poses
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import covariance
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.robot.kinematics import Frames, point_jacobian
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.contactdata import PlaneData
from kpioed_drake.tracker.contacts import ContactGauge, contact_model
from kpioed_drake.tracker.plane import tangent_basis

GAUGE_POSES = 300
"""Seeded poses on the planes (an equal share each) whose rank test fixes the design's gauge."""


@dataclasses.dataclass(frozen=True)
class PlaneProblem(Problem):
    """:class:`Problem` of plane touches (``measure == "plane"``), one row per pose.

    Attributes (besides :class:`Problem`'s):
        normals: (K, 3) unit normals of the planes in W, towards their free side.
        offsets: (K,) the planes' offsets [mm] (``n_k . x = d_k``).
        gauge: the parameters the design holds and why (:class:`ContactGauge`).
    """

    normals: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    offsets: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    gauge: ContactGauge = ContactGauge()

    @property
    def rows_per_pose(self) -> int:
        """One row per pose: the tool point's signed distance to its plane."""
        return 1

    def plane_of(self, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
        """(n,) the 0-based plane each pose ``q`` (n, nj) [rad] touches: the nearest to its tool point."""
        q = np.atleast_2d(q)
        frames = self.model.frames(q) if frames is None else frames
        p, _ = point_jacobian(frames, self.model.p_FQ)
        return np.argmin(np.abs(p @ self.normals.T - self.offsets), axis=1)

    def used_columns(self, q: np.ndarray) -> np.ndarray:
        """(k,) bool: the parameters a design ``q`` (n, nj) [rad] estimates: all but the planes it does
        not touch (a plane untouched is not part of its fit; its columns are zero and its parameters
        do not move the TCP)."""
        touched = np.isin(np.arange(len(self.offsets)), self.plane_of(q))
        cols = self.model.layout.plane_columns(np.flatnonzero(~touched)).ravel()
        return ~np.isin(self.free, cols)

    def covariances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Problem.covariances` of the parameters the design estimates (:meth:`used_columns`);
        the rows and columns of an untouched plane's parameters in ``Cp`` are 0 (not estimated)."""
        use = self.used_columns(q)
        try:
            Cp_used, Cs = covariance.kpi_covariance(self.F1(q)[:, use], self.Js()[:, use])
        except np.linalg.LinAlgError:
            raise InputError(
                f"the {len(np.atleast_2d(q))} touches do not determine the {int(use.sum())} parameters of "
                "the planes they touch (information matrix singular): 3 touches per plane at least, "
                "varied poses"
            ) from None
        Cp = np.zeros((self.n_params, self.n_params))
        Cp[np.ix_(use, use)] = Cp_used
        return Cp, Cs

    def F1(
        self, q: np.ndarray, *, with_dq: bool = False, frames: Frames | None = None
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Weighted rows (n, k); with ``with_dq`` also dF1/dq (n, nj, 1, k) [per rad]."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        model, lay = self.model, self.model.layout
        frames = model.frames(q) if frames is None else frames
        out = point_jacobian(frames, model.p_FQ, with_dq=with_dq)
        p, JW = out[0], out[1]
        k = np.argmin(np.abs(p @ self.normals.T - self.offsets), axis=1)
        nk, E = self.normals[k], tangent_basis(self.normals)[k]  # (n, 3), (n, 2, 3)
        nj, n = lay.joints.stop, q.shape[0]
        H = np.zeros((n, lay.size))
        H[:, lay.joints] = np.einsum("ni,nic->nc", nk, JW[:, :, :nj])
        H[:, lay.target(0)] = np.einsum("ni,nic->nc", nk, JW[:, :, nj : nj + 3])
        cols = lay.plane_columns(k)
        rows = np.arange(n)
        n_e = np.einsum("nij,nj->ni", E, nk)  # (n, 2), 0 at the reference normal (tilts 0)
        tilt = E - n_e[:, :, None] * nk[:, None, :]  # (n, 2, 3): d(dr/dt_i)/dp
        H[rows[:, None], cols[:, :2]] = np.einsum("nij,nj->ni", tilt, p)
        H[rows, cols[:, 2]] = -1.0
        F = H[:, self.free] / self.sigma
        if not with_dq:
            return F
        dJW = out[2]  # (n, nj, 3, g + 3)
        dH = np.zeros((n, lay.n_joints, lay.size))
        dH[..., lay.joints] = np.einsum("ni,njic->njc", nk, dJW[..., :nj])
        dH[..., lay.target(0)] = np.einsum("ni,njic->njc", nk, dJW[..., nj : nj + 3])
        dp = frames.joint_motion(p)  # (n, nj, 3)
        on = frames.point_path(None)
        if on is not None:
            dp = dp * on[:, :, None]
        dt = np.einsum("nij,nqj->nqi", tilt, dp)  # (n, nj, 2)
        for i in range(2):
            dH[rows[:, None], np.arange(lay.n_joints)[None, :], cols[:, i : i + 1]] = dt[:, :, i]
        return F, dH[:, :, None, self.free] / self.sigma


def make_plane_problem(
    robot: str | Robot,
    normals: Sequence[Sequence[float]] | np.ndarray,
    offsets: Sequence[float] | np.ndarray,
    *,
    cell_path: Path | str | None = None,
    q_work: np.ndarray | None = None,
    sigma_mm: float = 0.01,
    tool_offset_mm: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    collision: bool = True,
    seed: int = 20170710,
) -> PlaneProblem:
    """The :class:`PlaneProblem` of a robot touching the planes ``normals`` (K, 3) (normalised here;
    towards the free side, where the flange is) and ``offsets`` (K,) [mm] in W.

    Args:
        sigma_mm: the touch's noise along the normal [mm] (a touch probe: 0.01).
        collision: the gauge's poses on the planes avoid collisions (as the design's).
        seed: seed of the gauge's :data:`GAUGE_POSES` poses on the planes.

    Raises:
        InputError: bad planes (shapes, a zero normal), too few feasible poses on a plane, a plane
            its poses do not determine (:func:`contact_model`), and :func:`make_problem`'s errors.
    """
    base = make_problem(
        robot, cell_path=cell_path, q_work=q_work, sigma_mm=sigma_mm, tool_offset_mm=tool_offset_mm
    )
    N = np.atleast_2d(np.asarray(normals, dtype=float))
    d = np.asarray(offsets, dtype=float).reshape(-1)
    if N.ndim != 2 or N.shape[1] != 3 or N.shape[0] != d.size or d.size == 0:
        raise InputError(f"planes: {N.shape} normals and {d.size} offsets; expected (K, 3) and (K,)")
    norm = np.linalg.norm(N, axis=1)
    if not np.all(norm > 0):
        raise InputError("planes: a normal is zero")
    N = N / norm[:, None]
    q, plane = plane_poses(base, N, d, n=GAUGE_POSES, seed=seed, collision=collision)
    model, gauge = contact_model(base.model, planes=PlaneData.from_arrays(q, plane, sigma_mm=base.sigma))
    p = model.p.copy()  # the given planes, tilts 0 about their own normals
    cols = model.layout.plane_columns(np.arange(d.size))
    p[cols[:, :2]], p[cols[:, 2]] = 0.0, d
    model = dataclasses.replace(model, p=p, n_W_ref=N)
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Problem)}
    fields.update(model=model, measure="plane")
    return PlaneProblem(**fields, normals=N, offsets=d, gauge=gauge)
