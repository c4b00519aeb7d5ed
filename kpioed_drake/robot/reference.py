"""The geometry an extended model's effects are evaluated on: the model its calibration started from.

A fit evaluates the effects' gravity torques, mass-free bases and pivots on the nominal geometry
it starts from (they depend on the commanded poses only, so the residual function is the same for
every parameter value), while the joint rows move to their estimates. A calibrated model file holds
the estimated rows and, in ``estimated_errors``, the rows' errors against that start; the
reference is the file's geometry minus these errors. :func:`reference_of` rebuilds it, so that the
written model (:func:`kpioed_drake.tracker.measurement.nominal_model`) is the fit's model: the
reference robot with the estimated rows as parameters, and predicts exactly what the fit predicted.

A table robot's reference is its rows minus the errors; a URDF robot's has the errors folded out of
its joint placements (:mod:`kpioed_drake.robot.urdf.origins`), in the numpy chain and in the text
Drake parses for the gravity torques alike.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.urdf.origins import unfolded_chain, unfolded_text


@dataclasses.dataclass(frozen=True)
class Reference:
    """The model an extended model's calibration started from.

    Attributes:
        robot: the same robot with the reference geometry (a :class:`~kpioed_drake.robot.models.Robot`).
        geometry: (n_joints, per_joint) the model's joint rows in the reference's terms [rad, mm]
            (a table's estimated rows; a URDF chain's estimated errors): the parameters ``p``'s
            joint rows of the model the fit estimated.
    """

    robot: object
    geometry: np.ndarray


def estimated_errors(robot, rows, where: str) -> np.ndarray | None:
    """A model file's ``estimated_errors`` (file units: deg, mm) as (n_joints, per_joint) [rad, mm],
    or None for an empty field.

    Raises:
        InputError: ``where`` (the file) and the field: wrong shape or a non-finite value.
    """
    if not rows:
        return None
    shape = (robot.n_joints, robot.per_joint)
    try:
        arr = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(
            f"{where}: estimated_errors: expected {shape[0]} rows of {shape[1]} finite numbers (one row "
            "a joint, deg and mm, as a calibration writes them)",
            fields=("estimated_errors",),
        )
    angle = np.asarray(robot.param_is_angle(), dtype=bool).reshape(shape)
    return np.where(angle, np.deg2rad(arr), arr)


def file_rows(robot, errors: np.ndarray) -> list[list[float]]:
    """``errors`` (n_joints, per_joint) [rad, mm] in file units (deg, mm), for ``estimated_errors``."""
    angle = np.asarray(robot.param_is_angle(), dtype=bool).reshape(errors.shape)
    return np.where(angle, np.rad2deg(errors), errors).tolist()


def reference_of(robot) -> Reference | None:
    """The reference of a loaded extended model (None: a model without effects or without
    ``estimated_errors``, which is its own reference)."""
    errors = robot.estimated_errors
    if errors is None or not robot.effects:
        return None
    if robot.chain is None:
        ref = dataclasses.replace(robot, geometry=robot.geometry - errors, estimated_errors=None)
        return Reference(ref, np.array(robot.geometry, dtype=float))
    text = unfolded_text(robot.urdf.text, robot.urdf.joints, robot.chain, errors)
    urdf = dataclasses.replace(robot.urdf, text=text, unfolded=errors)
    ref = dataclasses.replace(
        robot,
        chain=unfolded_chain(robot.chain, errors),
        urdf=urdf,
        geometry=np.zeros_like(errors),
        estimated_errors=None,
    )
    return Reference(ref, np.array(errors, dtype=float))
