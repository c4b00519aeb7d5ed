"""Plausibility of measured data before a calibration or a diagnosis: refuse what cannot be right.

A fit always returns numbers; these checks make sure they mean something. Run before any fit, on
the nominal model with only the tracker frame registered (a rigid 6-DoF fit, no robot parameter
moved: :func:`kpioed_drake.estimation.estimator.register_tracker`):

- **degrees of freedom**: ``3 n`` coordinates must exceed the parameters, or no goodness of fit
  (and no covariance worth the name) exists;
- **units**: measured points spanning a hundredth (or a hundred times) of what the robot's poses
  span are lengths in metres (or micrometres), not millimetres;
- **gross errors**: after registering on the better half of the poses, a pose missing the nominal
  model by more than :data:`MAX_GEOMETRIC_MM` is no geometric error; more than a third of such
  rows is refused;
- **another robot or a wrong joint map**: an RMS miss of the better half above
  :data:`MAX_GEOMETRIC_MM` (the data of another robot, wrong joint signs, offsets or angle units).

Each check raises :class:`~kpioed_drake.errors.InputError` (exit status 2) saying what looks
wrong, unless ``force=True``, which turns it into a warning.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import register_tracker
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel, reflector_world

MAX_GEOMETRIC_MM = 25.0
"""Largest miss [mm] of the registered nominal model that geometric errors can explain. An
industrial robot's uncalibrated absolute error is a few millimetres (SPEC's error sizes give about
1 mm; the UR5 data set of the README 2.6 mm mean); 25 mm leaves a wide margin."""

UNIT_RATIO = 100.0
"""Span ratio (measured / nominal points) beyond which the lengths are in other units."""

MAX_GROSS_FRACTION = 1.0 / 3.0
"""Largest fraction of poses with gross errors (beyond :data:`MAX_GEOMETRIC_MM`) that is accepted."""


def _refuse(message: str, force: bool, warnings: list[str]) -> None:
    if not force:
        raise InputError(f"{message} (use force to go on anyway)", fields=("force",))
    warnings.append(f"forced: {message}")


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
            f"{where}: {n} poses give {3 * n} coordinates for {n_params} parameters: no degree of freedom "
            f"is left to test the fit; at least {n_params // 3 + 1} poses are needed"
        )
    warnings: list[str] = []
    p_W = reflector_world(model, data.q, data.target)
    span_model = float(np.max(np.ptp(p_W, axis=0)))
    span_data = float(np.max(np.ptp(data.eta, axis=0)))
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
    miss = _registered_miss(p_W, data.eta)
    good = miss <= MAX_GEOMETRIC_MM
    rows = data.rows[~good]
    if rows.size > MAX_GROSS_FRACTION * n:
        _refuse(
            f"{where}: {rows.size} of {n} poses miss the nominal model by more than {MAX_GEOMETRIC_MM:g} mm "
            f"after registering the tracker (rows {', '.join(map(str, rows[:8]))}"
            f"{', ...' if rows.size > 8 else ''}): more than a third are gross errors, which is no "
            "calibration data; check the file, the joint map and the units",
            force,
            warnings,
        )
        return warnings
    rms = float(np.sqrt(np.mean(np.sort(miss)[: max(3, n // 2)] ** 2)))
    if rms > MAX_GEOMETRIC_MM:
        _refuse(
            f"{where}: after registering the tracker frame the nominal model misses the better half of "
            f"the poses by {rms:.4g} mm RMS, more than geometric errors explain ({MAX_GEOMETRIC_MM:g} mm): "
            "data of another robot, a wrong joint map (signs, offsets, degrees vs radians) or other units",
            force,
            warnings,
        )
    return warnings


def _registered_miss(p_W: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """(n,) distance [mm] of each pose after registering on all, then on the better half."""
    use = np.ones(len(p_W), dtype=bool)
    for _ in range(2):
        R_WT, p_WT = register_tracker(p_W[use], eta[use])
        miss = np.linalg.norm(eta @ R_WT.T + p_WT - p_W, axis=1)
        use = miss <= np.median(miss)
        if np.count_nonzero(use) < 3:
            break
    return miss
