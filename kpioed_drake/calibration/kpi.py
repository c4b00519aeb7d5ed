"""The KPI of a calibration and the working pose it is taken at.

The KPI is the TCP (reflector point) at the working pose ``q_work`` in W under KPI conditions (no
payload, reference temperature) with its covariance ``Cs = Js Cp Js^T`` (paper eq. 24e), ``Js``
the derivative of the TCP w.r.t. the estimated parameters: the free geometric ones and, for an
extended model, the effects' (:func:`kpioed_drake.effects.effect_kpi_columns`). With a 6-DoF probe's
orientations the TCP's orientation has a covariance too, ``Js_rot Cp Js_rot^T``
(:func:`orientation_covariance`, ``Js_rot`` the tool frame's angular Jacobian).
"""

from __future__ import annotations

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import EstimationResult
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.measurement import kpi_jacobian
from kpioed_drake.tracker.orientation import tcp_angular_jacobian


def working_pose(
    robot: Robot, q_work: np.ndarray | None = None, *, poses: np.ndarray | None = None
) -> tuple[np.ndarray, list[str]]:
    """(n_joints,) the working pose [rad]: ``q_work``, the model file's, or (a model file without
    one, e.g. a URDF with a two-line sidecar) the measured pose of ``poses`` (n, n_joints) nearest
    their mean, a pose the robot took; and a note saying so (empty otherwise).

    Raises:
        InputError: no working pose (and no poses), or one outside the joint limits.
    """
    note = []
    if q_work is None and robot.q_work is None and poses is not None and len(poses):
        q = np.asarray(poses, dtype=float)
        k = int(np.argmin(np.linalg.norm(q - q.mean(axis=0), axis=1)))
        q_work = q[k]
        note = [
            f"{robot.name}: the model file has no working pose (q_work); the KPI is the TCP at the "
            f"measured pose nearest the data's mean (row {k + 1}); give q_work_deg for your own"
        ]
    if q_work is None:
        if robot.q_work is None:
            raise InputError(
                f"{robot.name}: the model file has no working pose; pass q_work_deg", fields=("q_work_deg",)
            )
        q_work = robot.q_work
    q_work = np.asarray(q_work, dtype=float)
    if (
        q_work.shape != (robot.n_joints,)
        or np.any(q_work < robot.lower - 1e-9)
        or np.any(q_work > robot.upper + 1e-9)
    ):
        raise InputError(f"{robot.name}: q_work must be {robot.n_joints} angles within the joint limits")
    return q_work, note


def kpi_and_covariance(result: EstimationResult, q_work: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP at ``q_work`` in W of an estimation (effects included) and its covariance.

    Returns:
        s: (3,) [mm]; Cs: (3, 3) ``Js Cp Js^T`` [mm^2] (a priori, from the given sigma).
    """
    model, effects = result.model, list(result.effects)
    s, Js = kpi_jacobian(model, q_work)
    s = s + fx.effect_tcp_shift(model, q_work, effects)
    Je = np.concatenate([Js[:, result.free], fx.effect_kpi_columns(model, q_work, effects)], axis=1)
    return s, Je @ result.Cp @ Je.T


def orientation_covariance(result: EstimationResult, q_work: np.ndarray) -> np.ndarray:
    """(3, 3) the covariance of the TCP frame's orientation at ``q_work`` (small rotations in W)
    [rad^2], a priori from the given noise: ``Js_rot Cp Js_rot^T``
    (:func:`~kpioed_drake.tracker.orientation.tcp_angular_jacobian` over the estimated parameters).

    Raises:
        InputError: an extended fit (the effects' turning of the tool is not modelled).
    """
    if result.effects:
        raise InputError("the TCP's orientation with model extensions is not modelled", fields=("effects",))
    J = tcp_angular_jacobian(result.model, q_work)[:, result.free]
    return J @ result.Cp @ J.T
