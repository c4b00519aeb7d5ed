"""Parameter estimation from laser-tracker data: rigid registration and Levenberg-Marquardt.

The one estimator of the package, used by calibration and by the diagnosis:

- :func:`register_tracker` (:mod:`kpioed_drake.estimation.registration`, re-exported): the tracker
  pose from nominal reflector positions in W and the measured ones in the tracker frame T
  (Kabsch/Umeyama without scaling; a proper rotation even when the best orthogonal fit would be a
  reflection), and a 6-DoF probe's orientation on the flange.
- :func:`estimate`: weighted nonlinear least squares on the free geometric parameters
  (``model.layout.free``, 27 for six joints) of :class:`~kpioed_drake.tracker.measurement.TrackerModel`,
  optionally together with the parameters of non-geometric effects (their Jacobian columns from
  :func:`kpioed_drake.effects.augmented_jacobian`), started from the given model, by default with
  the registered tracker pose. The tracker orientation is kept as a reference rotation
  ``R_WT_ref`` times three small rotations; after every accepted step the small rotations are
  folded into the reference (:meth:`TrackerModel.rebased`), so they stay near zero and the
  parametrisation never approaches a singularity, whatever the tracker's orientation.
- :func:`covariance` (:mod:`kpioed_drake.estimation.covariance`, re-exported): ``(J^T J)^-1`` of a
  weighted Jacobian (column-scaled Cholesky).

The covariance of the estimated parameters is ``Cp = (F1^T F1)^-1`` with ``F1 = J / sigma`` at the
solution (paper eq. 19 without constraints): the a-priori covariance given the noise ``sigma``.
``EstimationResult.Cp_scaled`` multiplies it by chi^2/dof (the a-posteriori version).

Units: millimetres and radians. Residuals are ``eta - h(p, q)`` in the tracker frame [mm].
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.effects.model import Effect
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.covariance import covariance  # noqa: F401 (re-exported)
from kpioed_drake.estimation.registration import register_tracker, registered_model  # noqa: F401 (re-exported)
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.parameters import ParameterLayout
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.contacts import ContactFit, ContactRows, contact_inputs
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel
from kpioed_drake.tracker.orientation import orientation_jacobian, orientation_residuals, with_probe

LM_LAMBDA0 = 1e-6
"""Initial Levenberg-Marquardt damping (relative to the unit diagonal of the column-scaled
information matrix)."""
GN_RIDGE = 1e-12
"""Relative ridge of the convergence test: the iteration stops when the Gauss-Newton step predicts a
cost decrease below ``tol`` times the cost (a step that small would not change the result, and
evaluating it near the optimum only meets rounding)."""


# ----------------------------------------------------------------------------------------------
# The model response with effects
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Conditions:
    """Per-pose inputs of the effects (all optional).

    Attributes:
        temperature_C: (n,) [C] (thermal expansion).
        time_s: (n,) [s] (tracker drift).
        tau: (n, 6) gravity torques [N m] at the commanded angles, payload included (joint
            elasticity); computed by the effects module when needed and not given.
        target: (n,) 0-based target (reflector) of each row; None: target 0 for every row.
        side: (n, 6) a backlash's side per pose; None: the sign of ``tau``.
        payload_kg: (n,) [kg] or None: the payload of a column or base compliance's moment.
    """

    temperature_C: np.ndarray | None = None
    time_s: np.ndarray | None = None
    tau: np.ndarray | None = None
    target: np.ndarray | None = None
    side: np.ndarray | None = None
    payload_kg: np.ndarray | None = None

    def subset(self, idx: np.ndarray | slice) -> Conditions:
        """The poses ``idx``."""
        values = (getattr(self, f.name) for f in dataclasses.fields(self))
        return Conditions(*(None if x is None else x[idx] for x in values))


def data_conditions(robot: Robot, data: Measurements, *, p_FP: np.ndarray) -> Conditions:
    """The conditions of measured data: its temperature and time, and the gravity torques at the
    commanded angles with the payload at ``p_FP`` [mm] (held fixed during a fit, so that the
    residual function is the same for every parameter value)."""
    tau = fx.gravity_torques(robot, data.q, payload_kg=data.payload_kg, p_FP=p_FP)
    return Conditions(data.temperature_C, data.time_s, tau, data.target, payload_kg=data.payload_kg)


def rms(r: np.ndarray) -> float:
    """Root mean square over all coordinates [mm] (nan for no coordinates)."""
    r = np.asarray(r)
    return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


def response(
    model: TrackerModel,
    effects: Sequence[Effect],
    q: np.ndarray,
    conditions: Conditions,
    *,
    jac: bool = True,
) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Model response with effects and (with ``jac``) its Jacobian: h (n, 3) [mm], H (n, 3, n_full),
    E (n, 3, k)."""
    f = fx.augmented_jacobian if jac else fx.augmented_response
    c = conditions
    kw = dict(temperature_C=c.temperature_C, time_s=c.time_s, tau=c.tau, target=c.target, side=c.side)
    return f(model, q, effects, compliance_payload_kg=c.payload_kg, **kw)


# ----------------------------------------------------------------------------------------------
# Levenberg-Marquardt
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class EstimationResult:
    """Outcome of :func:`estimate`.

    Attributes:
        model: the estimated model (tracker small rotations folded into ``R_WT_ref``, so zero).
        residuals: (n, 3) ``eta - h`` for every pose, used or not [mm, tracker frame].
        mask: (n,) poses used in the fit.
        weights: (n,) relative weights of the poses (1 = noise ``sigma``).
        sigma: noise standard deviation per coordinate [mm].
        iterations: accepted plus rejected LM iterations.
        converged: True if a step/cost tolerance was met.
        cost: chi^2 = sum over used poses of ``w_i |r_i|^2 / sigma^2``.
        dof: 3 * (used poses) - (estimated parameters).
        Cp: (n_free + k, n_free + k) a-priori covariance ``(F1^T F1)^-1`` of the estimated
            parameters (free geometric ones, then the effects') [mm, rad, effect units].
        J: (3 m, n_free + k) weighted Jacobian ``F1`` at the solution over the used poses
            (pose-major).
        message: why the iteration stopped.
        q: (n, 6) [rad], the commanded joint angles the fit was made to.
        eta: (n, 3) [mm], the measurements the fit was made to.
        effects: the estimated effects with their values (empty for the geometric model).
        conditions: the per-pose inputs of the effects.
        R_TP: (n, 3, 3) a 6-DoF probe's measured orientations the fit was made to, or None (points).
        sigma_rot: (n, 3) their noise about the tracker axes [rad], or None.
        rot_residuals: (n, 3) ``log(R_meas R_model^T)`` of every row, used or not [rad, tracker
            axes], or None. With orientations ``J`` has 3 m orientation rows after the 3 m
            position rows (pose-major both), ``cost`` and ``dof`` count them.
        contacts: the distance and plane rows' outcome (:mod:`kpioed_drake.tracker.contacts`), or
            None. With them ``J`` ends with their rows, distances first; ``cost`` and ``dof`` count them.
    """

    model: TrackerModel
    residuals: np.ndarray
    mask: np.ndarray
    weights: np.ndarray
    sigma: float
    iterations: int
    converged: bool
    cost: float
    dof: int
    Cp: np.ndarray
    J: np.ndarray
    message: str
    q: np.ndarray
    eta: np.ndarray
    effects: tuple = ()
    conditions: Conditions = dataclasses.field(default_factory=Conditions)
    R_TP: np.ndarray | None = None
    sigma_rot: np.ndarray | None = None
    rot_residuals: np.ndarray | None = None
    contacts: ContactFit | None = None

    @property
    def free(self) -> np.ndarray:
        return self.model.layout.free

    @property
    def free_names(self) -> list[str]:
        return self.model.layout.free_names

    @property
    def k(self) -> int:
        """Number of effect parameters."""
        return sum(e.n_params for e in self.effects)

    @property
    def layout(self) -> ParameterLayout:
        """The model's layout with the effect parameters after the free geometric ones."""
        return self.model.layout.with_effects(self.k)

    @property
    def n_params(self) -> int:
        """Estimated parameters: free geometric plus effects'."""
        return self.layout.n_unknowns

    @property
    def chi2_per_dof(self) -> float:
        return self.cost / self.dof if self.dof > 0 else float("nan")

    @property
    def Cp_scaled(self) -> np.ndarray:
        """A-posteriori covariance ``Cp * chi^2/dof`` (noise level estimated from the residuals)."""
        return self.Cp * self.chi2_per_dof if self.dof > 0 else np.full_like(self.Cp, np.nan)

    @property
    def std(self) -> np.ndarray:
        """(n_free + k,) a-priori standard deviations of the estimated parameters [mm, rad, ...]."""
        return np.sqrt(np.diag(self.Cp))

    @property
    def n_used(self) -> int:
        return int(np.count_nonzero(self.mask))


@dataclasses.dataclass(frozen=True)
class _Problem:
    """The used poses, their weights and conditions: residuals and Jacobians of a parameter point
    (with a probe's orientations ``R_TP`` (m, 3, 3) their rows after the positions', weighted by
    ``w_rot`` (m, 3) [1/rad])."""

    q: np.ndarray
    eta: np.ndarray
    sw: np.ndarray
    sigma: float
    conditions: Conditions
    R_TP: np.ndarray | None = None
    w_rot: np.ndarray | None = None
    contacts: ContactRows | None = None

    def weighted(self, model: TrackerModel, effects, *, jac: bool = True):
        """Whitened residuals (and Jacobian) of every row: tracker, orientations, then contacts."""
        rows = self._tracker_rows(model, effects, jac=jac)
        return rows if self.contacts is None else self.contacts.stacked(model, rows, jac=jac)

    def _tracker_rows(self, model: TrackerModel, effects, *, jac: bool = True):
        w = self.sw[:, None] / self.sigma
        if not jac:
            r = ((self.eta - response(model, effects, self.q, self.conditions, jac=False)) * w).reshape(-1)
            if self.R_TP is None:
                return r
            return np.concatenate(
                [r, (orientation_residuals(model, self.q, self.R_TP) * self.w_rot).reshape(-1)]
            )
        h, H, E = response(model, effects, self.q, self.conditions)
        r = ((self.eta - h) * w).reshape(-1)
        free = model.layout.free
        J = np.concatenate([H[:, :, free], E], axis=2) * w[:, :, None]
        if self.R_TP is None:
            return r, J.reshape(r.size, J.shape[2])
        e, Hr = orientation_jacobian(model, self.q, self.R_TP)
        Jr = Hr[:, :, free] * self.w_rot[:, :, None]
        r = np.concatenate([r, (e * self.w_rot).reshape(-1)])
        return r, np.concatenate([J.reshape(-1, J.shape[2]), Jr.reshape(-1, Jr.shape[2])])


def apply_step(
    model: TrackerModel, effects: Sequence[Effect], dx: np.ndarray
) -> tuple[TrackerModel, list[Effect]]:
    """``model`` and ``effects`` moved by ``dx`` (n_free + k,): the free geometric parameters, then
    the effects' values in order [mm, rad, effect units]. Returns (model, list of effects)."""
    free = model.layout.free
    p = model.p.copy()
    p[free] += dx[: free.size]
    out, c = [], free.size
    for e in effects:
        out.append(e.with_values(e.value_array() + dx[c : c + e.n_params]))
        c += e.n_params
    return model.with_params(p), out


def _gauss_newton_decrease(A: np.ndarray, g: np.ndarray) -> float:
    """Decrease of the cost the (undamped) Gauss-Newton step predicts, ``g^T A^-1 g`` (a tiny
    relative ridge keeps a rank-deficient ``A`` solvable; inf if it still fails)."""
    try:
        return float(g @ np.linalg.solve(A + GN_RIDGE * np.eye(A.shape[0]), g))
    except np.linalg.LinAlgError:
        return float("inf")


def _check_inputs(q, eta, sigma, mask, weights, n_params, nj, rows_per_pose=3):
    q = np.atleast_2d(np.asarray(q, dtype=float))
    eta = np.atleast_2d(np.asarray(eta, dtype=float))
    n = q.shape[0]
    if q.shape != (n, nj) or eta.shape != (n, 3):
        raise InputError(f"estimate: expected q (n, {nj}) and eta (n, 3), got {q.shape} and {eta.shape}")
    if not (np.isfinite(sigma) and sigma > 0):
        raise InputError(f"estimate: sigma must be a positive number of millimetres, got {sigma!r}")
    mask = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).copy()
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).copy()
    if mask.shape != (n,) or w.shape != (n,) or np.any(w[mask] <= 0) or not np.all(np.isfinite(w)):
        raise InputError("estimate: mask and weights must have one entry per pose, weights > 0")
    m = int(np.count_nonzero(mask))
    if rows_per_pose * m < n_params:
        raise InputError(
            f"estimate: {m} poses give {rows_per_pose * m} coordinates, fewer than the {n_params} "
            f"parameters (need at least {int(np.ceil(n_params / rows_per_pose))} poses)"
        )
    return q, eta, mask, w


def _levenberg_marquardt(prob: _Problem, model: TrackerModel, effects, free, *, max_iter: int, tol: float):
    """Levenberg-Marquardt from ``model`` and ``effects`` (steps in Jacobian-scaled units, the damping
    raised after a rejected step and lowered by the gain ratio after an accepted one; stops as
    :func:`estimate`'s ``tol`` says).

    Returns:
        (model, effects, J, cost, converged, message, iterations) at the last accepted point: J the
        weighted Jacobian (3m, n_free + k), cost ``|r|^2`` of the weighted residuals.
    """
    r, J = prob.weighted(model, effects)
    cost = float(r @ r)
    lam = LM_LAMBDA0
    nu = 2.0
    converged, message, it = False, "maximum number of iterations reached", 0
    while it < max_iter:
        it += 1
        D = np.linalg.norm(J, axis=0)
        D[D == 0] = 1.0
        Js = J / D
        g = Js.T @ r
        A = Js.T @ Js
        if np.max(np.abs(g)) <= 1e-14 * max(1.0, np.sqrt(cost)):
            converged, message = True, "gradient is zero"
            break
        if _gauss_newton_decrease(A, g) <= tol * cost:
            converged, message = True, "predicted cost decrease below tol"
            break
        try:
            dxs = np.linalg.solve(A + lam * np.eye(A.shape[0]), g)
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2.0
            continue
        dx = dxs / D
        pred = float(dxs @ (2.0 * g - A @ dxs))  # predicted decrease of |r|^2 (Gauss-Newton model)
        trial, trial_effects = apply_step(model, effects, dx)
        r_new = prob.weighted(trial, trial_effects, jac=False)
        cost_new = float(r_new @ r_new)
        actual = cost - cost_new
        rho = actual / pred if pred > 0 else -1.0
        x_scaled = D * np.concatenate([model.p[free], *(e.value_array() for e in effects)])
        if actual > 0 and rho > 0:
            small_step = np.linalg.norm(dxs) <= tol * (np.linalg.norm(x_scaled) + tol)
            small_cost = actual <= tol * cost
            model, effects = trial.rebased(), trial_effects
            r, J = prob.weighted(model, effects)
            cost = float(r @ r)
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small_step or small_cost:
                converged = True
                message = "relative step below tol" if small_step else "relative cost decrease below tol"
                break
        else:
            if np.linalg.norm(dxs) <= tol * (np.linalg.norm(x_scaled) + tol):
                converged, message = True, "no further decrease possible (step below tol)"
                break
            lam *= nu
            nu *= 2.0
    return model, effects, J, cost, converged, message, it


def estimate(
    model: TrackerModel,
    q: np.ndarray,
    eta: np.ndarray,
    *,
    sigma: float = 0.02,
    max_iter: int = 100,
    tol: float = 1e-10,
    mask: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    register: bool = True,
    effects: Sequence[Effect] = (),
    conditions: Conditions | None = None,
    singular_ok: bool = False,
    R_TP: np.ndarray | None = None,
    sigma_rot: np.ndarray | None = None,
    distances: DistanceData | None = None,
    planes: PlaneData | None = None,
) -> EstimationResult:
    """Estimate the free parameters of ``model`` (and the effects' values) from measured reflector positions.

    Args:
        model: starting model (normally the nominal one); its tracker pose is replaced by the
            registration of its reflector points to the data unless ``register`` is False.
        q: (n, 6) commanded joint angles [rad].
        eta: (n, 3) measured reflector positions in the tracker frame [mm].
        sigma: noise standard deviation per coordinate [mm].
        max_iter: most LM iterations (accepted or rejected).
        tol: stop when the Gauss-Newton step predicts a cost decrease below ``tol`` times the
            cost, or the accepted step is below ``tol`` relative to the parameters (in
            Jacobian-scaled units), or the relative cost decrease is below ``tol``.
        mask: (n,) bool, the poses to use (default all).
        weights: (n,) positive relative weights (pose i has noise ``sigma / sqrt(w_i)``).
        register: start from the rigid registration of the tracker (default True).
        effects: :class:`~kpioed_drake.effects.Effect` list estimated with the geometry; their
            values are the starting point (unknown = 0).
        conditions: the per-pose inputs the effects need (over all n poses).
        singular_ok: accept a rank-deficient Jacobian at the solution (``Cp`` is then the
            pseudo-inverse) instead of raising; the diagnosis fits candidates that way.
        R_TP: (n, 3, 3) a 6-DoF probe's measured orientations in the tracker frame: their rows join
            the fit (:mod:`kpioed_drake.tracker.orientation`; the model gets the probe's three
            rotations if its layout lacks them, registered with the tracker when ``register``).
        sigma_rot: (n, 3) the orientations' noise about the tracker axes [rad] (needed with ``R_TP``).
        distances, planes: distance and plane-contact rows joining the fit (alone: ``q`` and ``eta``
            None or empty; the model gets their parameters, starts and gauge,
            :func:`kpioed_drake.tracker.contacts.contact_model`, unless it has them already).

    Returns:
        :class:`EstimationResult`.

    Raises:
        InputError: bad shapes, too few poses for the parameters, or (unless ``singular_ok``) a
            Jacobian without full rank at the solution (parameters not identifiable from these poses).
    """
    effects = [e.with_values(e.value_array()) for e in effects]
    conditions = Conditions() if conditions is None else conditions
    contacts = None
    if distances is not None or planes is not None:
        kw = dict(sigma=sigma, mask=mask, conditions=conditions, other_rows=bool(effects or R_TP is not None))
        model, contacts, q, eta = contact_inputs(model, q, eta, distances=distances, planes=planes, **kw)
    if R_TP is not None:
        R_TP, sigma_rot, model = _pose_inputs(model, q, R_TP, sigma_rot, effects)
    free = model.layout.free
    n_params = free.size + sum(e.n_params for e in effects)
    per_pose = 3 if R_TP is None else 6
    nj = model.robot.n_joints
    q, eta, mask, w = _check_inputs(
        q, eta, sigma, mask, weights, n_params if contacts is None else 0, nj, per_pose
    )
    m = int(np.count_nonzero(mask))
    prob = _Problem(
        q[mask], eta[mask], np.sqrt(w[mask]), float(sigma), conditions.subset(mask), contacts=contacts
    )
    if R_TP is not None:
        prob = dataclasses.replace(prob, R_TP=R_TP[mask], w_rot=prob.sw[:, None] / sigma_rot[mask])
    if register and m:
        model = registered_model(model, prob.q, prob.eta, target=prob.conditions.target, R_TP=prob.R_TP)

    model, effects, J, cost, converged, message, it = _levenberg_marquardt(
        prob, model, effects, free, max_iter=max_iter, tol=tol
    )

    iteration = dict(iterations=it, converged=converged, cost=cost, message=message)
    fitted_to = dict(
        q=q, eta=eta, mask=mask, weights=w, conditions=conditions, R_TP=R_TP, sigma_rot=sigma_rot
    )
    return EstimationResult(
        model=model,
        residuals=eta - response(model, effects, q, conditions, jac=False),
        rot_residuals=None if R_TP is None else orientation_residuals(model, q, R_TP),
        sigma=float(sigma),
        dof=per_pose * m + (0 if contacts is None else contacts.n_rows) - n_params,
        contacts=None if contacts is None else contacts.fit(model),
        Cp=_solution_covariance(J, m, n_params, singular_ok),
        J=J,
        effects=tuple(effects),
        **iteration,
        **fitted_to,
    )


def _pose_inputs(
    model: TrackerModel, q, R_TP, sigma_rot, effects
) -> tuple[np.ndarray, np.ndarray, TrackerModel]:
    """The orientations and their noise checked ((n, 3, 3), (n, 3) > 0 [rad]) and the model with the
    probe's rotations; InputError for bad shapes or effects (their orientation rows are not modelled)."""
    n = np.atleast_2d(q).shape[0]
    R_TP = np.asarray(R_TP, dtype=float)
    sigma_rot = None if sigma_rot is None else np.asarray(sigma_rot, dtype=float)
    if R_TP.shape != (n, 3, 3) or sigma_rot is None or sigma_rot.shape != (n, 3):
        got = None if sigma_rot is None else sigma_rot.shape
        raise InputError(
            f"estimate: expected R_TP (n, 3, 3) and sigma_rot (n, 3) with n = {n}, got {R_TP.shape} and {got}"
        )
    if not (np.all(np.isfinite(sigma_rot)) and np.all(sigma_rot > 0)):
        raise InputError("estimate: sigma_rot must be positive numbers of radians")
    if effects:
        raise InputError("estimate: non-geometric effects with orientation rows are not modelled")
    return R_TP, sigma_rot, with_probe(model)


def _solution_covariance(J: np.ndarray, m: int, n_params: int, singular_ok: bool) -> np.ndarray:
    """The a-priori covariance at the solution of ``m`` poses; InputError if singular (not singular_ok)."""
    try:
        return covariance(J, singular_ok=singular_ok)
    except np.linalg.LinAlgError:
        raise InputError(
            f"estimate: the {m} poses do not determine the {n_params} parameters (information matrix "
            "singular); use more or more varied poses"
        ) from None
