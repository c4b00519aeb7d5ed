"""Plausibility of measured data before a calibration or a diagnosis: refuse what cannot be right.

A fit always returns numbers; these checks make sure they mean something. Run before any fit, on
the nominal model with what the data alone can tell registered: the tracker frame (a rigid 6-DoF
fit, :func:`kpioed_drake.estimation.estimator.register_tracker`) and the target offsets on the
flange (a wrong nominal tool point is no robot error), no robot parameter moved:

- **degrees of freedom**: ``3 n`` coordinates must exceed the parameters, or no goodness of fit
  (and no covariance worth the name) exists;
- **units**: measured points spanning a hundredth (or a hundred times) of what the robot's poses
  span are lengths in metres (or micrometres), not millimetres;
- **gross errors**: after registering on the better half of the poses, a pose missing the nominal
  model by more than :func:`geometric_gate_mm` (scaled by the robot's reach) is no geometric
  error; more than a third of such rows is refused;
- **another robot or a wrong joint map**: an RMS miss of the better half above the same gate (the
  data of another robot, wrong joint signs, offsets or angle units).

After the fit, :func:`check_fitted` tests the estimate: robot parameters moved by more than
:data:`MAX_FITTED_SHARE` of the reach or :data:`MAX_FITTED_DEG` are no geometric error of a real
robot (a wrong joint map or coupling left out of it, another robot); it names the joint.

Each check raises :class:`~kpioed_drake.errors.InputError` (exit status 2) saying what looks
wrong, unless ``force=True``, which turns it into a warning.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import EstimationResult, register_tracker
from kpioed_drake.robot.parameters import joint_label, parameter_joint
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world

MAX_GEOMETRIC_MM = 25.0
"""Smallest gate [mm] on the miss of the registered nominal model that geometric errors can explain.
An industrial robot's uncalibrated absolute error is a few millimetres (SPEC's error sizes give
about 1 mm; the UR5 data set of the README 2.6 mm mean); 25 mm leaves a wide margin."""
GATE_REACH_SHARE = 0.03
"""... and the gate grows with the robot: 3 % of its reach (a 1.2 m elastic humanoid misses by
about 20 mm uncalibrated)."""
MAX_FITTED_SHARE = 0.1
"""A fitted robot length parameter more than this share of the reach from nominal is no error."""
MAX_FITTED_DEG = 15.0
"""Nor is a fitted robot angle more than this many degrees from nominal [deg]."""
REGISTRATION_ROUNDS = 12
"""Alternations of the tracker rotation and the tracker position with the target offsets (the last
half on the better half of the rows)."""

UNIT_RATIO = 100.0
"""Span ratio (measured / nominal points) beyond which the lengths are in other units."""

MAX_GROSS_FRACTION = 1.0 / 3.0
"""Largest fraction of poses with gross errors (beyond :data:`MAX_GEOMETRIC_MM`) that is accepted."""


def _refuse(message: str, force: bool, warnings: list[str]) -> None:
    if not force:
        raise InputError(f"{message} (use force to go on anyway)", fields=("force",))
    warnings.append(f"forced: {message}")


def geometric_gate_mm(model: TrackerModel) -> float:
    """The largest miss [mm] of the registered nominal model that geometric errors explain:
    ``max(MAX_GEOMETRIC_MM, GATE_REACH_SHARE * reach)``."""
    return max(MAX_GEOMETRIC_MM, GATE_REACH_SHARE * float(model.robot.reach))


def check_data(model: TrackerModel, data: Measurements, *, n_params: int, force: bool = False) -> list[str]:
    """Refuse implausible data; returns the warnings (with ``force``, the refusals as warnings).

    Args:
        model: the nominal measurement model (its tracker pose is not used).
        data: the measurements (tracker frame).
        n_params: parameters to be estimated (geometric plus effects).
        force: warn instead of refusing the plausibility checks (never the degrees of freedom).

    Raises:
        InputError: no degrees of freedom; lengths in other units; more than a third of gross
            errors; a registered miss beyond any geometric error.
    """
    where = data.source
    n = data.n
    if data.n_targets > model.layout.n_targets:
        raise InputError(
            f"{where}: field 'target': the rows name {data.n_targets} targets, but the robot model "
            f"defines {model.layout.n_targets} (add them to its targets_mm)"
        )
    if 3 * n <= n_params:
        raise InputError(
            f"{where}: {n} rows give {3 * n} coordinates for {n_params} parameters: no degree of freedom "
            f"is left to test the fit; at least {n_params // 3 + 1} rows (poses x targets) are needed"
        )
    warnings: list[str] = []
    p_W = reflector_world(model, data.q, data.target)
    _check_spread(p_W, data.eta, where)
    span_model, span_data = _span(p_W), _span(data.eta)
    if span_model > 0 and span_data * UNIT_RATIO < span_model:
        _refuse(
            f"{where}: the measured points span {span_data:.4g} mm but the robot's poses span "
            f"{span_model:.4g} mm: the lengths look like metres; expected millimetres (x_mm, y_mm, z_mm)",
            force,
            warnings,
        )
        return warnings
    if span_model > 0 and span_data > UNIT_RATIO * span_model:
        _refuse(
            f"{where}: the measured points span {span_data:.4g} mm but the robot's poses span only "
            f"{span_model:.4g} mm: the lengths look like micrometres or another robot's data",
            force,
            warnings,
        )
        return warnings
    gate = geometric_gate_mm(model)
    miss = _registered_miss(model, data)
    wild = data.rows[miss > WILD_REACHES * float(model.robot.reach)]
    if 0 < wild.size <= MAX_GROSS_FRACTION * n:  # more are the other checks' (units, robot, joint map)
        _refuse(
            f"{where}: row(s) {', '.join(map(str, wild[:8]))}{', ...' if wild.size > 8 else ''} miss the "
            f"nominal model by more than {WILD_REACHES:g} times the robot's reach after registering the "
            "tracker: no measurement of this robot (a mistyped or broken row); correct or remove them",
            force,
            warnings,
        )
        return warnings
    good = miss <= gate
    rows = data.rows[~good]
    if rows.size > MAX_GROSS_FRACTION * n:
        _refuse(
            f"{where}: {rows.size} of {n} rows miss the nominal model by more than {gate:.3g} mm "
            f"after registering the tracker and the target offsets (rows {', '.join(map(str, rows[:8]))}"
            f"{', ...' if rows.size > 8 else ''}): more than a third are gross errors, which is no "
            "calibration data; check the file, the joint map and the units",
            force,
            warnings,
        )
        return warnings
    rms = float(np.sqrt(np.mean(np.sort(miss)[: max(3, n // 2)] ** 2)))
    if rms > gate:
        _refuse(
            f"{where}: after registering the tracker frame and the target offsets the nominal model misses "
            f"the better half of the poses by {rms:.4g} mm RMS, more than geometric errors explain "
            f"({gate:.3g} mm): "
            "data of another robot, a wrong joint map (signs, offsets, degrees vs radians) or other units",
            force,
            warnings,
        )
    return warnings


SPAN_PERCENTILES = (10.0, 90.0)
"""The span of points compared in the units check: between these percentiles per axis, so that
one wild row (a mistyped coordinate) does not pass for other units; the gross-error check names
it."""
FLAT_SPREAD = 1e-6
"""Points whose second principal spread is below this share of the first lie on one line: no
rotation registers them."""


def _span(points: np.ndarray) -> float:
    """The largest robust extent of ``points`` (n, 3) over the axes [mm] (:data:`SPAN_PERCENTILES`)."""
    low, high = np.percentile(points, SPAN_PERCENTILES, axis=0)
    return float(np.max(high - low))


def _flat(points: np.ndarray) -> bool:
    """The points are all one or lie (nearly) on one line (:data:`FLAT_SPREAD`)."""
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(spread[1] <= FLAT_SPREAD * max(spread[0], 1e-300))


def _check_spread(p_W: np.ndarray, eta: np.ndarray, where: str) -> None:
    """Refuse points no tracker frame can be registered to (never forced: no fit exists).

    Raises:
        InputError: the file, and whether the poses or the measured points lie on one line.
    """
    distinct = len(np.unique(np.round(p_W, 9), axis=0))
    if _flat(p_W):
        at = "one point" if distinct == 1 else f"{distinct} distinct points on (nearly) one line"
        raise InputError(
            f"{where}: the poses put the reflector at {at}: "
            "the tracker frame cannot be registered; measure poses spread over the workspace (e.g. of "
            "`kpioed design`)"
        )
    if _flat(eta):
        raise InputError(
            f"{where}: the measured points (x_mm, y_mm, z_mm) are all one or lie (nearly) on one line "
            "while the poses spread: the tracker frame cannot be registered; check the file's columns"
        )


WILD_REACHES = 2.0
"""A row that misses the registered nominal model by more than this many reaches of the robot is
no gross error of a measurement of it (a wrong reflector is still within reach): a broken row,
refused by its row number (when they are a few: many are other units, another robot or a wrong
joint map)."""
WILD_FACTOR = 10.0
"""A measured point more than this many times the median distance from the points' median is left
out of the first registration rounds (a mistyped coordinate would turn the whole frame)."""


def _not_wild(eta: np.ndarray) -> np.ndarray:
    """(n,) the rows whose measured point lies within :data:`WILD_FACTOR` median distances of the
    points' median (all rows when fewer than three would be left)."""
    d = np.linalg.norm(eta - np.median(eta, axis=0), axis=1)
    use = d <= WILD_FACTOR * np.median(d)
    return use if np.count_nonzero(use) >= 3 else np.ones(len(eta), dtype=bool)


def _registered_miss(model: TrackerModel, data: Measurements) -> np.ndarray:
    """(n,) distance [mm] of each row after registering the tracker frame and the target offsets on
    all rows, then on the better half. Alternating: the tracker rotation by Procrustes given the
    points, then the tracker position and the offsets jointly by linear least squares
    (``R_WT eta_i + p_WT = o_WF_i + R_WF_i d_t``) given the rotation."""
    frames = model.frames(data.q)
    n = data.n
    target = np.zeros(n, dtype=int) if data.target is None else np.asarray(data.target)
    R_WF, o_WF = frames.at_link(model.target_links(target))  # each row's target link
    offsets = np.array(model.target_offsets, dtype=float)
    T = offsets.shape[0]
    # design matrix of [p_WT, d_0 .. d_{T-1}]: I for p_WT, -R_WF_i in target i's columns
    A = np.zeros((n, 3, 3 + 3 * T))
    A[:, :, :3] = np.eye(3)
    for t in range(T):
        A[target == t, :, 3 + 3 * t : 6 + 3 * t] = -R_WF[target == t]
    use = _not_wild(data.eta)
    for k in range(REGISTRATION_ROUNDS):
        p_W = o_WF + np.einsum("nij,nj->ni", R_WF, offsets[target])
        R_WT, _ = register_tracker(p_W[use], data.eta[use])
        rhs = o_WF - data.eta @ R_WT.T
        known = np.isin(np.arange(T), target[use])  # offsets of targets no used row measures stay
        cols = np.concatenate([[True] * 3, np.repeat(known, 3)])
        x, *_ = np.linalg.lstsq(A[use][:, :, cols].reshape(-1, cols.sum()), rhs[use].ravel(), rcond=None)
        p_WT, d = np.split(x, [3])  # the tracker position, the offsets of the measured targets
        offsets[known] = d.reshape(-1, 3)
        miss = np.linalg.norm(
            data.eta @ R_WT.T + p_WT - (o_WF + np.einsum("nij,nj->ni", R_WF, offsets[target])), axis=1
        )
        if k >= REGISTRATION_ROUNDS // 2:
            use = miss <= np.median(miss)
        if np.count_nonzero(use) < 3:
            break
    return miss


def check_fitted(
    result: EstimationResult, nominal: TrackerModel, data: Measurements, *, force: bool, warnings: list[str]
) -> None:
    """Refuse a fitted model whose robot parameters moved further than any geometric error
    (:data:`MAX_FITTED_SHARE` of the reach for lengths, :data:`MAX_FITTED_DEG` for angles; the
    tracker pose and the target offsets may move freely), naming the parameters and their joint.

    Raises:
        InputError: such a fit, unless ``force`` (then a warning).
    """
    lay = nominal.layout
    delta = result.model.p - nominal.p
    robot_side = np.zeros(lay.size, dtype=bool)
    robot_side[lay.joints] = True
    limit = np.where(lay.is_angle, np.deg2rad(MAX_FITTED_DEG), MAX_FITTED_SHARE * float(nominal.robot.reach))
    far = np.flatnonzero(robot_side & (np.abs(delta) > limit))
    if far.size == 0:
        return
    robot = nominal.robot
    moved = ", ".join(
        f"{lay.names[i]} [{joint_label(robot, parameter_joint(lay.names[i]))}] by "
        + (f"{np.rad2deg(delta[i]):+.3g} deg" if lay.is_angle[i] else f"{delta[i]:+.4g} mm")
        for i in far[:6]
    )
    _refuse(
        f"{data.source}: the fit moved {moved} from nominal: no geometric error of a real robot is that "
        f"large (limits {MAX_FITTED_SHARE:.0%} of the reach, {MAX_FITTED_DEG:g} deg); a wrong joint map (a "
        "coupling left out, a sign or offset), another robot or a wrong robot file",
        force,
        warnings,
    )
