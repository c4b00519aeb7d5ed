"""Self-contained 3-D pages of a design, a calibration and a diagnosis (Drake Meshcat, static HTML).

- :func:`design_page`: every pose of a design (paper eq. 24) with its laser beam and the witness
  segment of its smallest clearance, coloured by feasibility (eq. 24b, Drake's check); the working
  pose and the TCP's 95 % confidence ellipsoid ``x^T Cs^-1 x <= chi2_3(0.95)`` (Cs of eq. 24c),
  optionally next to a second design's.
- :func:`calibration_page`: measured against predicted reflector positions (eq. 3) with scaled
  residual arrows, outliers marked; with a 6-DoF probe's orientations its measured and predicted
  frames as triads (:mod:`kpioed_drake.scene3d.probe`).
- :func:`validation_page`: the same of a validation's prediction errors (points in W; the
  calibration page is drawn by it).
- :func:`diagnosis_page`: the residuals of the baseline model and of the model with a named
  extension, at the same scale.

Poses are steps of an animation (Meshcat's controls: Animations, time k s = pose k + 1). The
inputs are plain arrays (millimetres, radians), so the pages depend on the core modules only.
:func:`start_canvas`, :func:`draw_points` and :func:`finish_page` are the steps the pages share
(with :mod:`kpioed_drake.scene3d.contacts`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
import scipy.stats
from numpy.typing import ArrayLike
from pydrake.geometry import Rgba

from kpioed_drake.outputs import atomic_write_text
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.plant import build_scene
from kpioed_drake.scene3d.canvas import (
    BEAM,
    CAR,
    CLEARANCE,
    COMPARE,
    ELLIPSOID,
    INFEASIBLE,
    ROBOT,
    WORK,
    Canvas,
    css,
    nice_scale,
)
from kpioed_drake.scene3d.drawing import (
    clearance_witness,
    default_camera,
    draw_cell,
    draw_pose,
    draw_robot,
    reflector_point,
)
from kpioed_drake.scene3d.probe import ProbeFrames, draw_probe_frames
from kpioed_drake.tracker.feasibility import FeasibilityChecker, PoseReport
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world

K95 = float(np.sqrt(scipy.stats.chi2.ppf(0.95, 3)))
"""Radius of the 95 % confidence ellipsoid of a 3-D Gaussian in standard deviations (2.7955)."""
ELLIPSOID_TARGET_MM = 250.0
"""Default magnification draws the largest ellipsoid semi-axis at about this length [mm]."""
ARROW_TARGET_MM = 200.0
"""Default magnification draws the longest residual at about this length [mm]."""
BEFORE = Rgba(0.95, 0.35, 0.0, 1.0)
AFTER = Rgba(0.0, 0.55, 0.35, 1.0)
RESIDUAL = Rgba(0.1, 0.3, 0.9, 1.0)
POINT = Rgba(0.2, 0.2, 0.2, 1.0)
HALO = Rgba(0.9, 0.0, 0.1, 0.35)
STEP_NOTE = "Step through the poses: Open Controls > Animations > play, or drag 'time' (t = k s: pose k+1)."


def write_page(path: str | Path, page: str) -> Path:
    """Write a page atomically (:func:`kpioed_drake.outputs.atomic_write_text`); returns the path."""
    atomic_write_text(path, page)
    return Path(path)


def start_canvas(
    robot: Robot, cell: Cell, title: str, q, colours, *, pairs=None, shown: int = 0, reflector: bool = True
):
    """Canvas with the cell and one animated group per pose; returns it, the scene and p_WQ (n, 3).

    ``pairs`` (n,) names the clearance pair whose witness segment each pose shows (or "" / None);
    the page opens showing pose ``shown`` (0-based); ``reflector`` False draws no reflectors and beams.
    """
    scene = build_scene(robot, cell)
    canvas = Canvas(title)
    draw_cell(canvas, scene, robot, cell)
    p_Q = []
    for k, qk in enumerate(q):
        pair = pairs[k] if pairs is not None else None
        witness = clearance_witness(scene, robot, cell, qk, pair) if pair else None
        path = canvas.group(k)
        p_Q.append(
            draw_pose(
                canvas, path, scene, robot, cell, qk, rgba=colours[k], witness=witness, reflector=reflector
            )
        )
    canvas.animate_groups(shown)
    return canvas, scene, np.array(p_Q)


def finish_page(
    canvas: Canvas, robot: Robot, cell: Cell, points: np.ndarray, note: str, header: list, rows: list
) -> str:
    """The page of ``canvas`` with the ``note``, the per-pose table (``header``, ``rows``) and the
    camera on the ``points`` (n, 3) [mm]."""
    canvas.notes.append(note)
    canvas.table = (header, rows)
    default_camera(canvas, robot, cell, points)
    return canvas.html()


def design_page(
    robot: Robot,
    cell: Cell,
    q: ArrayLike,
    *,
    reports: list[PoseReport] | None = None,
    q_work: ArrayLike | None = None,
    Cs: np.ndarray | None = None,
    compare: tuple | None = None,
    title: str | None = None,
    ellipsoid_scale: float | None = None,
) -> str:
    """3-D page of a measurement design.

    Args:
        robot, cell: the models (the cell as loaded for this robot).
        q: (n, 6) poses [rad].
        reports: feasibility of each pose (:meth:`FeasibilityChecker.check`); computed if None.
        q_work: (6,) working pose [rad] (default the robot's); drawn as a translucent robot.
        Cs: (3, 3) covariance of the TCP at ``q_work`` [mm^2]; its 95 % ellipsoid is drawn at the
            reflector point of ``q_work``.
        compare: a second design ``(label, q (m, 6) [rad], Cs (3, 3) [mm^2] or None)``: its
            reflector points and its ellipsoid (above the first, same scale) are drawn in lavender.
        title: page title (default: robot, number of poses, feasible count).
        ellipsoid_scale: magnification of the ellipsoids (default: a round number drawing the
            largest semi-axis at about :data:`ELLIPSOID_TARGET_MM`).

    Returns:
        The HTML text.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if reports is None:
        reports = FeasibilityChecker(robot, cell).check(q)
    n_ok = sum(r.feasible for r in reports)
    title = title or f"{robot.name}: design, {len(q)} poses, {n_ok} feasible"
    colours = [ROBOT if r.feasible else INFEASIBLE for r in reports]
    pairs = [r.min_clearance_pair for r in reports]
    shown = int(np.argmin([r.min_clearance_mm for r in reports]))
    canvas, scene, p_Q = start_canvas(robot, cell, title, q, colours, pairs=pairs, shown=shown)
    with canvas:
        for k, p in enumerate(p_Q):
            canvas.sphere(f"/design/reflectors/{k + 1:03d}", p, 25.0, colours[k])
        canvas.legend += [
            (css(ROBOT), f"robot, feasible pose ({n_ok})"),
            (css(INFEASIBLE), f"robot, infeasible pose ({len(q) - n_ok})"),
            (css(BEAM), "laser beam, reflector to tracker"),
            (css(CLEARANCE), "smallest clearance (witness points)"),
            (css(CAR), "car; grey: mount; panels: floor and wall"),
        ]
        if compare is not None:
            for k, p in enumerate(np.atleast_2d(compare[1])):
                canvas.sphere(
                    f"/compare/reflectors/{k + 1:03d}", reflector_point(robot, cell, p), 10.0, COMPARE
                )
            canvas.legend.append((css(COMPARE), f"{compare[0]}: reflector points"))
        q_work = robot.q_work if q_work is None else np.asarray(q_work, dtype=float)
        if q_work is not None:
            _kpi(canvas, scene, robot, cell, q_work, Cs, compare, ellipsoid_scale)
        note = f"Shown: pose {shown + 1}, the one with the smallest clearance. {STEP_NOTE}"
        header = ["pose", "feasible", "min clearance [mm]", "pair", "incidence [deg]"]
        rows = [
            [
                str(k + 1),
                "yes" if r.feasible else "NO",
                f"{r.min_clearance_mm:.1f}",
                r.min_clearance_pair,
                f"{r.incidence_deg:.1f}",
            ]
            for k, r in enumerate(reports)
        ]
        return finish_page(canvas, robot, cell, p_Q, note, header, rows)


def _kpi(canvas, scene, robot, cell, q_work, Cs, compare, scale) -> None:
    """Working pose, TCP and the 95 % ellipsoids: ``Cs`` at the TCP, the comparison's above it."""
    draw_robot(canvas, "/kpi/working pose", scene, q_work, WORK)
    p_tcp = reflector_point(robot, cell, q_work)
    canvas.legend.append((css(WORK), "working pose q_work"))
    covs = [("this design", Cs, ELLIPSOID)]
    if compare is not None:
        covs.append((compare[0], compare[2], COMPARE))
    covs = [(label, np.asarray(C, float), colour) for label, C, colour in covs if C is not None]
    if not covs:
        return
    longest = [K95 * np.sqrt(np.linalg.eigvalsh(C).max()) for _, C, _ in covs]
    scale = scale or nice_scale(max(longest), ELLIPSOID_TARGET_MM)
    for k, (label, C, colour) in enumerate(covs):
        centre = p_tcp + [0.0, 0.0, scale * (longest[0] + longest[k]) + 80.0] if k else p_tcp
        semi = canvas.ellipsoid(f"/kpi/ellipsoid {k + 1}", centre, C * scale**2, K95, colour) / scale
        axes = ", ".join(f"{s:.3f}" for s in semi)
        canvas.legend.append((css(colour), f"TCP 95 % ellipsoid, {label}: semi-axes {axes} mm"))
    above = "; the second above it" if len(covs) > 1 else ""
    canvas.notes.append(f"Ellipsoids magnified x{scale:g} (centred at the TCP of q_work{above}).")


def _arrows(canvas: Canvas, path: str, starts, vectors_W, scale: float, rgba: Rgba, which=None) -> None:
    """Arrows ``starts[k]`` to ``starts[k] + scale * vectors_W[k]`` [mm] at ``path/<k+1>``, k in ``which``."""
    for k in range(len(starts)) if which is None else which:
        canvas.arrow(f"{path}/{k + 1:03d}", starts[k], starts[k] + scale * vectors_W[k], 8.0, rgba)


def calibration_page(
    robot: Robot,
    cell: Cell,
    model: TrackerModel,
    q: ArrayLike,
    measured_xyz_T: ArrayLike,
    predicted_xyz_T: ArrayLike,
    *,
    outliers: Iterable[int] | None = None,
    scale: float | None = None,
    title: str | None = None,
    probe: ProbeFrames | None = None,
) -> str:
    """3-D page of a calibration: measured vs predicted reflector points and residual arrows.

    Args:
        robot, cell: the models (the robot drawn with its nominal geometry).
        model: the calibrated measurement model (its tracker pose places the tracker-frame points).
        q: (n, 6) poses [rad].
        measured_xyz_T, predicted_xyz_T: (n, 3) measured ``eta`` and predicted ``h(p, q)`` reflector
            positions in the tracker frame [mm] (eq. 3).
        outliers: indices (0-based) of the poses removed as outliers (red).
        scale: magnification of the residual arrows (default: the longest residual of the poses
            kept, not the outliers', drawn at about 200 mm).
        probe: a 6-DoF probe's predicted frames and orientation errors
            (:func:`~kpioed_drake.scene3d.probe.probe_frames`): triads at the worst poses.

    Returns:
        The HTML text.
    """
    eta, h = np.asarray(measured_xyz_T, float), np.asarray(predicted_xyz_T, float)
    r_W = (eta - h) @ model.R_WT.T
    p_pred = model.p_WT + h @ model.R_WT.T
    options = dict(probe=probe, title=title, scale=scale, outliers=outliers, kind="calibration")
    return validation_page(robot, cell, q=q, predicted_W=p_pred, residuals_W=r_W, **options)


def validation_page(
    robot: Robot,
    cell: Cell,
    *,
    q: ArrayLike,
    predicted_W: ArrayLike,
    residuals_W: ArrayLike,
    outliers: Iterable[int] | None = None,
    probe: ProbeFrames | None = None,
    kind: str = "validation",
    label: str = "",
    title: str | None = None,
    scale: float | None = None,
) -> str:
    """3-D page of a validation (and of a calibration, ``kind``, from points in W): the predicted
    reflector points and the prediction errors as arrows, under ``/<kind>``; probe frames under
    ``/probe``.

    Args:
        q: (n, 6) poses [rad].
        predicted_W: (n, 3) the model's predicted points in W [mm]; residuals_W: (n, 3) measured
            minus predicted in W [mm] (the measurements taken to W with the validation's tracker frame).
        label: the tracker frame used (e.g. ``kept``), for the title.
        probe, scale, outliers: as :func:`calibration_page`'s.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = set(int(i) for i in (outliers or ()))
    p_pred, r_W = np.asarray(predicted_W, float), np.asarray(residuals_W, float)
    norms = np.linalg.norm(r_W, axis=1)
    keep = np.array([k not in out for k in range(len(q))])
    scale = scale or nice_scale(float(norms[keep if keep.any() else ~keep].max()), ARROW_TARGET_MM)
    frame = f" (tracker frame {label})" if label else ""
    title = title or f"{robot.name}: {kind}{frame}, {len(q)} poses, {len(out)} outliers, residuals x{scale:g}"
    colours = [INFEASIBLE if k in out else ROBOT for k in range(len(q))]
    canvas, _, _ = start_canvas(robot, cell, title, q, colours)
    with canvas:
        draw_points(canvas, f"/{kind}", p_pred, r_W, scale, out)
        canvas.legend.append((css(BEAM), "laser beam"))
        header = ["pose", "|residual| [mm]", "outlier"]
        rows = [[str(k + 1), f"{norms[k]:.3f}", "yes" if k in out else ""] for k in range(len(q))]
        if probe is not None:
            draw_probe_frames(canvas, "/probe", probe, p_pred, r_W, scale)
            header.append("orientation error [deg]")
            rows = [[*row, f"{e:.4f}"] for row, e in zip(rows, probe.errors_deg, strict=True)]
        return finish_page(canvas, robot, cell, p_pred, STEP_NOTE, header, rows)


def draw_points(canvas: Canvas, path: str, p_pred: np.ndarray, r_W: np.ndarray, scale: float, out=()) -> None:
    """Predicted points (spheres) ``p_pred`` (n, 3) and residual arrows ``r_W`` (n, 3) magnified
    ``scale`` [mm] under ``path/predicted``, ``path/residuals``, the outliers' (0-based ``out``)
    arrows and halos under ``path/outliers``; and their legend."""
    keep = np.array([k not in out for k in range(len(p_pred))], dtype=bool)
    for k, p in enumerate(p_pred):
        canvas.sphere(f"{path}/predicted/{k + 1:03d}", p, 15.0, POINT)
        if k in out:
            canvas.sphere(f"{path}/outliers/{k + 1:03d}/halo", p, 45.0, HALO)
    _arrows(canvas, f"{path}/residuals", p_pred, r_W, scale, RESIDUAL, np.flatnonzero(keep))
    _arrows(canvas, f"{path}/outliers", p_pred, r_W, scale, INFEASIBLE, np.flatnonzero(~keep))
    canvas.legend += [
        (css(POINT), "predicted reflector point h(p, q)"),
        (css(RESIDUAL), f"residual: arrow from predicted to measured, x{scale:g}"),
    ]
    if out:
        canvas.legend.append((css(INFEASIBLE), f"outlier ({len(out)}): arrow, halo and robot in red"))


def diagnosis_page(
    robot: Robot,
    cell: Cell,
    model: TrackerModel,
    q: ArrayLike,
    residual_before: ArrayLike,
    residual_after: ArrayLike,
    *,
    label: str = "extension",
    scale: float | None = None,
    title: str | None = None,
) -> str:
    """3-D page of a diagnosis: the residuals before and after adding the extension ``label``.

    Args:
        model: the baseline (geometric) model; the arrows start at its predicted reflector points.
        q: (n, 6) poses [rad].
        residual_before, residual_after: (n, 3) ``eta - h`` of the baseline and of the extended
            model, tracker frame [mm].
        label: name of the extension (e.g. ``joint_elasticity``).
        scale: magnification of both arrow sets (default: longest at about 200 mm).

    Returns:
        The HTML text.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    rb = np.asarray(residual_before, float) @ model.R_WT.T
    ra = np.asarray(residual_after, float) @ model.R_WT.T
    nb, na = np.linalg.norm(rb, axis=1), np.linalg.norm(ra, axis=1)
    scale = scale or nice_scale(float(max(nb.max(), na.max())), ARROW_TARGET_MM)
    rms_b, rms_a = np.sqrt(np.mean(rb**2)), np.sqrt(np.mean(ra**2))
    title = title or f"{robot.name}: diagnosis, residuals before / after {label}, x{scale:g}"
    canvas, _, _ = start_canvas(robot, cell, title, q, [ROBOT] * len(q))
    with canvas:
        p_pred = reflector_world(model, q)
        _arrows(canvas, "/diagnosis/before", p_pred, rb, scale, BEFORE)
        _arrows(canvas, "/diagnosis/after", p_pred, ra, scale, AFTER)
        canvas.legend += [
            (css(BEFORE), f"residual, geometric model (RMS {rms_b:.3f} mm), x{scale:g}"),
            (css(AFTER), f"residual with {label} (RMS {rms_a:.3f} mm), x{scale:g}"),
            (css(BEAM), "laser beam"),
        ]
        rows = [[str(k + 1), f"{nb[k]:.3f}", f"{na[k]:.3f}"] for k in range(len(q))]
        return finish_page(
            canvas, robot, cell, p_pred, STEP_NOTE, ["pose", "before [mm]", "after [mm]"], rows
        )
