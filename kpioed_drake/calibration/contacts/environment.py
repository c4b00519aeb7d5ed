"""The environment of a contact calibration: its planes, pivots and bars as a model file's
``contact_environment`` block (:class:`~kpioed_drake.robot.modelspec.ContactEnvironmentSpec`) and
back into a model, the environment fitted with the robot held, and the figures of residuals.

Units: millimetres and radians inside; the block holds unit normals, offsets [mm], pivot
positions in W [mm] and bar length corrections [mm].
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.modelspec import ContactEnvironmentSpec, PlaneSpec, RobotSpec, load_yaml_typed
from kpioed_drake.robot.parameters import ContactLayout, parameter_layout
from kpioed_drake.robot.urdf.read import SidecarSpec, sidecar_path
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.contacts import ContactRows
from kpioed_drake.tracker.distance import pivot_start
from kpioed_drake.tracker.measurement import TrackerModel
from kpioed_drake.tracker.plane import plane_normals, plane_start

FIT_ITERATIONS = 50
"""Most Gauss-Newton steps of :func:`fit_environment`."""
FIT_TOL = 1e-12
""":func:`fit_environment` stops when a step changes the cost by less than this fraction."""


def environment_of(model: TrackerModel) -> ContactEnvironmentSpec:
    """The planes, pivots and bars of a fitted ``model`` as a model file's block."""
    lay = model.layout
    c = lay.contacts
    normals, offsets = plane_normals(model) if c.planes else (np.zeros((0, 3)), np.zeros(0))
    return ContactEnvironmentSpec(
        planes=[
            PlaneSpec(normal=n.tolist(), offset_mm=float(d)) for n, d in zip(normals, offsets, strict=True)
        ],
        pivots_mm=model.p[lay.pivot_columns(np.arange(c.pivots))].reshape(-1, 3).tolist() if c.pivots else [],
        bars_dL_mm=model.p[lay.bar_columns(np.arange(c.bars))].tolist() if c.bars else [],
    )


def model_environment(robot: Robot) -> ContactEnvironmentSpec | None:
    """The ``contact_environment`` of ``robot``'s model file (a URDF robot's sidecar), or None (a
    nominal model: none written, or an empty one)."""
    if robot.urdf is not None:
        path, schema = sidecar_path(Path(robot.urdf.path)), SidecarSpec
    else:
        path, schema = Path(robot.source) if robot.source else None, RobotSpec
    if path is None or not path.is_file():
        return None
    env = load_yaml_typed(path, schema).contact_environment
    if env is None or not (env.planes or env.pivots_mm or env.bars_dL_mm):
        return None
    where = f"{path}: contact_environment"
    for k, p in enumerate(env.planes):
        n = np.asarray(p.normal, dtype=float)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or abs(np.linalg.norm(n) - 1.0) > 1e-6:
            raise InputError(
                f"{where}: planes[{k}].normal: expected a unit vector of 3 numbers, got {p.normal}"
            )
    if any(len(v) != 3 for v in env.pivots_mm):
        raise InputError(f"{where}: pivots_mm: expected [x, y, z] per pivot [mm]")
    return env


def with_environment(
    model: TrackerModel, normals: np.ndarray, offsets: np.ndarray, pivots: np.ndarray, bars: np.ndarray
) -> TrackerModel:
    """``model`` (no contact parameters) with these planes ((K, 3) unit normals, (K,) offsets [mm];
    tilts 0 about them), pivots (C, 3) [mm] and bar corrections (B,) [mm]; its held parameters
    stay held."""
    lay = model.layout
    cl = ContactLayout(bars=len(bars), pivots=len(pivots), planes=len(offsets))
    held = tuple(n for i, n in enumerate(lay.names) if i not in set(lay.free.tolist()))
    layout = parameter_layout(model.robot, fixed=held, n_targets=lay.n_targets, contacts=cl)
    planes = np.column_stack([np.zeros((cl.planes, 2)), np.asarray(offsets, dtype=float)]).ravel()
    p = np.concatenate(
        [model.p, np.asarray(bars, dtype=float), np.asarray(pivots, dtype=float).ravel(), planes]
    )
    normals = np.asarray(normals, dtype=float).reshape(-1, 3)
    return dataclasses.replace(model, p=p, layout=layout, n_W_ref=normals if cl.planes else None)


def spec_model(model: TrackerModel, env: ContactEnvironmentSpec) -> TrackerModel:
    """``model`` with a model file's environment (nothing fitted)."""
    normals = np.array([p.normal for p in env.planes], dtype=float).reshape(-1, 3)
    offsets = np.array([p.offset_mm for p in env.planes], dtype=float)
    return with_environment(
        model, normals, offsets, np.reshape(env.pivots_mm, (-1, 3)), np.asarray(env.bars_dL_mm)
    )


def fit_environment(
    model: TrackerModel, distances: DistanceData | None, planes: PlaneData | None
) -> TrackerModel:
    """``model`` (the robot held) with the planes, pivots and bars of these rows fitted: the
    closed-form starts (:func:`~kpioed_drake.tracker.plane.plane_start`,
    :func:`~kpioed_drake.tracker.distance.pivot_start`, bars 0), then Gauss-Newton on their columns
    alone (weighted least squares, each row by its sigma).

    Raises:
        InputError: a plane or pivot the rows do not determine.
    """
    normals, offsets = plane_start(model, planes) if planes is not None else (np.zeros((0, 3)), np.zeros(0))
    pivots = (
        pivot_start(model, distances) if distances is not None and distances.n_pivots else np.zeros((0, 3))
    )
    bars = np.zeros(0 if distances is None else distances.n_bars)
    out = with_environment(model, normals, offsets, pivots, bars)
    rows = ContactRows(distances, planes)
    cols = np.arange(out.layout.size)[out.layout.contact]
    if not cols.size:
        return out
    cost = np.inf
    for _ in range(FIT_ITERATIONS):
        r, H, s = rows.jacobian(out)
        new = float(np.sum((r / s) ** 2))
        if cost - new <= FIT_TOL * max(new, 1e-300):
            break
        cost = new
        step = np.linalg.lstsq(H[:, cols] / s[:, None], -r / s, rcond=None)[0]
        p = out.p.copy()
        p[cols] += step
        out = out.with_params(p)
    return out


def residual_figures(r: np.ndarray) -> dict:
    """``n``, ``rms_mm``, ``mean_mm`` (of |r|), ``p95_mm``, ``max_mm`` of residuals ``r`` (n,) [mm]
    (``norms``: of 3-D errors alike)."""
    a = np.abs(np.asarray(r, dtype=float))
    if not a.size:
        return {"n": 0}
    return {
        "n": int(a.size),
        "rms_mm": float(np.sqrt(np.mean(a**2))),
        "mean_mm": float(np.mean(a)),
        "p95_mm": float(np.percentile(a, 95)),
        "max_mm": float(np.max(a)),
    }


def figures_line(what: str, fig: dict) -> str:
    """One line of :func:`residual_figures`."""
    if not fig.get("n"):
        return f"  {what}: no rows"
    return (
        f"  {what} ({fig['n']} rows): RMS {fig['rms_mm']:.4f} mm, mean {fig['mean_mm']:.4f} mm, "
        f"95 % {fig['p95_mm']:.4f} mm, max {fig['max_mm']:.4f} mm"
    )
