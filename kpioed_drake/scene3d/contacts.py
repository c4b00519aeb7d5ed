"""3-D page of a calibration or validation with plane contacts and distances (docs/contacts.md).

:func:`contact_page` draws, over the cell and the robot at every contact pose (an animation step
each, no laser beam):

- each plane ``n_k . x = d_k`` of the model (:func:`~kpioed_drake.tracker.plane.plane_normals`) as a
  thin translucent square patch: centred on the plane, its edges along the plane's tangent basis
  (:func:`~kpioed_drake.tracker.plane.tangent_basis`), bounding the projections of its touches plus
  :data:`MARGIN_MM`;
- the touch points, the model's tool point ``p_WQ(p, q)`` at each touch pose, as small spheres
  coloured by their signed distance residual ``n_k . p_WQ - d_k - s`` (blue below, grey on, red
  above the plane, full colour at the largest magnitude);
- each pivot ``p_WC`` as a sphere, and each distance row as a rod between the tool points of its two
  poses (pair rows) or from the tool point to its pivot, coloured by its residual (the model minus
  the measured length);
- tracker points measured with them, if any, as on a calibration page
  (:func:`~kpioed_drake.scene3d.pages.draw_points`).

Units: millimetres in W.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from pydrake.geometry import Rgba

from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.scene3d.canvas import INFEASIBLE, ROBOT, TRACKER, Canvas, css, nice_scale
from kpioed_drake.scene3d.pages import (
    ARROW_TARGET_MM,
    RESIDUAL,
    STEP_NOTE,
    draw_points,
    finish_page,
    start_canvas,
)
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world
from kpioed_drake.tracker.plane import plane_normals, tangent_basis

MARGIN_MM = 50.0
"""A plane patch reaches this far beyond its touches' projections [mm]."""
PATCH_MM = 2.0
"""Thickness of a plane patch [mm] (centred on the plane)."""
PATCH = Rgba(0.3, 0.6, 0.95, 0.25)
"""A plane's patch (translucent)."""
BELOW, ON, ABOVE = RESIDUAL, Rgba(0.75, 0.75, 0.75, 1.0), INFEASIBLE
"""Residual colours: the most negative, zero and the most positive (blue, grey, red)."""


def signed_colour(r: float, r_max: float) -> Rgba:
    """Colour of a signed residual ``r`` [mm]: grey at 0, towards blue (negative) or red (positive),
    full at ``|r| >= r_max``."""
    t = float(np.clip(r / r_max, -1.0, 1.0)) if r_max > 0 else 0.0
    end = ABOVE if t > 0 else BELOW
    a, b = np.array([ON.r(), ON.g(), ON.b()]), np.array([end.r(), end.g(), end.b()])
    return Rgba(*(a + abs(t) * (b - a)), 1.0)


def plane_patch(normal: ArrayLike, offset: float, points: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
    """The square patch of plane ``normal . x = offset`` [mm] around ``points`` (m, 3) [mm]:
    ``R_WB`` (3, 3) (columns: the tangent basis and the normal), the centre ``p_WB`` (3,) on the
    plane [mm] and the edge length [mm] (the larger extent of the projections plus twice
    :data:`MARGIN_MM`)."""
    n = np.asarray(normal, dtype=float)
    E = tangent_basis(n)[0]  # (2, 3)
    uv = np.atleast_2d(points) @ E.T
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    centre = 0.5 * (lo + hi) @ E + offset * n
    return np.column_stack([E[0], E[1], n]), centre, float(np.max(hi - lo) + 2.0 * MARGIN_MM)


def contact_page(
    robot: Robot,
    cell: Cell,
    model: TrackerModel,
    *,
    planes: tuple[PlaneData | None, ArrayLike] = (None, ()),
    distances: tuple[DistanceData | None, ArrayLike] = (None, ()),
    points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    kind: str = "calibration",
    title: str | None = None,
) -> str:
    """3-D page of plane contacts and distances (module docstring).

    Args:
        robot, cell: the models (the robot drawn with its nominal geometry).
        model: the model with the planes, pivots and bars (its layout's contacts) the residuals are of.
        planes: the plane rows and their residuals (n_p,) [mm] (rows None: none).
        distances: the distance rows and their residuals (n_d,) [mm] (rows None: none).
        points: tracker rows fitted or scored with them: ``(q (m, nj), predicted (m, 3), residuals
            (m, 3))`` in W [mm], or None.
        kind: ``calibration`` or ``validation`` (the title).

    Returns:
        The HTML text.
    """
    (p_rows, r_p), (d_rows, r_d) = planes, distances
    r_p, r_d = np.asarray(r_p, float).reshape(-1), np.asarray(r_d, float).reshape(-1)
    q = [d.q for d in (p_rows, d_rows) if d is not None]
    q_all = np.concatenate(q) if q else np.zeros((0, robot.n_joints))
    r_max = float(np.max(np.abs(np.concatenate([r_p, r_d])), initial=0.0))
    title = title or f"{robot.name}: {kind} with contacts, {len(q_all)} contact poses"
    canvas, _, _ = start_canvas(robot, cell, title, q_all, [ROBOT] * len(q_all), reflector=False)
    with canvas:
        header, rows, tool = ["pose", "contact", "residual [mm]"], [], []
        if p_rows is not None:
            tool.append(_draw_planes(canvas, model, p_rows, r_p, r_max, rows))
        if d_rows is not None:
            tool += _draw_distances(canvas, model, d_rows, r_d, r_max, rows, offset=len(rows))
        canvas.legend += [
            (css(signed_colour(-r_max, r_max)), f"residual -{r_max:.4f} mm (model below the measured)"),
            (css(ON), "residual 0"),
            (css(signed_colour(r_max, r_max)), f"residual +{r_max:.4f} mm"),
        ]
        if points is not None:
            _, p_pred, r_W = (np.asarray(a, float) for a in points)
            scale = nice_scale(float(np.linalg.norm(r_W, axis=1).max(initial=0.0)), ARROW_TARGET_MM)
            draw_points(canvas, "/contacts/tracker points", p_pred, r_W, scale)
            tool.append(p_pred)
        centre = np.concatenate(tool) if tool else np.zeros((1, 3))
        note = f"Residuals: the model minus the measured (signed distance, length). {STEP_NOTE}"
        return finish_page(canvas, robot, cell, centre, note, header, rows)


def _draw_planes(
    canvas: Canvas, model: TrackerModel, data: PlaneData, r: np.ndarray, r_max: float, rows: list
) -> np.ndarray:
    """The planes' patches and the touch points under ``/contacts/planes/plane <k>``; appends the
    table's rows; returns the touch points (n, 3) [mm]."""
    normals, offsets = plane_normals(model)
    p_W = reflector_world(model, data.q, data.target)
    for k in np.unique(data.plane):
        on = data.plane == k
        R, centre, side = plane_patch(normals[k], offsets[k], p_W[on])
        canvas.oriented_box(f"/contacts/planes/plane {k + 1}/patch", [side, side, PATCH_MM], R, centre, PATCH)
    for i, p in enumerate(p_W):
        path = f"/contacts/planes/plane {data.plane[i] + 1}/touches/{i + 1:03d}"
        canvas.sphere(path, p, 8.0, signed_colour(r[i], r_max))
        rows.append([str(i + 1), f"plane {data.plane[i] + 1}", f"{r[i]:+.4f}"])
    canvas.legend.append(
        (css(PATCH), f"estimated plane ({len(np.unique(data.plane))}): patch around its touches")
    )
    canvas.legend.append((css(ON), "touch point: the model's tool point, coloured by its signed distance"))
    return p_W


def _draw_distances(
    canvas: Canvas,
    model: TrackerModel,
    data: DistanceData,
    r: np.ndarray,
    r_max: float,
    rows: list,
    *,
    offset: int,
) -> list[np.ndarray]:
    """The pivots and the distance rows' rods under ``/contacts/distances``; appends the table's rows
    (poses numbered after ``offset``); returns the tool points and pivots [mm]."""
    lay = model.layout
    pivots = model.p[lay.pivot_columns(np.arange(lay.contacts.pivots))].reshape(-1, 3)
    p_i = reflector_world(model, data.q, data.target)
    pair = data.is_pair
    p_j = pivots[np.maximum(data.pivot, 0)] if pivots.size else np.zeros_like(p_i)
    if pair.any():
        q_j = np.where(pair[:, None], data.q_other, data.q)
        p_j = np.where(pair[:, None], reflector_world(model, q_j, data.target), p_j)
    for c, p in enumerate(pivots):
        canvas.sphere(f"/contacts/distances/pivots/pivot {c + 1}", p, 20.0, TRACKER)
    for i in range(data.n):
        path = f"/contacts/distances/rows/{offset + i + 1:03d}"
        colour = signed_colour(r[i], r_max)
        canvas.rod(f"{path}/bar", p_i[i], p_j[i], 3.0, colour)
        canvas.sphere(f"{path}/tool", p_i[i], 8.0, colour)
        if pair[i]:
            canvas.sphere(f"{path}/other tool", p_j[i], 8.0, colour)
        what = "pair" if pair[i] else f"pivot {data.pivot[i] + 1}"
        rows.append([str(offset + i + 1), f"distance, {what}", f"{r[i]:+.4f}"])
    canvas.legend.append((css(ON), "distance: rod between the tool points or to the pivot, by its residual"))
    if len(pivots):
        canvas.legend.append((css(TRACKER), f"estimated pivot ({len(pivots)})"))
    return [p_i, p_j]
