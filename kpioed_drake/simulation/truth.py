"""Simulated laser-tracker measurements of a robot whose true geometry differs from the nominal one.

:func:`simulate` draws a "true" robot: the nominal model plus random geometric errors on the 27
estimated parameters (SPEC sizes: standard deviation 0.5 mm for lengths, 0.05 deg for angles; the 6
gauge parameters stay nominal) and an arbitrary tracker frame (uniformly random orientation,
position within +-100 mm of the cell's tracker position): :func:`true_model`, which the synthetic
harness of :mod:`kpioed_drake.diagnosis` shares. It then measures the commanded poses, optionally
with non-geometric effects (:mod:`kpioed_drake.effects`), and adds N(0, sigma^2) noise per
coordinate. The result is a table in the measurement-file format of SPEC ("Measured data and model
discrepancy") plus the truth.

Defaults for the environment columns (always written): ``time_s`` = 30 s per pose from 0;
``temperature_C`` = 20 C drifting linearly from 18 to 22 C over the run (plus 0.05 C jitter).
``payload_kg`` is written when a payload is given. A design CSV with a measurement plan (``kpioed
design --discriminate`` for a temperature, time or payload pair) has ``temperature_offset_K`` /
``time_offset_s`` / ``payload_offset_kg`` per row: :func:`simulate_file` adds them to these columns
(block 2 measured after the planned temperature change or pause, or with the planned payload).

Several targets (SMRs): every pose measures the first ``n_targets`` targets of the robot model
file (``targets_mm``; default all of them), one row per target, pose-major, with a ``target``
column (1..T) when there is more than one; the true robot has random errors on every target
offset. The environment columns are per pose (a pose's rows share them).

A 6-DoF probe (``orientation_sigma_deg``): the rows get the probe frame's orientation in the
tracker frame too (the native quaternion columns ``qw, qx, qy, qz``, scalar first, 10 decimals), the
true model ``R_TP = R_WT^T R_WF R_FP``
(:mod:`kpioed_drake.tracker.orientation`) times a small rotation with N(0, s^2) about each tracker
axis. The true robot then has errors on the probe layout's free parameters (a model file's
``extra_gauge`` is not held: orientations determine it) and its probe orientation on the flange is
the model file's ``probe_rpy_deg``, else uniformly random (drawn after the noise of the points).
Non-geometric effects with orientations are refused (their orientation is not modelled).

Units: files mm/deg; inside mm/rad.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from kpioed_drake.effects import model_effects, parse_effect, resolve, true_measurements
from kpioed_drake.errors import InputError
from kpioed_drake.files.designs import OFFSET_COLUMNS
from kpioed_drake.files.orientation_columns import QUATERNION_COLUMNS, native_columns
from kpioed_drake.files.tables import TARGET_COLUMN
from kpioed_drake.robot.jointmap import q_columns, q_from_file, q_to_file
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.tracker.data import per_pose
from kpioed_drake.tracker.measurement import TrackerModel, measure, nominal_model
from kpioed_drake.tracker.orientation import probe_orientation, with_probe

LENGTH_ERROR_MM = 0.5
ANGLE_ERROR_DEG = 0.05
TRACKER_POSITION_SPREAD_MM = 100.0
SECONDS_PER_POSE = 30.0
Q_DECIMALS = 8  # joint angles written with 1e-8 deg resolution; the simulation uses those values
XYZ_DECIMALS = 6
ORIENTATION_COLUMNS = QUATERNION_COLUMNS
"""A 6-DoF probe's orientation in the tracker frame: the native file's unit quaternion, scalar first
(``qw, qx, qy, qz``; docs/data-formats.md), unambiguous where Euler angles need a named convention."""
ORIENTATION_DECIMALS = 10


def random_rotation(rng: np.random.Generator, *, scalar_first: bool = True) -> np.ndarray:
    """(3, 3) rotation uniformly distributed on SO(3): the unit quaternion of four standard normals.

    Args:
        rng: the generator (four normals are drawn).
        scalar_first: read the normals as (w, x, y, z) (:func:`simulate`) or as (x, y, z, w), which
            is ``scipy.spatial.transform.Rotation.random`` (the diagnosis' synthetic harness). Both
            are uniform; each caller keeps its convention, so its seeded results reproduce.
    """
    return Rotation.from_quat(rng.standard_normal(4), scalar_first=scalar_first).as_matrix()


def true_model(
    nominal: TrackerModel,
    rng: np.random.Generator,
    *,
    geometric_errors: bool = True,
    tracker_spread_mm: float = TRACKER_POSITION_SPREAD_MM,
    scalar_first: bool = True,
) -> TrackerModel:
    """A "true" robot: nominal + random geometric errors + an arbitrary tracker frame.

    Errors: N(0, ``LENGTH_ERROR_MM``) on the free lengths, N(0, ``ANGLE_ERROR_DEG``) on the free
    angles of the joints and the reflector (the gauge parameters stay nominal); the tracker origin
    uniform within +-``tracker_spread_mm`` of the nominal one per axis; its orientation uniform
    (:func:`random_rotation` with ``scalar_first``). Draws in this order from ``rng``.
    """
    lay = nominal.layout
    p = nominal.p.copy()
    if geometric_errors:
        size = np.where(lay.is_angle, np.deg2rad(ANGLE_ERROR_DEG), LENGTH_ERROR_MM)
        robot_side = lay.free_robot_side
        p[robot_side] += size[robot_side] * rng.standard_normal(robot_side.size)
    p[lay.tracker_position] = nominal.p_WT + rng.uniform(-tracker_spread_mm, tracker_spread_mm, 3)
    p[lay.tracker_rotation] = 0.0
    return dataclasses.replace(nominal, p=p, R_WT_ref=random_rotation(rng, scalar_first=scalar_first))


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
    robot: Robot,
    q: np.ndarray,
    options: SimulationOptions | None = None,
    *,
    payload_kg: float | np.ndarray = 0.0,
    temperature_C: np.ndarray | None = None,
    time_s: np.ndarray | None = None,
    condition_offsets: dict | None = None,
    cell: Cell | None = None,
) -> tuple[pd.DataFrame, dict]:
    """Simulated measurement table of the poses ``q``.

    Args:
        robot: the nominal robot.
        q: (n, n_joints) commanded joint angles [rad].
        options: :class:`SimulationOptions` (noise, seed, effects, geometric errors, targets). An
            extended model file's effects (with their values) are part of the truth too, unless
            ``options.effects`` names the same.
        payload_kg: payload, one value or one per pose [kg]; the column is written if nonzero.
        temperature_C, time_s: per pose; defaults see the module docstring.
        condition_offsets: a measurement plan's offsets per pose added to them,
            ``{"temperature_C": [K], "time_s": [s], "payload_kg": [kg]}`` (any of them; a design
            CSV's ``temperature_offset_K`` / ``time_offset_s`` / ``payload_offset_kg``,
            :func:`~kpioed_drake.files.designs.read_condition_offsets`).
        cell: the measuring cell (default ``models/cell.yaml``).

    Returns:
        (table, truth): the table has columns ``q1_deg``..``q6_deg``, ``x_mm``, ``y_mm``, ``z_mm``,
        ``temperature_C``, ``time_s`` [, ``payload_kg``]; ``truth`` holds ``model`` (the true
        :class:`TrackerModel`), ``parameters`` (33 entries, mm/deg), ``R_WT``, ``p_WT_mm``,
        ``effects``, ``sigma_mm``, ``seed``.
    """
    rob, options = robot, options or SimulationOptions()
    sigma_mm, seed = options.sigma_mm, options.seed
    cell = load_cell(robot=rob) if cell is None else cell
    effects = _with_model_effects(rob, list(options.effects))
    q_deg, q, n_t = _checked_poses(rob, q, options.n_targets)
    n = q.shape[0]

    rng = np.random.default_rng(seed)
    pose = options.orientation_sigma_deg is not None
    if pose and effects:
        raise InputError(
            "simulate: orientation_sigma_deg with non-geometric effects: the effects' orientation is not "
            "modelled; simulate the orientations of the geometric model",
            fields=("orientation_sigma_deg", "effects"),
        )
    start = nominal_model(rob, cell)
    start = with_probe(start, np.eye(3)) if pose else start
    model = true_model(start, rng, geometric_errors=options.geometric_errors)
    offsets = condition_offsets or {}
    t, temp, payload = _conditions(
        n, rng, time_s=time_s, temperature_C=temperature_C, payload_kg=payload_kg, offsets=offsets
    )
    # one row per (pose, target), pose-major; one target: the rows are the poses
    target = None if n_t == 1 else np.tile(np.arange(n_t), n)
    q_deg, q, t, temp, payload = (np.repeat(x, n_t, axis=0) for x in (q_deg, q, t, temp, payload))

    eta, effect_objs = _measured(model, q, effects, rng, temp=temp, t=t, payload=payload, target=target)
    eta = eta + rng.normal(0.0, sigma_mm, eta.shape) if sigma_mm > 0 else eta

    table = _table(rob, q_deg, eta, t=t, temp=temp, payload=payload, target=target)
    R_TP = None
    if pose:
        ref = random_rotation(rng) if rob.R_FP is None else rob.R_FP
        model = dataclasses.replace(model, R_FP_ref=ref)
        R_TP = _orientations(model, q, float(options.orientation_sigma_deg or 0.0), rng)
        for k, (c, v) in enumerate(native_columns(R_TP, None).items()):
            table.insert(table.columns.get_loc("z_mm") + 1 + k, c, v)
    truth = {
        "robot": rob.name,
        "model": model,
        "parameters": parameters_table(model),
        "R_WT": model.R_WT.copy(),
        "p_WT_mm": model.p_WT.copy(),
        "effects": effect_objs,
        "sigma_mm": float(sigma_mm),
        "seed": int(seed),
        "geometric_errors": bool(options.geometric_errors),
        "n_targets": int(n_t),
        "condition_offsets": sorted(offsets),
        "R_TP": R_TP,
        "R_FP": None if R_TP is None else model.R_FP,
        "orientation_sigma_deg": options.orientation_sigma_deg,
    }
    return table, truth


def _orientations(
    model: TrackerModel, q: np.ndarray, sigma_deg: float, rng: np.random.Generator
) -> np.ndarray:
    """(rows, 3, 3) the probe's measured orientations: the true ones turned by N(0, sigma^2) about each
    tracker axis (none for 0)."""
    R = probe_orientation(model, q)
    if sigma_deg == 0:
        return R
    return Rotation.from_rotvec(rng.normal(0.0, np.deg2rad(sigma_deg), (len(q), 3))).as_matrix() @ R


def _checked_poses(rob: Robot, q, n_targets: int | None) -> tuple[np.ndarray, np.ndarray, int]:
    """The poses as the file will hold them (joint values [deg, mm] rounded to ``Q_DECIMALS``) and
    in model units, so that the simulation uses exactly the written values; and the targets
    measured per pose. InputError for a bad shape or target count."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    nj = rob.n_joints
    if q.shape != (n, nj) or n == 0 or not np.all(np.isfinite(q)):
        raise InputError(f"simulate: expected (n, {nj}) finite joint angles, got shape {q.shape}")
    n_t = rob.n_targets if n_targets is None else n_targets
    if not (isinstance(n_t, int | np.integer) and 1 <= n_t <= rob.n_targets):
        raise InputError(
            f"n_targets: expected a whole number in 1..{rob.n_targets} (the targets the robot model "
            f"{rob.source or rob.name} defines in targets_mm), got {n_targets!r}",
            fields=("n_targets",),
        )
    q_deg = np.round(q_to_file(rob, q), Q_DECIMALS)
    return q_deg, q_from_file(rob, q_deg), n_t


def _with_model_effects(robot: Robot, effects) -> list:
    """``effects`` plus those of an extended model file (``effects:``, with their values) that
    ``effects`` does not name: the file's model is part of the truth."""
    if not robot.effects:
        return effects
    given = [parse_effect(e, n_joints=robot.n_joints) if isinstance(e, str) else e for e in effects]
    keys = {e.key for e in given}
    return list(effects) + [e for e in model_effects(robot) if e.key not in keys]


def _conditions(n: int, rng: np.random.Generator, *, time_s, temperature_C, payload_kg, offsets: dict):
    """Time [s], temperature [C] and payload [kg] of the n poses: the given ones or the defaults (module
    docstring), plus a measurement plan's ``offsets`` (``simulate``'s ``condition_offsets``)."""
    t = np.arange(n) * SECONDS_PER_POSE if time_s is None else per_pose(time_s, n, "time_s")
    if temperature_C is None:
        frac = t / t[-1] if n > 1 and t[-1] > 0 else np.zeros(n)
        temp = 18.0 + 4.0 * frac + rng.normal(0.0, 0.05, n)
    else:
        temp = per_pose(temperature_C, n, "temperature_C")
    unknown = set(offsets) - set(OFFSET_COLUMNS)
    if unknown:
        raise InputError(
            f"simulate: condition offsets for {sorted(unknown)}; expected {sorted(OFFSET_COLUMNS)}"
        )
    # after the defaults, so a plan does not change the seeded draws; the payload offset is the
    # mass a plan adds at the reflector in its block 2
    cond = {"time_s": t, "temperature_C": temp, "payload_kg": per_pose(payload_kg, n, "payload_kg")}
    for c in cond:
        if c in offsets:
            cond[c] = cond[c] + per_pose(offsets[c], n, OFFSET_COLUMNS[c])
    t, temp, payload = cond["time_s"], cond["temperature_C"], cond["payload_kg"]
    if "payload_kg" in offsets and (bad := np.flatnonzero(payload < 0)).size:
        raise InputError(
            f"simulate: pose {bad[0] + 1}: payload {payload[bad[0]]:g} kg after the plan's "
            f"{OFFSET_COLUMNS['payload_kg']}; expected >= 0"
        )
    return t, temp, payload


def _measured(model: TrackerModel, q, effects, rng: np.random.Generator, *, temp, t, payload, target):
    """(rows, 3) noise-free measurements [mm] of the true ``model`` at ``q`` (one row per measurement)
    with the ``effects`` (texts drawn from ``rng`` or effect objects), and the resolved effects."""
    effect_objs = []
    if effects:
        for e in effects:
            e = parse_effect(e, rng, model=model) if isinstance(e, str) else e
            effect_objs.append(resolve(e, model))
        keys = [e.key for e in effect_objs]
        for k, e in zip(keys, effect_objs, strict=True):
            if keys.count(k) > 1:
                raise InputError(f"effect {e.name!r} given more than once")
        eta = true_measurements(
            model, q, effect_objs, temperature_C=temp, time_s=t, payload_kg=payload, target=target
        )
        eta = np.asarray(eta, dtype=float)
        if eta.shape != (len(q), 3):
            raise RuntimeError(
                f"effects.true_measurements returned shape {eta.shape}, expected {(len(q), 3)}"
            )
    else:
        eta = measure(model, q, target)
    return eta, effect_objs


def _table(rob: Robot, q_deg, eta, *, t, temp, payload, target) -> pd.DataFrame:
    """The measurement table: joint columns [deg, mm], x/y/z [mm], temperature and time, the payload
    if any is nonzero and the 1-based target if there are several."""
    cols = {c: q_deg[:, j] for j, c in enumerate(q_columns(rob))}
    cols.update(x_mm=eta[:, 0], y_mm=eta[:, 1], z_mm=eta[:, 2], temperature_C=temp, time_s=t)
    if np.any(payload != 0):
        cols["payload_kg"] = payload
    if target is not None:
        cols[TARGET_COLUMN] = target + 1
    return pd.DataFrame(cols)
