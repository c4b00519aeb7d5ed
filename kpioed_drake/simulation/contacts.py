"""Simulated distance and plane-contact measurements of a true robot (seeded).

The true robot is :func:`kpioed_drake.simulation.truth.true_model`'s (SPEC-sized random errors on
the free parameters of the points' gauge: 0.5 mm on lengths, 0.05 deg on angles), drawn from
``numpy.random.default_rng(seed)``, or a given one (the truth of a tracker simulation, for mixed
data). Parameters a contact fit's gauge holds beyond the points' gauge (``hold``: e.g. the length
planes hold as the scale) are set back to nominal in a drawn truth, as the points' gauge is: a
fit can only recover the truth in its gauge.

- :func:`simulate_distances`: lengths between the true tool points of pose pairs, or to true
  pivots, minus the true bar corrections (one N(0, 0.5 mm) per bar), plus N(0, sigma^2) noise;
- :func:`simulate_planes`: each commanded pose is moved in joint space (minimum-norm Newton steps)
  until the true tool point touches its plane, up to N(0, sigma^2) along the normal: the touch
  probe's trigger; the data hold the touched joint values and a measured distance 0;
- :func:`truth_parameters`: a truth in a fitted model's parameter vector (its tilts of the true
  normals, its small rotations of the true tracker orientation), to compare an estimate with.

Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.simulation.truth import LENGTH_ERROR_MM, true_model
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model, reflector_world
from kpioed_drake.tracker.plane import tangent_basis

TOUCH_TOL_MM = 1e-9
"""The touch search stops when every row's tool point is this close to its (noisy) plane [mm]."""
TOUCH_ITERATIONS = 50


def _truth(
    robot: Robot, rng: np.random.Generator, cell: Cell | None, truth, hold: Sequence[str]
) -> TrackerModel:
    """The given truth, or one drawn with ``rng`` whose ``hold`` parameters are nominal."""
    if truth is not None:
        return truth
    nominal = nominal_model(robot, load_cell(robot=robot) if cell is None else cell)
    model = true_model(nominal, rng)
    p = model.p.copy()
    idx = [nominal.layout.names.index(n) for n in hold if n in nominal.layout.names]
    p[idx] = nominal.p[idx]
    return model.with_params(p)


def simulate_distances(
    robot: Robot,
    q: np.ndarray,
    *,
    q_other: np.ndarray | None = None,
    pivot: Sequence[int] | np.ndarray | None = None,
    pivots: np.ndarray | None = None,
    bar: Sequence[int] | np.ndarray | None = None,
    sigma_mm: float = 0.01,
    seed: int = 0,
    cell: Cell | None = None,
    truth: TrackerModel | None = None,
    hold: Sequence[str] = (),
) -> tuple[DistanceData, dict]:
    """Simulated distance rows (:class:`~kpioed_drake.tracker.contactdata.DistanceData`).

    Args:
        robot: the nominal robot.
        q, q_other, pivot, bar: the rows as :meth:`DistanceData.from_arrays` takes them [rad; mm].
        pivots: (C, 3) the pivots' true positions in W [mm] (with pivot rows).
        sigma_mm: the lengths' noise [mm].
        seed: of ``numpy.random.default_rng``: the truth (unless given), the bars' corrections,
            the noise, in this order.
        cell: the measuring cell of the nominal model (default ``models/cell.yaml``).
        truth: the true model (default: drawn).
        hold: parameters nominal in a drawn truth (a contact fit's gauge beyond the points').

    Returns:
        (data, truth): ``truth`` holds ``model`` (the true model), ``pivots`` (C, 3) [mm],
        ``bar_dL`` (B,) the bars' true corrections [mm], ``sigma_mm``, ``seed``.
    """
    rng = np.random.default_rng(seed)
    model = _truth(robot, rng, cell, truth, hold)
    shape = DistanceData.from_arrays(
        q, 1.0, q_other=q_other, pivot=pivot, bar=bar, sigma_mm=sigma_mm, n_joints=robot.n_joints
    )
    C = shape.n_pivots
    pivots = np.zeros((0, 3)) if C == 0 else np.asarray(pivots, dtype=float)
    if pivots.shape != (C, 3):
        raise InputError(f"simulate_distances: pivots: expected ({C}, 3) positions [mm], got {pivots.shape}")
    p_i = reflector_world(model, shape.q)
    q_j = np.where(shape.is_pair[:, None], shape.q_other, shape.q)
    p_j = reflector_world(model, q_j)
    if C:
        p_j = np.where(shape.is_pair[:, None], p_j, pivots[np.maximum(shape.pivot, 0)])
    bar_dL = LENGTH_ERROR_MM * rng.standard_normal(shape.n_bars)
    length = np.linalg.norm(p_i - p_j, axis=1)
    if shape.n_bars:
        length -= np.where(shape.bar >= 0, bar_dL[np.maximum(shape.bar, 0)], 0.0)
    length = length + rng.normal(0.0, sigma_mm, shape.n) if sigma_mm > 0 else length
    data = dataclasses.replace(shape, length=length)
    return data, {
        "model": model,
        "pivots": pivots,
        "bar_dL": bar_dL,
        "sigma_mm": float(sigma_mm),
        "seed": seed,
    }


def simulate_planes(
    robot: Robot,
    q: np.ndarray,
    plane: Sequence[int] | np.ndarray,
    *,
    normals: np.ndarray,
    offsets: np.ndarray,
    sigma_mm: float = 0.01,
    seed: int = 0,
    cell: Cell | None = None,
    truth: TrackerModel | None = None,
    hold: Sequence[str] = (),
    target: Sequence[int] | np.ndarray | None = None,
) -> tuple[PlaneData, dict]:
    """Simulated plane contacts (:class:`~kpioed_drake.tracker.contactdata.PlaneData`).

    Args:
        robot: the nominal robot.
        q: (n, n_joints) commanded poses near their planes [rad; mm].
        plane: (n,) 0-based plane of each row.
        normals: (K, 3) the planes' true normals in W (normalised here); offsets: (K,) [mm].
        sigma_mm: the contacts' noise along the normal [mm].
        seed, cell, truth, hold: as :func:`simulate_distances` (draws: the truth, then the noise).
        target: (n,) 0-based tool target touching in each row (None: target 0), e.g. the two arms'
            of a two-arm robot.

    Returns:
        (data, truth): the touched poses; ``truth`` holds ``model``, ``normals`` (K, 3),
        ``offsets`` (K,) [mm], ``sigma_mm``, ``seed``.

    Raises:
        InputError: bad shapes, or a row whose touch search does not converge (a pose too far from
            its plane, or at a singularity).
    """
    rng = np.random.default_rng(seed)
    model = _truth(robot, rng, cell, truth, hold)
    data = PlaneData.from_arrays(q, plane, sigma_mm=sigma_mm, n_joints=robot.n_joints, target=target)
    n = np.atleast_2d(np.asarray(normals, dtype=float))
    d = np.asarray(offsets, dtype=float)
    if n.shape != (data.n_planes, 3) or d.shape != (data.n_planes,):
        raise InputError(
            f"simulate_planes: expected normals ({data.n_planes}, 3) and offsets ({data.n_planes},)"
        )
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    eps = rng.normal(0.0, sigma_mm, data.n) if sigma_mm > 0 else np.zeros(data.n)
    q_touch = _touch(model, data.q, n[data.plane], d[data.plane] + eps, data.target)
    touched = dataclasses.replace(data, q=q_touch)
    return touched, {"model": model, "normals": n, "offsets": d, "sigma_mm": float(sigma_mm), "seed": seed}


def _touch(
    model: TrackerModel, q: np.ndarray, n: np.ndarray, d: np.ndarray, target: np.ndarray | None = None
) -> np.ndarray:
    """(n, n_joints) joint values near ``q`` at which the rows' tool points (``target``, None:
    target 0) satisfy ``n . p = d``; only the joints that move a row's point move."""
    q = q.copy()
    for _ in range(TOUCH_ITERATIONS):
        frames = model.frames(q)
        p = reflector_world(model, q, target)
        f = np.sum(n * p, axis=1) - d
        if np.all(np.abs(f) < TOUCH_TOL_MM):
            return q
        dp_dq = frames.joint_motion(p)  # (n, nj, 3)
        on = frames.point_path(model.target_links(target))
        if on is not None:
            dp_dq = dp_dq * on[:, :, None]
        g = np.einsum("nji,ni->nj", dp_dq, n)
        q -= (f / np.maximum(np.sum(g**2, axis=1), 1e-300))[:, None] * g
    bad = int(np.argmax(np.abs(f)))
    raise InputError(
        f"simulate_planes: row {bad + 1}: the pose does not reach its plane ({f[bad]:.3g} mm off)"
    )


def truth_parameters(fitted: TrackerModel, truth: dict) -> np.ndarray:
    """(n_full,) the truth of ``simulate_*`` in ``fitted``'s parameter vector: the true robot's joint
    rows, targets and tracker position, the small rotations taking ``fitted.R_WT_ref`` to the true
    tracker orientation, the true pivots and bar corrections, and the true planes as tilts about
    ``fitted.n_W_ref`` (with their offsets)."""
    lay, true = fitted.layout, truth["model"]
    p = np.full(lay.size, np.nan)
    for seg, true_seg in ((lay.joints, true.layout.joints), (lay.targets, true.layout.targets)):
        p[seg] = true.p[true_seg]
    p[lay.tracker_position] = true.p_WT
    p[lay.tracker_rotation] = Rotation.from_matrix(fitted.R_WT_ref.T @ true.R_WT).as_euler("XYZ")
    c = lay.contacts
    if c.bars:
        p[lay.bar_columns(np.arange(c.bars))] = truth["bar_dL"]
    if c.pivots:
        p[lay.pivot_columns(np.arange(c.pivots))] = truth["pivots"]
    if c.planes:  # v = m + t1 e1 + t2 e2 parallel to the true normal: t_i = e_i . n / (m . n)
        cols = lay.plane_columns(np.arange(c.planes))
        n, m = truth["normals"], fitted.n_W_ref
        mn = np.sum(m * n, axis=1)
        p[cols[:, :2]] = np.einsum("kij,kj->ki", tangent_basis(m), n) / mn[:, None]
        p[cols[:, 2]] = np.sign(mn) * truth["offsets"]
    return p
