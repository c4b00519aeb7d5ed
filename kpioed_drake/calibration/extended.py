"""The effects of an extended calibration: parsed and sized for the robot and the data, refused
where the data do not vary what identifies them, and dropped (with a warning naming them and what
they trade against) where the fit's Jacobian cannot tell them from the geometry or from each other.

:func:`resolve_extension` is what :func:`kpioed_drake.calibration.fit.calibrate` runs on its
``effects``: texts (joints 1..n_joints of the robot) or effects, each resolved for the nominal
model (a column's joint checked, a gravity basis sized for the payload of the data), and the
per-pose conditions the effects need (temperature, time, gravity torques with the payload).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.effects import lateral_basis
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.effects.gravity_basis import resolve_all, size_on_poses
from kpioed_drake.effects.model import Effect
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import Conditions, data_conditions
from kpioed_drake.estimation.identifiability import trades_against, undetermined_parameters
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel

_MIN_SIDE = 3
"""Poses needed on each side of a backlash (gravity torque positive and negative)."""


def resolve_extension(
    effects: Sequence[str | Effect], nominal: TrackerModel, data: Measurements
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


@dataclasses.dataclass(frozen=True)
class UndeterminedEffect:
    """An effect the poses cannot determine beside the geometry and the effects kept before it.

    Attributes:
        effect: the effect.
        partners: what it trades against (geometric parameters or effects, strongest first).
        share: the share of its signature within their span (1: a combination of them).
        silent: its columns are zero at these poses (it changes no measurement).
    """

    effect: fx.Effect
    partners: tuple[str, ...]
    share: float
    silent: bool = False

    def text(self) -> str:
        if self.silent:
            return f"{self.effect.name} (it changes no measurement at these poses)"
        within = f"{100 * self.share:.1f} % of its signature lies within " if self.share < 0.9995 else ""
        what = ", ".join(self.partners) or "its own columns (they do not separate from each other)"
        return f"{self.effect.name} (it trades against {within}{what})"


def undetermined_effects(
    J: np.ndarray, free_names: Sequence[str], held: Sequence[str], effects: Sequence[Effect]
) -> list[UndeterminedEffect]:
    """The effects a fit's weighted Jacobian does not determine beside the geometry.

    The effects are taken in their order: each is tested (:func:`undetermined_parameters`, the
    geometric parameters' test) with the geometric parameters not in ``held`` and the effects kept
    before it; one that leaves any column undetermined is not determined: the geometry is the base
    model, an effect it cannot tell from the geometry (or from an effect before it) adds nothing.

    Args:
        J: (3m, n_free + k) the fit's weighted Jacobian (geometric columns, then the effects').
        free_names: (n_free,) the geometric parameters' names.
        held: geometric names the geometric test holds (left out of the comparison).
        effects: the fit's effects, in the order of their columns.

    Returns:
        One :class:`UndeterminedEffect` per effect not determined (empty: all determined).
    """
    n_free = len(free_names)
    keep = [i for i, name in enumerate(free_names) if name not in set(held)]
    owners = [free_names[i] for i in keep]
    out, c = [], n_free
    for e in effects:
        cols = list(range(c, c + e.n_params))
        c += e.n_params
        norms = np.linalg.norm(J[:, cols], axis=0)
        if np.all(norms <= 1e-9 * max(float(np.linalg.norm(J, axis=0).max(initial=0.0)), 1e-300)):
            out.append(UndeterminedEffect(e, (), 1.0, silent=True))
            continue
        names = [*owners, *e.param_names]
        if undetermined_parameters(J[:, keep + cols], names).names:
            partners, share = trades_against(J[:, keep], owners, J[:, cols])
            out.append(UndeterminedEffect(e, tuple(partners), share))
            continue
        keep += cols
        owners += [e.name] * e.n_params
    return out
