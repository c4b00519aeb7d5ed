"""Simulated laser-tracker measurements of a robot whose true geometry differs from the nominal one.

:func:`simulate` draws a "true" robot: the nominal model plus random geometric errors on the 27
estimated parameters (SPEC sizes: standard deviation 0.5 mm for lengths, 0.05 deg for angles; the 6
gauge parameters stay nominal) and an arbitrary tracker frame (uniformly random orientation, position
within +-100 mm of the cell's tracker position). It then measures the commanded poses, optionally
with non-geometric effects (:mod:`kpioed_drake.effects`), and adds N(0, sigma^2) noise per
coordinate. The result is a table in the measurement-file format of SPEC ("Measured data and model
discrepancy") plus the truth.

Defaults for the environment columns (always written): ``time_s`` = 30 s per pose from 0;
``temperature_C`` = 20 C drifting linearly from 18 to 22 C over the run (plus 0.05 C jitter).
``payload_kg`` is written when a payload is given.

Units: files mm/deg; inside mm/rad.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from kpioed_drake.designio import Q_COLUMNS, atomic_write_json, atomic_write_text, read_design
from kpioed_drake.errors import InputError
from kpioed_drake.measurement import TrackerModel, measure, nominal_model
from kpioed_drake.models import Robot, load_cell, load_robot

LENGTH_ERROR_MM = 0.5
ANGLE_ERROR_DEG = 0.05
TRACKER_POSITION_SPREAD_MM = 100.0
SECONDS_PER_POSE = 30.0
Q_DECIMALS = 8  # joint angles written with 1e-8 deg resolution; the simulation uses those values
XYZ_DECIMALS = 6


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix uniformly distributed on SO(3) (unit quaternion from 4 normals)."""
    w, x, y, z = rng.standard_normal(4)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def true_model(
    nominal: TrackerModel, rng: np.random.Generator, *, geometric_errors: bool = True
) -> TrackerModel:
    """Nominal + random geometric errors on the free parameters + an arbitrary tracker frame."""
    lay = nominal.layout
    p = nominal.p.copy()
    if geometric_errors:
        size = np.where(lay.is_angle, np.deg2rad(ANGLE_ERROR_DEG), LENGTH_ERROR_MM)
        joint_and_reflector = np.array([i for i in lay.free if not 24 <= i < 30])
        p[joint_and_reflector] += size[joint_and_reflector] * rng.standard_normal(joint_and_reflector.size)
    p[24:27] = nominal.p_WT + rng.uniform(-TRACKER_POSITION_SPREAD_MM, TRACKER_POSITION_SPREAD_MM, 3)
    p[27:30] = 0.0
    return dataclasses.replace(nominal, p=p, R_WT_ref=random_rotation(rng))


def _per_pose(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected one finite number or {n} (one per pose)")
    return arr


def parameters_table(model: TrackerModel) -> list[dict]:
    """The 33 parameters of a model in file units (mm, deg), with names and units."""
    lay = model.layout
    out = []
    for i, name in enumerate(lay.names):
        ang = bool(lay.is_angle[i])
        out.append(
            {
                "name": name,
                "value": float(np.rad2deg(model.p[i]) if ang else model.p[i]),
                "unit": "deg" if ang else "mm",
                "estimated": bool(i in set(lay.free.tolist())),
            }
        )
    return out


def simulate(
    robot: str | Robot,
    q,
    *,
    sigma_mm: float = 0.02,
    seed: int = 0,
    effects=(),
    geometric_errors: bool = True,
    payload_kg=0.0,
    temperature_C=None,
    time_s=None,
    cell_path=None,
) -> tuple[pd.DataFrame, dict]:
    """Simulated measurement table of the poses ``q``.

    Args:
        robot: model name, YAML path or :class:`Robot`.
        q: (n, 6) commanded joint angles [rad].
        sigma_mm: noise per coordinate [mm] (0 = noise free).
        seed: seed of ``numpy.random.default_rng`` (geometric errors, tracker frame, effects, noise).
        effects: effect specifications (strings parsed by ``effects.parse_effect``, or effect
            objects); empty = purely geometric model.
        geometric_errors: draw random geometric errors (False: the true robot is the nominal one).
        payload_kg: payload, one value or one per pose [kg]; the column is written if nonzero.
        temperature_C, time_s: per pose; defaults see the module docstring.

    Returns:
        (table, truth): the table has columns ``q1_deg``..``q6_deg``, ``x_mm``, ``y_mm``, ``z_mm``,
        ``temperature_C``, ``time_s`` [, ``payload_kg``]; ``truth`` holds ``model`` (the true
        :class:`TrackerModel`), ``parameters`` (33 entries, mm/deg), ``R_WT``, ``p_WT_mm``,
        ``effects``, ``sigma_mm``, ``seed``.
    """
    rob = load_robot(robot) if isinstance(robot, str) else robot
    cell = load_cell(cell_path, robot=rob)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    if q.shape != (n, 6) or n == 0 or not np.all(np.isfinite(q)):
        raise InputError(f"simulate: expected (n, 6) finite joint angles, got shape {q.shape}")
    if not (np.isfinite(sigma_mm) and sigma_mm >= 0):
        raise InputError(f"--sigma-mm must be a non-negative number of millimetres, got {sigma_mm!r}")
    # the simulation uses exactly the joint values that the file will hold
    q_deg = np.round(np.rad2deg(q), Q_DECIMALS)
    q = np.deg2rad(q_deg)

    rng = np.random.default_rng(seed)
    model = true_model(nominal_model(rob, cell), rng, geometric_errors=geometric_errors)
    t = np.arange(n) * SECONDS_PER_POSE if time_s is None else _per_pose(time_s, n, "time_s")
    if temperature_C is None:
        frac = t / t[-1] if n > 1 and t[-1] > 0 else np.zeros(n)
        temp = 18.0 + 4.0 * frac + rng.normal(0.0, 0.05, n)
    else:
        temp = _per_pose(temperature_C, n, "temperature_C")
    payload = _per_pose(payload_kg, n, "payload_kg")

    effect_objs = []
    if effects:
        from kpioed_drake.effects import parse_effect, resolve, true_measurements

        for e in effects:
            e = parse_effect(e, rng, model=model) if isinstance(e, str) else e
            effect_objs.append(resolve(e, model))
        keys = [e.key for e in effect_objs]
        for k, e in zip(keys, effect_objs, strict=True):
            if keys.count(k) > 1:
                raise InputError(f"effect {e.name!r} given more than once")
        eta = true_measurements(model, q, effect_objs, temperature_C=temp, time_s=t, payload_kg=payload)
        eta = np.asarray(eta, dtype=float)
        if eta.shape != (n, 3):
            raise RuntimeError(f"effects.true_measurements returned shape {eta.shape}, expected {(n, 3)}")
    else:
        eta = measure(model, q)
    eta = eta + rng.normal(0.0, sigma_mm, eta.shape) if sigma_mm > 0 else eta

    cols = {c: q_deg[:, j] for j, c in enumerate(Q_COLUMNS)}
    cols.update(x_mm=eta[:, 0], y_mm=eta[:, 1], z_mm=eta[:, 2], temperature_C=temp, time_s=t)
    if np.any(payload != 0):
        cols["payload_kg"] = payload
    table = pd.DataFrame(cols)
    truth = {
        "robot": rob.name,
        "model": model,
        "parameters": parameters_table(model),
        "R_WT": model.R_WT.copy(),
        "p_WT_mm": model.p_WT.copy(),
        "effects": effect_objs,
        "sigma_mm": float(sigma_mm),
        "seed": int(seed),
        "geometric_errors": bool(geometric_errors),
    }
    return table, truth


def table_csv_text(table: pd.DataFrame) -> str:
    """CSV text of a measurement table (joint angles to 1e-8 deg, positions to 1e-6 mm)."""
    out = table.copy()
    for c in Q_COLUMNS:
        out[c] = out[c].map(lambda v: f"{v:.{Q_DECIMALS}f}")
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = out[c].map(lambda v: f"{v:.{XYZ_DECIMALS}f}")
    for c in ("temperature_C", "time_s", "payload_kg"):
        if c in out:
            out[c] = out[c].map(lambda v: f"{v:.6g}")
    return out.to_csv(index=False, lineterminator="\n")


def truth_json(truth: dict) -> dict:
    """The JSON-serialisable part of a truth dict."""

    def effect_repr(e):
        return e.to_dict() if hasattr(e, "to_dict") else str(e)

    return {
        "robot": truth["robot"],
        "parameters": truth["parameters"],
        "R_WT": np.asarray(truth["R_WT"]).tolist(),
        "p_WT_mm": np.asarray(truth["p_WT_mm"]).tolist(),
        "effects": [effect_repr(e) for e in truth["effects"]],
        "sigma_mm": truth["sigma_mm"],
        "seed": truth["seed"],
        "geometric_errors": truth["geometric_errors"],
    }


def simulate_file(
    robot: str,
    design: str,
    out: str,
    *,
    sigma_mm: float = 0.02,
    seed: int = 0,
    effects=(),
    geometric_errors: bool = True,
    payload_kg: float = 0.0,
    truth_path: str | None = None,
    cell_path=None,
) -> tuple[pd.DataFrame, dict]:
    """Read a design file, simulate it, write the measurement CSV (and the truth JSON) atomically.

    Nothing is written unless the whole simulation succeeds.
    """
    rob = load_robot(robot)
    q = read_design(design, rob)
    table, truth = simulate(
        rob,
        q,
        sigma_mm=sigma_mm,
        seed=seed,
        effects=effects,
        geometric_errors=geometric_errors,
        payload_kg=payload_kg,
        cell_path=cell_path,
    )
    text = table_csv_text(table)
    tj = truth_json(truth) if truth_path else None
    atomic_write_text(out, text)
    if truth_path:
        atomic_write_json(truth_path, tj)
    return table, truth
