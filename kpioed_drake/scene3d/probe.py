"""A 6-DoF probe's measured and predicted frames drawn as RGB triads on a page of tracker points.

A 6-DoF probe (a laser tracker's T-Mac) measures the orientation ``R_TP`` of its frame P beside its
origin (:mod:`kpioed_drake.tracker.orientation`). At a row the model predicts ``R_WP = R_WF(q) R_FP``
(the flange's orientation of the forward kinematics, eq. 1, times the probe's mounting ``R_FP``) at
the predicted origin ``p_WP`` (target 0's point, eq. 3); the measurement is ``R_WT R_TP``, whose
error against the prediction is the rotation vector ``e = log(R_meas R_pred^T)`` in W [rad].

:func:`draw_probe_frames` draws, at up to :data:`MAX_TRIADS` rows (those of the largest errors), the
predicted frame (thin opaque axes) at the predicted origin and the measured frame (thick translucent
axes) at the tip of the row's residual arrow, its rotation from the predicted magnified
(``exp(s e) R_pred``, the factor ``s`` stated in the legend), so that errors of hundredths of a degree
are visible; the rows' errors go to the page's table and the largest to its notes.
Units: millimetres, radians (degrees in the text).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike
from pydrake.geometry import Rgba
from scipy.spatial.transform import Rotation

from kpioed_drake.scene3d.canvas import Canvas, css, nice_scale
from kpioed_drake.tracker.measurement import TrackerModel

MAX_TRIADS = 30
"""Most rows drawn with their probe frames (those of the largest orientation errors)."""
AXIS_MM = 50.0
"""Length of a triad's axes [mm]."""
ROTATION_TARGET_DEG = 20.0
"""Default magnification turns the largest drawn orientation error to about this angle [deg]."""
LISTED = 5
"""The page's notes name this many rows of the largest orientation errors."""
_FRAME = Rgba(0.35, 0.35, 0.35, 1.0)


@dataclasses.dataclass(frozen=True)
class ProbeFrames:
    """A probe's predicted orientations and their errors at the rows of a page.

    Attributes:
        R_WP: (n, 3, 3) the predicted probe frame orientations in W.
        errors_W: (n, 3) ``log(R_meas R_pred^T)`` in W axes [rad].
        origin: (n,) True at the rows whose point is the probe's origin (target 0): triads only there.
    """

    R_WP: np.ndarray
    errors_W: np.ndarray
    origin: np.ndarray

    @property
    def errors_deg(self) -> np.ndarray:
        """(n,) the rows' orientation errors (rotation angles) [deg]."""
        return np.rad2deg(np.linalg.norm(self.errors_W, axis=1))


def probe_frames(
    model: TrackerModel, q: ArrayLike, errors_W: ArrayLike, target: ArrayLike | None = None
) -> ProbeFrames:
    """The :class:`ProbeFrames` of ``model`` (with a probe orientation ``R_FP``) at ``q`` (n, n_joints)
    [rad; mm] and the rows' orientation errors ``errors_W`` (n, 3) [rad, W axes]; ``target`` (n,)
    0-based (None: every row is target 0)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    R_FP = model.R_FP
    if R_FP is None:
        raise ValueError("the model has no probe orientation (R_FP): data without orientations")
    R_WP = model.frames(q).at_link(None)[0] @ R_FP
    origin = np.ones(len(q), bool) if target is None else np.asarray(target) == 0
    return ProbeFrames(R_WP, np.asarray(errors_W, dtype=float), origin)


def shown_rows(frames: ProbeFrames, limit: int = MAX_TRIADS) -> np.ndarray:
    """(m,) the rows drawn (0-based, ascending): the ``limit`` probe origins of the largest errors."""
    rows = np.flatnonzero(frames.origin)
    worst = rows[np.argsort(-frames.errors_deg[rows], kind="stable")[:limit]]
    return np.sort(worst)


def draw_probe_frames(
    canvas: Canvas,
    path: str,
    frames: ProbeFrames,
    p_pred: np.ndarray,
    r_W: np.ndarray,
    scale: float,
    *,
    rotation_scale: float | None = None,
) -> float:
    """Predicted and measured probe frames at :func:`shown_rows` under ``path/predicted/<row>`` and
    ``path/measured/<row>`` (rows 1-based, 3 digits), their legend and notes.

    Args:
        p_pred: (n, 3) the predicted probe origins in W [mm]; r_W: (n, 3) their residuals
            (measured minus predicted) [mm], drawn magnified ``scale``: the measured frame sits at
            ``p_pred + scale * r_W``, the residual arrow's tip.
        rotation_scale: magnification of the orientation errors (default: a round number turning
            the largest drawn one to about :data:`ROTATION_TARGET_DEG`, at least 1).

    Returns:
        The rotation magnification used.
    """
    rows = shown_rows(frames)
    deg = frames.errors_deg
    if rotation_scale is None:
        largest = float(deg[rows].max()) if rows.size else 0.0
        rotation_scale = max(1.0, nice_scale(largest, ROTATION_TARGET_DEG))
    R_meas = Rotation.from_rotvec(rotation_scale * frames.errors_W[rows]).as_matrix() @ frames.R_WP[rows]
    for i, k in enumerate(rows):
        canvas.triad(f"{path}/predicted/{k + 1:03d}", frames.R_WP[k], p_pred[k], AXIS_MM, 2.0)
        tip = p_pred[k] + scale * r_W[k]
        canvas.triad(f"{path}/measured/{k + 1:03d}", R_meas[i], tip, AXIS_MM, 5.0, alpha=0.45)
    n_origin = int(np.count_nonzero(frames.origin))
    which = f"the {rows.size} of the largest orientation errors" if rows.size < n_origin else "every pose"
    canvas.legend += [
        (
            css(_FRAME),
            f"probe frame P, predicted R_WF R_FP: thin axes (x red, y green, z blue, {AXIS_MM:g} mm)",
        ),
        (
            css(_FRAME),
            f"probe frame P, measured R_WT R_TP: thick translucent axes at the residual arrow's tip, "
            f"its rotation from the predicted magnified x{rotation_scale:g}",
        ),
    ]
    worst = rows[np.argsort(-deg[rows], kind="stable")[:LISTED]]
    listed = "; ".join(f"pose {k + 1}: {deg[k]:.4f} deg" for k in worst)
    canvas.notes += [
        f"Probe frames drawn at {which} ({rows.size} of {n_origin} poses).",
        f"Largest orientation errors: {listed}." if listed else "No orientation errors.",
    ]
    return rotation_scale
