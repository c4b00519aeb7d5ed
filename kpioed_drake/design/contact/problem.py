"""The identification problem of a contact system: F1 of poses on its surfaces, one row per pose.

A design pose lies on one of K surfaces of a contact system (:mod:`.surfaces`): a plane touched by
the tool point (``n_k . x = d_k``, unit normals ``n_k`` towards the planes' free side, offsets
``d_k`` [mm]), or the sphere of a ballbar about its pivot (``|x - c_k| = L_k``). Its one row of F1
is the fit's row over sigma, the robot's free columns followed by the system's:

    ``F1_x = [g^T dp_WQ/dp,  environment] / sigma``    (1, k),

``g = dr/dp`` the surface's gradient (the plane's normal; the bar's direction ``u`` from the pivot
to the tool point), the environment columns those of the plane row of
:mod:`kpioed_drake.tracker.plane` (two tilts of the normal [rad] and the offset [mm]) or of the
pivot row of :mod:`kpioed_drake.tracker.distance` (``-u`` on the pivot's position; the bar's length
is known: no correction); only surface k's are nonzero. Which surface a pose is on follows from the
pose: the one its nominal tool point is nearest to (a design pose lies on its surface, within
:data:`~kpioed_drake.design.contact.poses.ON_SURFACE_TOL_MM`). The parameters are those of a fit
with these planes or pivots (:func:`~kpioed_drake.tracker.contacts.contact_model`): the robot's,
each surface's three, and the contact gauge: the points' gauge, the tracker pose (no tracker rows),
for planes the scale (the tool length; a ballbar of known length fixes the scale) and what the
rank test on :data:`GAUGE_POSES` seeded poses on the surfaces holds.

``dF1/dq`` in closed form: the robot columns ``g^T dJ/dq_j`` (:func:`point_jacobian`), plus
``(dg/dq_j)^T J`` for a sphere (``du/dq_j = (I - u u^T) dp/dq_j / |p - c|``); the tilt columns
``(e_i - (n_k . e_i) n_k) . dp/dq_j``, the offset column constant, the pivot columns ``-du/dq_j``.
The KPI, its Jacobian ``Js`` and every criterion are those of
:class:`~kpioed_drake.estimation.problem.Problem` (the TCP in W; the surfaces' and the held columns
dropped). Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.design.contact.poses import contact_poses, tool_motion
from kpioed_drake.design.contact.surfaces import Planes, Surfaces, pivots, planes
from kpioed_drake.errors import InputError
from kpioed_drake.estimation import covariance
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.robot.kinematics import Frames, point_jacobian
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.contacts import ContactGauge, contact_model

GAUGE_POSES = 300
"""Seeded poses on the surfaces (an equal share each) whose rank test fixes the design's gauge."""
BALLBAR_SIGMA_MM = 0.01
"""A ballbar row's noise [mm]: the bar's sensor resolves about 1 um, but a row sees the robot's
repeatability at the tool ball; the touch probe's figure, so that the two designs compare."""


@dataclasses.dataclass(frozen=True)
class ContactProblem(Problem):
    """:class:`Problem` of a contact system (``measure`` ``plane`` or ``ballbar``), one row per pose.

    Attributes (besides :class:`Problem`'s):
        surfaces: the planes or pivots (:mod:`.surfaces`).
        gauge: the parameters the design holds and why (:class:`ContactGauge`).
    """

    surfaces: Surfaces = Planes(np.zeros((0, 3)), np.zeros(0))
    gauge: ContactGauge = ContactGauge()

    @property
    def rows_per_pose(self) -> int:
        """One row per pose: the tool point's residual on its surface."""
        return 1

    def surface_of(self, q: np.ndarray, *, frames: Frames | None = None) -> np.ndarray:
        """(n,) the 0-based surface each pose ``q`` (n, nj) [rad] is on: the nearest to its tool point."""
        q = np.atleast_2d(q)
        frames = self.model.frames(q) if frames is None else frames
        p, _ = point_jacobian(frames, self.model.p_FQ)
        return self.surfaces.nearest(p)

    def used_columns(self, q: np.ndarray) -> np.ndarray:
        """(k,) bool: the parameters a design ``q`` (n, nj) [rad] estimates: all but the surfaces it
        does not use (a plane untouched is not part of its fit; its columns are zero and its
        parameters do not move the TCP)."""
        touched = np.isin(np.arange(len(self.surfaces)), self.surface_of(q))
        cols = self.surfaces.columns(self.model.layout, np.flatnonzero(~touched)).ravel()
        return ~np.isin(self.free, cols)

    def covariances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Problem.covariances` of the parameters the design estimates (:meth:`used_columns`);
        the rows and columns of an unused surface's parameters in ``Cp`` are 0 (not estimated)."""
        use = self.used_columns(q)
        try:
            Cp_used, Cs = covariance.kpi_covariance(self.F1(q)[:, use], self.Js()[:, use])
        except np.linalg.LinAlgError:
            kind, noun = self.surfaces.kind, self.surfaces.words.noun
            raise InputError(
                f"the {len(np.atleast_2d(q))} {noun} do not determine the {int(use.sum())} parameters of "
                f"the {kind}s they use (information matrix singular): 3 {noun} per {kind} at least, "
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
        model, lay, S = self.model, self.model.layout, self.surfaces
        frames = model.frames(q) if frames is None else frames
        out = point_jacobian(frames, model.p_FQ, with_dq=with_dq)
        p, JW = out[0], out[1]
        k = S.nearest(p)
        g = S.gradient(p, k)  # (n, 3)
        nj, n = lay.joints.stop, q.shape[0]
        robot_cols = np.r_[np.arange(lay.size)[lay.joints], np.arange(lay.size)[lay.target(0)]]
        JR = JW[:, :, : nj + 3]  # the joint rows' and target 0's columns, in that order
        H = np.zeros((n, lay.size))
        H[:, robot_cols] = np.einsum("ni,nic->nc", g, JR)
        cols, rows = S.columns(lay, k), np.arange(n)
        dp = tool_motion(frames, p) if with_dq else None
        vals, dvals = S.environment(p, k, dp)
        H[rows[:, None], cols] = vals
        F = H[:, self.free] / self.sigma
        if not with_dq:
            return F
        dH = np.zeros((n, lay.n_joints, lay.size))
        dH[..., robot_cols] = np.einsum("ni,njic->njc", g, out[2][..., : nj + 3])
        if S.curved:
            dH[..., robot_cols] += np.einsum("nji,nic->njc", S.gradient_dq(p, k, dp), JR)
        dH[rows[:, None, None], np.arange(lay.n_joints)[None, :, None], cols[:, None, :]] = dvals
        return F, dH[:, :, None, self.free] / self.sigma


def contact_problem(base: Problem, S: Surfaces, *, collision: bool, seed: int) -> ContactProblem:
    """The :class:`ContactProblem` of ``base`` (a point problem) on surfaces ``S``: the fit's
    parameters and gauge (:func:`contact_model` on :data:`GAUGE_POSES` seeded poses on them), the
    surfaces' parameters at their given values (planes: tilts 0 about their own normals).

    Raises:
        InputError: too few feasible poses on a surface, one its poses do not determine.
    """
    q, k = contact_poses(base, S, n=GAUGE_POSES, seed=seed, collision=collision)
    if S.kind == "plane":
        rows = {"planes": PlaneData.from_arrays(q, k, sigma_mm=base.sigma)}
    else:
        rows = {"distances": DistanceData.from_arrays(q, S.lengths[k], pivot=k, sigma_mm=base.sigma)}
    model, gauge = contact_model(base.model, **rows)
    p = model.p.copy()
    cols = S.columns(model.layout, np.arange(len(S)))
    if S.kind == "plane":
        p[cols[:, :2]], p[cols[:, 2]] = 0.0, S.offsets
        model = dataclasses.replace(model, p=p, n_W_ref=S.normals)
    else:
        p[cols] = S.centres
        model = dataclasses.replace(model, p=p)
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Problem)}
    fields.update(model=model, measure="plane" if S.kind == "plane" else "ballbar")
    return ContactProblem(**fields, surfaces=S, gauge=gauge)


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
) -> ContactProblem:
    """The :class:`ContactProblem` of a robot touching the planes ``normals`` (K, 3) (normalised
    here; towards the free side, where the flange is) and ``offsets`` (K,) [mm] in W.

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
    return contact_problem(base, planes(normals, offsets), collision=collision, seed=seed)


def make_ballbar_problem(
    robot: str | Robot,
    pivot_mm: Sequence[float] | np.ndarray | None = None,
    bar_length_mm: float | Sequence[float] = 150.0,
    *,
    cell_path: Path | str | None = None,
    q_work: np.ndarray | None = None,
    sigma_mm: float = BALLBAR_SIGMA_MM,
    tool_offset_mm: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    collision: bool = True,
    seed: int = 20170710,
) -> ContactProblem:
    """The :class:`ContactProblem` of a pivot ballbar: the tool ball (the tool point) at the bar's
    length ``bar_length_mm`` [mm] from a fixed pivot ``pivot_mm`` (3,) in W [mm] (several: (K, 3)
    and K lengths or one), the pivot's position estimated, the length known.

    Args:
        pivot_mm: default the TCP of the (first) working pose (the bar then measures around the
            point whose precision the KPI is about).
        bar_length_mm: the bar's nominal length (default 150 mm, a common ballbar; the design puts
            the nominal tool point at it, and the bar's small measuring range, about +-1 mm, must
            hold the robot's errors there).
        sigma_mm: the row's noise [mm] (:data:`BALLBAR_SIGMA_MM`).
        collision: the gauge's poses avoid collisions (as the design's).
        seed: seed of the gauge's :data:`GAUGE_POSES` poses on the spheres.

    Raises:
        InputError: a bad pivot or length, too few feasible poses on a sphere, a pivot its poses do
            not determine, and :func:`make_problem`'s errors.
    """
    base = make_problem(
        robot, cell_path=cell_path, q_work=q_work, sigma_mm=sigma_mm, tool_offset_mm=tool_offset_mm
    )
    if pivot_mm is None:
        frames = base.model.frames(base.q_works[:1])
        pivot_mm = point_jacobian(frames, base.model.p_FQ + base.tool_offset)[0][0]
    return contact_problem(base, pivots(pivot_mm, bar_length_mm), collision=collision, seed=seed)
