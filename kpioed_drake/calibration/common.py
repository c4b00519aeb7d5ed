"""What the geometric and the extended calibration share: the options of a calibration
(:class:`CalibrationOptions`), the inputs of a command on a data file loaded once
(:func:`read_inputs`), the working pose and the KPI.

The KPI is the TCP (reflector point) at the working pose ``q_work`` in W under KPI conditions (no
payload, reference temperature) with its covariance ``Cs = Js Cp Js^T`` (paper eq. 24e), ``Js``
the derivative of the TCP w.r.t. the estimated parameters: the free geometric ones and, for an
extended model, the effects' (:func:`kpioed_drake.effects.effect_kpi_columns`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.arguments import check_paths, require
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation.estimator import EstimationResult
from kpioed_drake.robot.models import Cell, Robot, load_cell, load_robot
from kpioed_drake.robot.urdf.write import check_out_path, sidecar_of
from kpioed_drake.tracker.data import Measurements, read_data
from kpioed_drake.tracker.measurement import kpi_jacobian


@dataclasses.dataclass(frozen=True)
class CalibrationOptions:
    """The settings of one calibration (:func:`~kpioed_drake.calibration.fit.calibrate`); read from
    YAML with :func:`kpioed_drake.options.load_options`."""

    sigma_mm: float = 0.02
    """Noise standard deviation per coordinate [mm]: the weight of the fit, its goodness-of-fit test
    and the a-priori covariance."""
    effects: tuple[str, ...] = ()
    """Non-geometric effects estimated with the geometry (texts such as ``joint_elasticity:2``,
    joints 1..n_joints, or :class:`~kpioed_drake.effects.Effect` objects; their starting values the
    given ones, 0 when unknown): the extended model."""
    outlier_alpha: float = 0.01
    """Family-wise false-alarm level of the outlier test (Bonferroni: each pose at alpha / n), in
    [0, 1); 0: no test."""
    max_outlier_fraction: float = 0.1
    """The outlier test removes at most this fraction of the poses."""
    max_iter: int = 100
    """Most Levenberg-Marquardt iterations of one fit."""
    force: bool = False
    """Go on with implausible data (:func:`kpioed_drake.estimation.plausibility.check_data`), with a
    warning."""
    strict: bool = False
    """Refuse poses that do not determine every free parameter instead of holding the undetermined
    ones at nominal with a warning."""

    def __post_init__(self):
        check_sigma(self.sigma_mm)
        a = self.outlier_alpha
        ok = isinstance(a, int | float) and not isinstance(a, bool) and 0 <= a < 1
        require(ok, f"outlier_alpha: expected a number in [0, 1), got {a!r}", fields=("outlier_alpha",))
        f = self.max_outlier_fraction
        ok = isinstance(f, int | float) and 0 <= f < 1
        what = f"max_outlier_fraction: expected a number in [0, 1), got {f!r}"
        require(ok, what, fields=("max_outlier_fraction",))
        require(
            isinstance(self.max_iter, int) and self.max_iter >= 1,
            f"max_iter: expected a positive integer, got {self.max_iter!r}",
            fields=("max_iter",),
        )
        if isinstance(self.effects, str):
            object.__setattr__(self, "effects", (self.effects,))
        object.__setattr__(self, "effects", tuple(self.effects or ()))


def working_pose(robot: Robot, q_work=None, *, poses=None) -> tuple[np.ndarray, list[str]]:
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


def kpi_and_covariance(result: EstimationResult, q_work) -> tuple[np.ndarray, np.ndarray]:
    """TCP at ``q_work`` in W of an estimation (effects included) and its covariance.

    Returns:
        s: (3,) [mm]; Cs: (3, 3) ``Js Cp Js^T`` [mm^2] (a priori, from the given sigma).
    """
    model, effects = result.model, list(result.effects)
    s, Js = kpi_jacobian(model, q_work)
    s = s + fx.effect_tcp_shift(model, q_work, effects)
    Je = np.concatenate([Js[:, result.free], fx.effect_kpi_columns(model, q_work, effects)], axis=1)
    return s, Je @ result.Cp @ Je.T


def read_inputs(
    robot: str | Path,
    data_path: str | Path,
    data_format: str | Path | None = None,
    *,
    cell_path=None,
    model_out=None,
    outputs=(),
    folders=(),
    html=None,
) -> tuple[Robot, Cell, Measurements]:
    """The robot, cell and measurements of a command on a data file, each loaded once, after the
    paths are checked (:func:`~kpioed_drake.arguments.check_paths`).

    Args:
        model_out: a model file to write (a ``.urdf`` brings its sidecar; it must suit the robot).
        outputs, folders, html: the command's other output files, output folders and 3-D page.

    Returns:
        (robot, cell, data).

    Raises:
        InputError: a bad path, robot, cell or data file.
    """
    side = sidecar_of(model_out) if model_out is not None and Path(str(model_out)).suffix == ".urdf" else None
    check_paths(
        robot=robot,
        inputs=[data_path, data_format],
        outputs=[model_out, side, *outputs],
        folders=list(folders),
        html=html,
    )
    rob = load_robot(robot)
    check_out_path(rob, model_out)
    return rob, load_cell(cell_path, robot=rob), read_data(data_path, rob, data_format)
