"""The identification problem of one robot in one cell: F1, Js, Cp, Cs for a set of poses.

Bundles the robot, the cell, the nominal measurement model, the working pose and the noise, and
evaluates paper eqs. (19), (24c)-(24e) for a design: ``F1 = dh/dp / sigma`` over the 27 estimated
parameters (rows pose-major: x, y, z of pose 1, then pose 2, ...), ``Js = dTCP/dp`` at ``q_work``,
``Cp = (F1^T F1)^-1`` and ``Cs = Js Cp Js^T``.

Several KPIs (paper, Outlook: further working poses, or a working path sampled at K points): with
working poses ``q_work_k`` (K, 6) and weights ``w_k`` (sum 1), the KPI is the weighted mean of the
variances ``v_k = tr(Js_k Cp Js_k^T)/3`` or the worst one (``kpi_aggregate``). The weighted mean
equals ``tr(Js Cp Js^T)/3`` of the stacked rows ``Js = [sqrt(w_1) Js_1; ...; sqrt(w_K) Js_K]``
(3K, k), so :meth:`Problem.Js` returns that stack and every KPI criterion works on it unchanged;
with K = 1 it is the single (3, k) Jacobian and every number is that of one working pose.

Several targets (the robot file's ``targets_mm``): a pose measures all T of them, so its rows in
F1 are the stacked rows of its targets (3T rows: target 1's x, y, z, then target 2's, ...).

Pose measurements (``measure == "pose"``, a 6-DoF probe, :mod:`kpioed_drake.tracker.orientation`): a
pose has 6 rows, its 3 position rows / ``sigma`` then its 3 orientation rows ``Omega / sigma_rot``
(the orientation residual's Jacobian at the nominal model, where the residual is 0), and the probe's
three rotations on the flange are estimated too. The TCP's orientation joins the KPI with
``kpi_orientation_mm = L`` > 0: each working pose's rows are ``[Js; L Js_rot]`` (6, k), ``Js_rot``
the TCP frame's angular Jacobian [rad per unit], so that tr(Cs)/3 = ``v_pos + L^2 v_rot``: the
orientation counts as the displacement ``L * angle`` it makes at L mm from the TCP (every KPI
criterion, the approximate design and the certificate work on that stack unchanged).
:meth:`Problem.tcp_variances` gives the two parts apart, the orientation in deg^2.

Model extensions (non-geometric effects of :mod:`kpioed_drake.effects`, e.g. joint elasticity)
add parameters: their measurement columns are appended to F1 (and to dF1/dq) and their TCP
columns to Js, so that a design for the extended model estimates them too and its KPI variance
includes them (paper outlook; SPEC "Measured data and model discrepancy").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import scipy.linalg

from kpioed_drake.effects import (
    JOINT_FAMILIES,
    ROTATION_FAMILIES,
    effect_kpi_columns,
    extension_columns,
    extension_param_names,
    model_effects,
    parse_effect,
    resolve,
)
from kpioed_drake.effects.model import Effect
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation import covariance
from kpioed_drake.robot.kinematics import Frames
from kpioed_drake.robot.models import Cell, Robot, load_robot
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.tracker import kpi as inputs
from kpioed_drake.tracker.measurement import TrackerModel, kpi_jacobian, measurement_jacobian, nominal_model
from kpioed_drake.tracker.orientation import (
    angular_jacobian,
    angular_jacobian_dq,
    tcp_angular_jacobian,
    with_probe,
)

PARAM_SCALINGS = ("reach", "none")
"""Scalings of the standard criterion phi_A(Cp): SPEC's (angles times the reach) or none (the
paper's eq. 25 with the identity, angles in radians)."""


@dataclasses.dataclass(frozen=True)
class Problem:
    """Everything the covariance of a design depends on.

    Attributes:
        robot, cell: the models (cell as loaded for this robot).
        model: measurement model at the parameter values the design is evaluated at.
        q_work: (6,) working configuration [rad]; several KPIs: (K, 6) working poses (or the
            K samples of a working path) [rad].
        sigma: noise standard deviation per coordinate [mm].
        tool_offset: (3,) TCP relative to the reflector, flange axes [mm].
        extensions: model extensions (:mod:`kpioed_drake.effects`) whose parameters are estimated
            too: their columns follow the 27 geometric ones in ``F1`` and ``Js``.
        kpi_weights: (K,) weights of the working poses, positive, summing to 1 (None: one working
            pose, or equal weights).
        kpi_aggregate: how the K variances make the KPI: ``mean`` (weighted mean) or ``max`` (the
            worst working pose). Only the ``kpi`` criterion depends on it.
        param_scaling: scaling of the standard criterion's geometric parameters: ``reach`` (SPEC:
            lengths 1, angles times the reach) or ``none`` (all 1). Only ``param_crit`` depends on it.
        kpi_point: ``reflector`` (the reflector point plus ``tool_offset``) or ``flange`` (the
            flange origin, frame k of the paper: its position does not depend on the reflector
            offset, whose Js columns are then zero).
        measure: ``point`` (3 rows per pose) or ``pose`` (6: with the probe's orientation).
        sigma_rot: the orientation's noise per tracker axis [rad] (``pose`` only).
        kpi_orientation_mm: L [mm] >= 0: the TCP's orientation counts in the KPI as ``L * angle``
            (0: position only).
    """

    robot: Robot
    cell: Cell
    model: TrackerModel
    q_work: np.ndarray
    sigma: float
    tool_offset: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    extensions: tuple = ()
    kpi_weights: np.ndarray | None = None
    kpi_aggregate: str = "mean"
    param_scaling: str = "reach"
    kpi_point: str = "reflector"
    measure: str = "point"
    sigma_rot: float | None = None
    kpi_orientation_mm: float = 0.0

    @property
    def q_works(self) -> np.ndarray:
        """(K, 6) the working poses [rad] (K = 1 for one working pose)."""
        return np.atleast_2d(self.q_work)

    @property
    def n_kpis(self) -> int:
        """K, the number of working poses whose TCP variance makes the KPI."""
        return self.q_works.shape[0]

    @property
    def weights(self) -> np.ndarray:
        """(K,) weights of the working poses (sum 1)."""
        if self.kpi_weights is None:
            return np.full(self.n_kpis, 1.0 / self.n_kpis)
        return np.asarray(self.kpi_weights, dtype=float)

    @property
    def worst_case(self) -> bool:
        """The KPI is the largest of several variances (``kpi_aggregate == "max"`` and K > 1)."""
        return self.kpi_aggregate == "max" and self.n_kpis > 1

    @property
    def free(self) -> np.ndarray:
        return self.model.layout.free

    @property
    def n_params(self) -> int:
        """Estimated parameters: 27 geometric plus those of the extensions."""
        return self.model.layout.n_free + sum(e.n_params for e in self.extensions)

    @property
    def param_names(self) -> list[str]:
        return self.model.layout.free_names + extension_param_names(self.extensions)

    @property
    def scale(self) -> np.ndarray:
        """(k,) scaling of the standard criterion to millimetres at the tool.

        SPEC: lengths 1, angles times the reach (``param_scaling == "none"``: all 1). An extension
        parameter is scaled by how far one unit of it moves the TCP at ``q_work`` (its KPI column's
        norm; several working poses: the norm of its weighted stack, the root mean square over
        them) [mm per unit].
        """
        geo = self.model.layout.scale(self.robot.reach)
        if self.param_scaling == "none":
            geo = np.ones_like(geo)
        if not self.extensions:
            return geo
        ext = np.linalg.norm(self.Js()[:, self.model.layout.n_free :], axis=0)
        return np.concatenate([geo, np.where(ext > 0, ext, 1.0)])

    def _stack(self, blocks) -> np.ndarray:
        """Rows ``sqrt(w_k) B_k`` of K blocks B_k (3, c), stacked to (3K, c)."""
        return np.concatenate([np.sqrt(w) * B for w, B in zip(self.weights, blocks, strict=True)], axis=0)

    @property
    def n_targets(self) -> int:
        """Targets every pose measures (T; 1: the reflector)."""
        return self.model.layout.n_targets

    @property
    def rows_per_pose(self) -> int:
        """Rows of F1 per pose: 3 per target, or 6 (position and orientation) with ``pose``."""
        return 6 if self.measure == "pose" else 3 * self.n_targets

    def min_poses(self) -> int:
        """Fewest poses whose rows (:attr:`rows_per_pose`) can determine the parameters."""
        return int(np.ceil(self.n_params / self.rows_per_pose))

    def F1(
        self, q: np.ndarray, *, with_dq: bool = False, frames: Frames | None = None
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Weighted identification Jacobian (3n, 27); with ``with_dq`` also (n, 6, 3, 27).

        ``frames``: ``self.model.frames(q)`` if the caller has it already. With T targets every
        pose has 3T rows (its targets' rows stacked): (3Tn, k) and (n, 6, 3T, k); with ``pose``
        6 rows (x, y, z / sigma, then the 3 orientation rows / sigma_rot): (6n, k), (n, 6, 6, k).
        """
        if self.measure == "pose":
            return self._F1_pose(np.atleast_2d(q), with_dq, frames)
        if self.n_targets > 1:
            return self._F1_targets(np.atleast_2d(q), with_dq, frames)
        out = measurement_jacobian(self.model, q, with_dq=with_dq, frames=frames)
        H = out[1][:, :, self.free] / self.sigma
        dH = out[2][..., self.free] / self.sigma if with_dq else None
        if self.extensions:
            ext = extension_columns(self.model, q, self.extensions, with_dq=with_dq)
            E, dE = (ext[0], ext[1]) if with_dq else (ext, None)
            H = np.concatenate([H, E / self.sigma], axis=2)
            if with_dq:
                dH = np.concatenate([dH, dE / self.sigma], axis=3)
        n = H.shape[0]
        if not with_dq:
            return H.reshape(3 * n, -1)
        return H.reshape(3 * n, -1), dH

    def _F1_targets(self, q: np.ndarray, with_dq: bool, frames=None):
        """:meth:`F1` of T > 1 targets: every pose measured at each target (with the extensions'
        columns of each target's rows); one forward kinematics of the n poses, repeated."""
        n, T, nj = q.shape[0], self.n_targets, self.model.layout.n_joints
        target = np.tile(np.arange(T), n)
        qq = np.repeat(q, T, axis=0)
        frames = (self.model.frames(q) if frames is None else frames).repeated(T)
        out = measurement_jacobian(self.model, qq, with_dq=with_dq, frames=frames, target=target)
        H = out[1][:, :, self.free] / self.sigma  # (nT, 3, k)
        dH = out[2][..., self.free] / self.sigma if with_dq else None  # (nT, 6, 3, k)
        if self.extensions:
            ext = extension_columns(self.model, qq, self.extensions, with_dq=with_dq, target=target)
            E, dE = (ext[0], ext[1]) if with_dq else (ext, None)
            H = np.concatenate([H, E / self.sigma], axis=2)
            if with_dq:
                dH = np.concatenate([dH, dE / self.sigma], axis=3)
        F = H.reshape(3 * T * n, -1)
        if not with_dq:
            return F
        dH = dH.reshape(n, T, nj, 3, -1).transpose(0, 2, 1, 3, 4).reshape(n, nj, 3 * T, -1)
        return F, dH

    def _F1_pose(self, q: np.ndarray, with_dq: bool, frames=None):
        """:meth:`F1` of pose measurements: each pose's 3 position rows, then its 3 orientation rows."""
        frames = self.model.frames(q) if frames is None else frames
        out = measurement_jacobian(self.model, q, with_dq=with_dq, frames=frames)
        rot = angular_jacobian(self.model, q, frames=frames)[:, :, self.free] / self.sigma_rot
        F = np.concatenate([out[1][:, :, self.free] / self.sigma, rot], axis=1)  # (n, 6, k)
        if not with_dq:
            return F.reshape(6 * q.shape[0], -1)
        d_rot = angular_jacobian_dq(self.model, q, frames=frames)[..., self.free] / self.sigma_rot
        return F.reshape(6 * q.shape[0], -1), np.concatenate(
            [out[2][..., self.free] / self.sigma, d_rot], axis=2
        )

    def Js_orientation_each(self) -> np.ndarray:
        """(K, 3, k) the TCP frame's angular Jacobian at each working pose [rad per parameter unit]
        (:func:`~kpioed_drake.tracker.orientation.tcp_angular_jacobian`; ValueError with
        extensions, whose turning of the tool is not modelled)."""
        if self.extensions:
            raise ValueError("the TCP's orientation with model extensions is not modelled")
        return np.stack([tcp_angular_jacobian(self.model, qw)[:, self.free] for qw in self.q_works])

    def Js_each(self) -> np.ndarray:
        """(K, r, k) KPI Jacobian at each working pose: ``dTCP/dp`` (r = 3) [mm per parameter
        unit], with ``kpi_orientation_mm`` L > 0 followed by ``L Js_rot`` (r = 6)."""
        Js = self._Js_position_each()
        if self.kpi_orientation_mm > 0:
            return np.concatenate([Js, self.kpi_orientation_mm * self.Js_orientation_each()], axis=1)
        return Js

    def _Js_position_each(self) -> np.ndarray:
        """(K, 3, k) KPI Jacobian ``dTCP/dp`` at each working pose [mm per parameter unit]."""
        flange = self.kpi_point == "flange"
        offset = -self.model.p_FQ if flange else self.tool_offset
        out = []
        for qw in self.q_works:
            _, Js = kpi_jacobian(self.model, qw, offset)
            if flange:
                Js[:, self.model.layout.target(0)] = 0.0
            Js = Js[:, self.free]
            if self.extensions:
                ext = effect_kpi_columns(self.model, qw, self.extensions, tool_offset=offset)
                Js = np.concatenate([Js, ext], axis=1)
            out.append(Js)
        return np.stack(out)

    def Js(self) -> np.ndarray:
        """KPI Jacobian: (r, k) at ``q_work`` (r = 3, or 6 with the orientation); several working
        poses: the stack (rK, k) of ``sqrt(w_k) Js_k``, whose ``tr(Js Cp Js^T)/3`` is the weighted
        mean of the K variances."""
        Js = self.Js_each()
        return Js[0] if self.n_kpis == 1 else self._stack(Js)

    def covariances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Cp`` (27, 27) and ``Cs = Js Cp Js^T`` (3, 3) [mm^2] of a design ``q`` (n, 6) [rad]
        (several working poses: (3K, 3K) of the weighted stack :meth:`Js`, trace/3 = the mean KPI).

        Raises:
            InputError: if the design does not determine all parameters.
        """
        try:
            return covariance.kpi_covariance(self.F1(q), self.Js())
        except np.linalg.LinAlgError:
            raise InputError(
                f"the {len(np.atleast_2d(q))} poses do not determine the {self.n_params} parameters "
                "(information matrix singular); use more or more varied poses"
            ) from None

    def kpi_variances(self, q: np.ndarray) -> np.ndarray:
        """(K,) ``tr(Cs_k)/3`` [mm^2] at each working pose of a design ``q`` (n, 6) [rad].

        Raises:
            InputError: if the design does not determine all parameters.
        """
        Cp, _ = self.covariances(q)
        return np.array([float(np.sum(J * (J @ Cp))) / 3.0 for J in self.Js_each()])

    def tcp_variances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K,) the TCP position's variance tr(C_pos,k)/3 [mm^2] and (K,) its orientation's
        tr(C_rot,k)/3 [deg^2] (per axis; NaN with extensions) at each working pose of a design
        ``q`` (n, 6) [rad].

        Raises:
            InputError: if the design does not determine all parameters.
        """
        Cp, _ = self.covariances(q)
        pos = np.array([float(np.sum(J * (J @ Cp))) / 3.0 for J in self._Js_position_each()])
        if self.extensions:
            return pos, np.full(pos.shape, np.nan)
        rot = np.array([float(np.sum(J * (J @ Cp))) / 3.0 for J in self.Js_orientation_each()])
        return pos, rot * np.rad2deg(1.0) ** 2

    def criteria(self, q: np.ndarray) -> dict[str, float]:
        """``kpi_avg_var_mm2`` and ``param_crit`` (scaled tr(Cp) [mm^2]) of a design.

        ``kpi_avg_var_mm2`` is tr(Cs)/3 [mm^2]; with several working poses the KPI: the weighted
        mean of their tr(Cs_k)/3, or with ``kpi_aggregate == "max"`` the largest.
        """
        Cp, Cs = self.covariances(q)
        kpi = float(np.max(self.kpi_variances(q))) if self.worst_case else float(np.trace(Cs) / 3.0)
        return {
            "kpi_avg_var_mm2": kpi,
            "param_crit": float(np.sum(np.diag(Cp) * self.scale**2)),
        }


def make_problem(
    robot: str | Robot,
    *,
    cell_path: Path | str | None = None,
    q_work: np.ndarray | None = None,
    sigma_mm: float | None = None,
    tool_offset_mm: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    extend: Sequence[str | Effect] = (),
    kpi_weights: Sequence[float] | np.ndarray | None = None,
    kpi_aggregate: str = "mean",
    fixed: tuple[str, ...] | None = None,
    max_incidence_deg: float | None = None,
    param_scaling: str = "reach",
    kpi_point: str = "reflector",
    measure: str = "point",
    sigma_deg: float | None = None,
    kpi_orientation_mm: float = 0.0,
) -> Problem:
    """Build the :class:`Problem` of a robot (name, file path or :class:`Robot`).

    Args:
        q_work: (6,) [rad]; several KPIs: (K, 6) working poses or samples of a working path [rad];
            default: the model file's ``q_work_deg``.
        sigma_mm: noise per coordinate [mm]; default: the cell's ``noise_sigma_mm``.
        extend: model extensions, e.g. ``["joint_elasticity:2", "gear_cyclic:4:2"]`` (texts of
            :func:`kpioed_drake.effects.parse_effect`, values not needed). Only effects that do not
            need per-pose temperature or time (elasticity, gear errors) can extend a design. An
            extended model file (``effects:``) adds its joint-angle effects and compliances (with
            their values) to these.
        kpi_weights: (K,) positive weights of the working poses, normalised to sum 1 (default:
            equal). Not allowed with ``kpi_aggregate="max"`` unless equal.
        kpi_aggregate: ``mean`` (weighted mean of the K variances tr(Cs_k)/3) or ``max`` (the
            largest).
        fixed: the parameters held at their nominal values (default: SPEC's gauge,
            :data:`~kpioed_drake.robot.parameters.FIXED_NAMES`); the others are estimated.
        max_incidence_deg: largest admitted incidence angle from the reflector's axis [deg]
            (default: the cell's); the optimiser, the heuristic and the checker use it.
        param_scaling: scaling of the standard criterion, one of :data:`PARAM_SCALINGS`.
        kpi_point: ``reflector`` or ``flange`` (:mod:`kpioed_drake.tracker.kpi`); ``flange``
            takes no ``tool_offset_mm``.
        measure: ``point`` or ``pose`` (a 6-DoF probe: the orientation rows and the probe's three
            rotations (the model file's ``probe_rpy_deg`` or the identity as
            reference); one target, no extensions).
        sigma_deg: ``pose``: the orientation's noise per tracker axis [deg] (default
            :data:`~kpioed_drake.tracker.kpi.SIGMA_ROT_DEG`).
        kpi_orientation_mm: L [mm] >= 0: the KPI is tr(Cs)/3 of the TCP's position and, weighted
            by L, its orientation (``v_pos + L^2 v_rot``; 0: position only).

    Raises:
        InputError: q_work outside the joint limits or of a bad shape, bad weights or aggregate,
            bad sigma or extensions, unknown fixed names, an incidence limit outside (0, 90) deg,
            an unknown scaling or KPI point, a tool offset with the flange as KPI point, a bad
            measurement choice (:func:`~kpioed_drake.tracker.kpi.check_measure`).
    """
    robot = load_robot(robot) if isinstance(robot, str) else robot
    cell = inputs.checked_cell(robot, cell_path, max_incidence_deg)
    _check_scaling(param_scaling)
    inputs.check_kpi_point(kpi_point, tool_offset_mm)
    q_work = inputs.checked_q_work(robot, q_work)
    weights = inputs.kpi_weights_checked(kpi_weights, len(np.atleast_2d(q_work)), kpi_aggregate)
    sigma = cell.sigma if sigma_mm is None else check_sigma(sigma_mm)
    # a design is made at the robot's own (an extended model file's calibrated) geometry, the one the
    # feasibility checker's plant has; the reference of robot/reference.py reproduces a fit only
    robot = dataclasses.replace(robot, estimated_errors=None) if robot.reference is not None else robot
    model = nominal_model(robot, cell)
    exts = _parse_extensions(extend, model)
    exts += tuple(e for e in _file_extensions(robot) if all(o.key != e.key for o in exts))
    if fixed is not None:
        try:
            model = dataclasses.replace(model, layout=parameter_layout(robot, fixed=tuple(fixed)))
        except ValueError as exc:
            raise InputError(f"{robot.name}: {exc}") from None
    sigma_rot = inputs.check_measure(
        measure, sigma_deg, kpi_orientation_mm, n_targets=model.layout.n_targets, n_effects=len(exts)
    )
    if measure == "pose":
        model = with_probe(model)
    return _separable(
        Problem(
            extensions=tuple(resolve(e, model) for e in exts),  # joint_elasticity_basis: sized per robot
            robot=robot,
            cell=cell,
            model=model,
            q_work=q_work,
            sigma=sigma,
            tool_offset=np.asarray(tool_offset_mm, dtype=float),
            kpi_weights=weights,
            kpi_aggregate=kpi_aggregate,
            param_scaling=param_scaling,
            kpi_point=kpi_point,
            measure=measure,
            sigma_rot=sigma_rot,
            kpi_orientation_mm=float(kpi_orientation_mm),
        )
    )


def _check_scaling(param_scaling: str) -> None:
    """InputError for an unknown scaling of the standard criterion."""
    if param_scaling not in PARAM_SCALINGS:
        raise InputError(f"param_scaling must be one of {', '.join(PARAM_SCALINGS)}, got {param_scaling!r}")


SEPARABLE_POSES = 300
"""Seeded joint-box poses on which an extended problem's parameters must all be determined."""


def _separable(problem: Problem) -> Problem:
    """``problem``, checked: with extensions, every parameter is determined by some poses (the
    identification Jacobian of :data:`SEPARABLE_POSES` joint-box poses has full column rank).

    Raises:
        InputError: naming the extension parameters no poses tell apart from the others.
    """
    if not problem.extensions:
        return problem
    rng = np.random.default_rng(20170710)
    q = rng.uniform(problem.robot.lower, problem.robot.upper, size=(SEPARABLE_POSES, problem.robot.n_joints))
    F = problem.F1(q)
    norms = np.linalg.norm(F, axis=0)
    _, R, piv = scipy.linalg.qr(F / np.where(norms > 0, norms, 1.0), mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-9 * d[0]))
    if rank == F.shape[1]:
        return problem
    names = problem.param_names
    bad = [names[i] for i in sorted(piv[rank:])]
    raise InputError(
        f"extend: {', '.join(bad)} cannot be told apart from the other parameters at any poses of the "
        "joint box (an effect the geometry or another effect already reproduces)",
        fields=("extend",),
    )


def _file_extensions(robot: Robot) -> tuple:
    """The effects of an extended model file that a design can carry (joint-angle effects and
    compliances; the others need per-pose temperature or time)."""
    return tuple(e for e in model_effects(robot) if e.family in JOINT_FAMILIES + ROTATION_FAMILIES)


def _parse_extensions(extend, model: TrackerModel | None = None) -> tuple:
    if not extend:
        return ()
    out = []
    for e in extend:
        eff = parse_effect(e, model=model) if isinstance(e, str) else e
        if eff.family not in JOINT_FAMILIES + ROTATION_FAMILIES:
            raise InputError(
                f"extend {eff.name}: only joint-angle effects ({', '.join(JOINT_FAMILIES)}) and "
                f"compliances ({', '.join(ROTATION_FAMILIES)}) can be added to a design or an evaluation "
                "(thermal_expansion, tracker_drift and tracker_scale need per-pose temperature and time)",
                fields=("extend",),
            )
        if any(o.key == eff.key for o in out):
            raise InputError(f"extend {eff.name} is given twice", fields=("extend",))
        out.append(eff)
    return tuple(out)
