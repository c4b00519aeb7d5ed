"""The accuracy figures every report prints: how far the measured points lie from a model's
prediction, and on which poses with which tracker frame.

One function computes them (:func:`accuracy`) and one record writes them
(:meth:`Figures.lines`, :meth:`Figures.to_dict`), so that ``calibrate``, ``diagnose`` and
``validate`` print the same lines and a user can compare them line by line:

- RMS per coordinate of the residuals in W, for x, y, z and over all three [mm];
- the 3-D error of each row ``|measured - predicted|`` [mm]: mean, 95th percentile, max;
- the same per target (the rows of target t) when the data have several;
- a label: ``fit`` (the model was fitted to these poses: its error there is smaller than on
  others) or ``held-out`` (the model did not see them), and how the tracker frame was got
  (:data:`TRACKER`): estimated in the fit, kept (the model's), cross-registered (on other poses than
  those scored) or registered in-sample (fitted to the scored poses: optimistic).

Residuals are measured minus predicted, in W (the robot base: x towards the car, z up), so the
per-coordinate figures of every command are in the same frame.

With a 6-DoF probe's orientations, :func:`orientation_accuracy` gives the same figures of the
orientation errors (:class:`OrientationFigures`): the rotation vector ``log(R_meas R_model^T)`` of
each row in W axes, RMS about x, y, z and over all three [deg], and the angle ``|e|`` [deg]: mean,
95th percentile, max; labelled as the position figures beside them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.tracker.data import poses_and_rows

TRACKER = {
    "fitted": "tracker frame estimated in the fit",
    "kept": "tracker frame kept (the model's)",
    "cross": "tracker frame cross-registered (on the other half of the poses)",
    "folds": "tracker frame estimated with each fold's fit on the other folds' poses (cross-validation)",
    "in-sample": "tracker frame registered on these poses (in-sample: optimistic)",
}
"""How the tracker frame of a set of residuals was got, as the figures' header says it."""
KINDS = ("fit", "held-out")
"""Fit: the model was fitted to the poses scored; held-out: it did not see them."""


def labels(model: str, kind: str, tracker: str) -> dict:
    """The JSON labels of a block of figures: what was scored, fit or held-out, the tracker frame."""
    return {"model": model or None, "kind": kind, "tracker": tracker, "tracker_text": TRACKER[tracker]}


@dataclasses.dataclass(frozen=True)
class Figures:
    """Accuracy figures of one set of residuals (:func:`accuracy`) [mm].

    Attributes:
        kind: ``fit`` or ``held-out`` (:data:`KINDS`).
        tracker: a key of :data:`TRACKER`.
        n_poses, n_rows: the poses scored and their rows (one per pose and target).
        rms_mm: RMS over all coordinates; rms_xyz_mm: (x, y, z) RMS per coordinate in W.
        mean_error_mm, p95_error_mm, max_error_mm: of the 3-D error per row.
        targets: per target (several targets only): ``target`` (1-based), ``n_rows`` and the figures.
        model: what was scored (e.g. ``geometric model``; empty: the one model of the report).
    """

    kind: str
    tracker: str
    n_poses: int
    n_rows: int
    rms_mm: float
    rms_xyz_mm: tuple[float, float, float]
    mean_error_mm: float
    p95_error_mm: float
    max_error_mm: float
    targets: tuple[dict, ...] = ()
    model: str = ""

    def header(self) -> str:
        """``fit on 40 poses, tracker frame estimated in the fit`` (the model first when named)."""
        count = poses_and_rows(self.n_poses, self.n_rows)
        return (f"{self.model}, " if self.model else "") + f"{self.kind} on {count}, {TRACKER[self.tracker]}"

    def lines(self, indent: str = "  ") -> list[str]:
        """The header and the figures (and one line per target), each starting with ``indent``."""
        out = [f"{indent}{self.header()}:", f"{indent}  {figure_text(self.to_dict())}"]
        out += [
            f"{indent}  target {t['target']} ({t['n_rows']} rows): {figure_text(t)}" for t in self.targets
        ]
        return out

    @classmethod
    def from_dict(cls, d: dict, *, model: str | None = None) -> Figures:
        """The record of a JSON block (:meth:`to_dict`), its model renamed when ``model`` is given."""
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in d.items() if k in fields}
        kw["rms_xyz_mm"] = tuple(kw["rms_xyz_mm"])
        kw["targets"] = tuple(kw.get("targets") or ())
        kw["model"] = (kw.get("model") or "") if model is None else model
        return cls(**kw)

    def to_dict(self) -> dict:
        """The JSON block (mm)."""
        return {
            **labels(self.model, self.kind, self.tracker),
            "n_poses": self.n_poses,
            "n_rows": self.n_rows,
            "rms_mm": self.rms_mm,
            "rms_xyz_mm": list(self.rms_xyz_mm),
            "mean_error_mm": self.mean_error_mm,
            "p95_error_mm": self.p95_error_mm,
            "max_error_mm": self.max_error_mm,
            "targets": [dict(t) for t in self.targets],
        }


def figure_text(f: dict) -> str:
    """``RMS x, y, z, all: a, b, c, d mm; 3-D error mean m, 95 % p, max M mm`` of a figures dict."""
    rms = ", ".join(f"{v:.4f}" for v in (*f["rms_xyz_mm"], f["rms_mm"]))
    return (
        f"RMS x, y, z, all: {rms} mm; 3-D error mean {f['mean_error_mm']:.4f}, "
        f"95 % {f['p95_error_mm']:.4f}, max {f['max_error_mm']:.4f} mm"
    )


def _numbers(r: np.ndarray) -> dict:
    e = np.linalg.norm(r, axis=1)
    return {
        "rms_mm": float(np.sqrt(np.mean(r**2))),
        "rms_xyz_mm": [float(v) for v in np.sqrt(np.mean(r**2, axis=0))],
        "mean_error_mm": float(np.mean(e)),
        "p95_error_mm": float(np.percentile(e, 95)),
        "max_error_mm": float(np.max(e)),
    }


def accuracy(
    residuals_W: np.ndarray,
    q: np.ndarray,
    *,
    kind: str,
    tracker: str,
    target: np.ndarray | None = None,
    model: str = "",
) -> Figures:
    """The figures of residuals (measured minus predicted, in W) of the rows of poses ``q``.

    Args:
        residuals_W: (n, 3) residuals in W of the rows scored [mm].
        q: (n, n_joints) the rows' joint values (rows with equal values are one pose's targets).
        kind: ``fit`` or ``held-out``.
        tracker: how the tracker frame was got, a key of :data:`TRACKER`.
        target: (n,) 0-based target of each row, or None (one target).
        model: what was scored, named in the header (empty: not named).

    Returns:
        :class:`Figures` (per target only when the rows use several).

    Raises:
        ValueError: no rows, mismatched shapes, or an unknown kind or tracker (a programming error).
    """
    r = np.asarray(residuals_W, dtype=float)
    q = np.asarray(q, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] == 0 or q.shape[0] != r.shape[0]:
        raise ValueError(f"accuracy: expected (n, 3) residuals of n >= 1 rows, got {r.shape} and q {q.shape}")
    if kind not in KINDS or tracker not in TRACKER:
        raise ValueError(f"accuracy: unknown kind {kind!r} or tracker {tracker!r}")
    targets: tuple[dict, ...] = ()
    t = None if target is None else np.asarray(target, dtype=int)
    if t is not None and np.unique(t).size > 1:
        targets = tuple(
            {"target": int(k) + 1, "n_rows": int(np.count_nonzero(t == k)), **_numbers(r[t == k])}
            for k in np.unique(t)
        )
    f = _numbers(r)
    f["rms_xyz_mm"] = tuple(f["rms_xyz_mm"])
    n_poses = int(len(np.unique(q, axis=0)))
    return Figures(
        kind=kind, tracker=tracker, n_poses=n_poses, n_rows=r.shape[0], targets=targets, model=model, **f
    )


@dataclasses.dataclass(frozen=True)
class OrientationFigures:
    """Accuracy figures of a 6-DoF probe's orientation errors (:func:`orientation_accuracy`) [deg].

    Attributes:
        kind, tracker: as :class:`Figures` (the position figures' labels).
        n_rows: the rows scored.
        rms_deg: RMS over the three components; rms_xyz_deg: (x, y, z) RMS of the error's rotation
            vector about the W axes.
        mean_error_deg, p95_error_deg, max_error_deg: of the angle of each row's error.
        model: what was scored (empty: the one model of the report).
    """

    kind: str
    tracker: str
    n_rows: int
    rms_deg: float
    rms_xyz_deg: tuple[float, float, float]
    mean_error_deg: float
    p95_error_deg: float
    max_error_deg: float
    model: str = ""

    def lines(self, indent: str = "  ") -> list[str]:
        """One line: ``orientation (kind, tracker): RMS about x, y, z, all: ... deg; angle error ...``."""
        rms = ", ".join(f"{v:.4f}" for v in (*self.rms_xyz_deg, self.rms_deg))
        what = (
            f"{self.model}, " if self.model else ""
        ) + f"{self.kind} on {self.n_rows} rows, {TRACKER[self.tracker]}"
        return [
            f"{indent}  orientation ({what}): RMS about x, y, z, all: {rms} deg; angle error mean "
            f"{self.mean_error_deg:.4f}, 95 % {self.p95_error_deg:.4f}, max {self.max_error_deg:.4f} deg"
        ]

    def to_dict(self) -> dict:
        """The JSON block (deg)."""
        return {
            **labels(self.model, self.kind, self.tracker),
            "n_rows": self.n_rows,
            "rms_deg": self.rms_deg,
            "rms_xyz_deg": list(self.rms_xyz_deg),
            "mean_error_deg": self.mean_error_deg,
            "p95_error_deg": self.p95_error_deg,
            "max_error_deg": self.max_error_deg,
            "note": "rotation vector of R_measured R_predicted^T per row in W axes; angle = its norm",
        }


def orientation_accuracy(
    errors_W: np.ndarray, *, kind: str, tracker: str, model: str = ""
) -> OrientationFigures:
    """The figures of orientation errors ``errors_W`` (n, 3): rotation vectors of measured times
    predicted^T in W axes [rad]; ``kind`` and ``tracker`` as :func:`accuracy`.

    Raises:
        ValueError: no rows, a shape other than (n, 3), an unknown kind or tracker.
    """
    e = np.rad2deg(np.asarray(errors_W, dtype=float))
    if e.ndim != 2 or e.shape[1] != 3 or e.shape[0] == 0:
        raise ValueError(f"orientation_accuracy: expected (n, 3) errors of n >= 1 rows, got {e.shape}")
    if kind not in KINDS or tracker not in TRACKER:
        raise ValueError(f"orientation_accuracy: unknown kind {kind!r} or tracker {tracker!r}")
    angle = np.linalg.norm(e, axis=1)
    return OrientationFigures(
        kind=kind,
        tracker=tracker,
        n_rows=e.shape[0],
        rms_deg=float(np.sqrt(np.mean(e**2))),
        rms_xyz_deg=tuple(float(v) for v in np.sqrt(np.mean(e**2, axis=0))),  # type: ignore[arg-type]
        mean_error_deg=float(np.mean(angle)),
        p95_error_deg=float(np.percentile(angle, 95)),
        max_error_deg=float(np.max(angle)),
        model=model,
    )
