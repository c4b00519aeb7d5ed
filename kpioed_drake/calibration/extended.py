"""The effects of an extended calibration: parsed and sized for the robot and the data, and refused
where the data do not vary what identifies them.

:func:`resolve_extension` is what :func:`kpioed_drake.calibration.fit.calibrate` runs on its
``effects``: texts (joints 1..n_joints of the robot) or effects, each resolved for the nominal
model (a column's joint checked, a gravity basis sized for the payload of the data), and the
per-pose conditions the effects need (temperature, time, gravity torques with the payload).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.effects import lateral_basis
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.effects.gravity_basis import resolve_all, size_on_poses
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import Conditions, data_conditions
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel

_MIN_SIDE = 3
"""Poses needed on each side of a backlash (gravity torque positive and negative)."""


def resolve_extension(
    effects, nominal: TrackerModel, data: Measurements
) -> tuple[list, Conditions, TrackerModel]:
    """The effects to estimate with the geometry, and the conditions of the data they need.

    Args:
        effects: effect texts (e.g. ``"gear_cyclic:7:1"``) or :class:`~kpioed_drake.effects.Effect`.
        nominal: the nominal model (its robot's joint count bounds the joints).
        data: the measurements.

    Returns:
        (effects resolved for this robot and data, conditions, nominal): without effects the
        conditions hold only the rows' targets; ``nominal`` is the model given, its robot with the
        gravity bases sized on the data's poses where a ``joint_elasticity_basis`` is to be
        estimated (:func:`~kpioed_drake.effects.gravity_basis.size_on_poses`).

    Raises:
        InputError: a bad effect text, or data that do not vary what an effect needs.
    """
    if not effects:
        return [], Conditions(target=data.target), nominal
    robot = nominal.robot
    texts = [e for e in effects if not isinstance(e, fx.Effect)]
    parsed = iter(fx.parse_effects(texts, n_joints=robot.n_joints))
    given = [e if isinstance(e, fx.Effect) else next(parsed) for e in effects]
    keys = [e.key for e in given]
    for e in given:
        if keys.count(e.key) > 1:
            raise InputError(f"effect {e.name!r} given more than once", fields=("effects",))
    if any(e.family == BASIS_FAMILY and e.values is None for e in given):
        robot = size_on_poses(robot, data.q)[0]
    lateral = [e.joint for e in given if e.family == lateral_basis.FAMILY and e.values is None]
    if lateral:
        robot = lateral_basis.size_on_poses(robot, data.q, lateral)[0]
    robot = dataclasses.replace(robot, payload_point=nominal.p_FP)  # fixed for the fit and its file
    nominal = dataclasses.replace(nominal, robot=robot)
    resolved = resolve_all(
        [
            lateral_basis.resolve(e, robot, data.payload_kg, n_given=e.n_basis)  # refuses a varying payload
            if e.family == lateral_basis.FAMILY
            else fx.resolve(e, nominal)
            for e in given
        ],
        nominal,
        data.payload_kg,
    )
    conditions = data_conditions(robot, data, p_FP=nominal.p_FP)
    _check_conditions(resolved, data, conditions.tau)
    return resolved, conditions, nominal


def _check_conditions(effects, data: Measurements, tau: np.ndarray) -> None:
    """Refuse effects whose variable the data does not vary (their parameter would be arbitrary).

    ``tau``: (n, 6) gravity torques at the commanded angles [N m]; a backlash needs joint i's torque
    to take both signs at >= ``_MIN_SIDE`` poses each (else it is a constant offset: the joint's zero).
    """
    for e in effects:
        if e.family in ("thermal_expansion", "tracker_scale") and (
            data.temperature_C is None or np.ptp(data.temperature_C) <= 0.5
        ):
            raise InputError(
                f"{data.source}: {e.name} cannot be estimated: the temperature_C column is missing or varies "
                "by less than 0.5 K (a constant temperature only rescales lengths: the geometry absorbs it)"
            )
        if e.family == "backlash":
            side = np.sign(tau[:, e.joint - 1])
            if min(np.sum(side > 0), np.sum(side < 0)) < _MIN_SIDE:
                raise InputError(
                    f"{data.source}: {e.name} cannot be estimated: the gravity torque of joint {e.joint} "
                    f"must take both signs at {_MIN_SIDE} poses or more (else the backlash is a constant "
                    "offset that the joint's zero absorbs)"
                )
        if e.family == "tracker_drift" and (data.time_s is None or np.ptp(data.time_s) <= 0):
            raise InputError(
                f"{data.source}: {e.name} cannot be estimated: the time_s column is missing or constant"
            )
