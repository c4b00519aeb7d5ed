"""Fits of the geometric model plus any set of effects on any subset of the poses of one data set.

:class:`FitProblem` binds the data, the noise and the per-pose conditions (gravity torques at the
commanded angles, temperature, time) and fits with the package's one estimator
(:func:`kpioed_drake.estimation.estimator.estimate`); :meth:`FitProblem.holdout` gives K-fold
cross-validated residuals (each fold's refit one Gauss-Newton step from the fit on all poses).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.diagnosis.common import FOLD_SEED, K_FOLDS
from kpioed_drake.estimation import estimator
from kpioed_drake.estimation.estimator import Conditions, EstimationResult
from kpioed_drake.robot.models import Cell, Robot, load_cell
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model

Fit = EstimationResult
"""A fit of the geometric parameters and some effects (``effects``, ``Cp`` of both)."""


@dataclasses.dataclass(frozen=True, eq=False)
class FitProblem:
    """Data + sigma + the per-pose conditions: fits of any set of effects on any subset of poses.

    Immutable: :meth:`with_nominal`, :meth:`with_robot`, :meth:`with_sides`, :meth:`with_side` and
    :meth:`with_tau` return a new problem, so a fit with another backlash side or torque never
    changes the problem others hold.

    Attributes:
        robot: the robot.
        data: the measurements.
        sigma: noise per coordinate [mm].
        cell: the cell (default: the robot's cell file).
        nominal: the nominal model, the start of every fit without ``start`` (default: the cell's).
        conditions: per-pose inputs of the effects over all poses (default: the data's); the gravity
            torques hold the payload at the nominal reflector point (fixed during the fit, so that the
            residual function stays the same for every parameter value).
    """

    robot: Robot
    data: Measurements
    sigma: float
    _: dataclasses.KW_ONLY
    cell: Cell | None = None
    nominal: TrackerModel | None = None
    conditions: Conditions | None = None

    def __post_init__(self):
        # the defaults are derived from the other fields (set once, at construction)
        object.__setattr__(self, "sigma", float(self.sigma))
        if self.cell is None:
            object.__setattr__(self, "cell", load_cell(robot=self.robot))
        if self.nominal is None:
            object.__setattr__(self, "nominal", nominal_model(self.robot, self.cell))
        if self.conditions is None:
            conditions = estimator.data_conditions(self.robot, self.data, p_FP=self.nominal.p_FQ)
            object.__setattr__(self, "conditions", conditions)

    def with_nominal(self, nominal: TrackerModel) -> FitProblem:
        """The same problem started from another nominal model (e.g. with parameters held)."""
        return dataclasses.replace(self, nominal=nominal)

    def with_robot(self, robot: Robot) -> FitProblem:
        """The same problem with another description of the same robot (e.g. its gravity bases
        sized on these poses): the nominal model's robot replaced too."""
        return dataclasses.replace(self, robot=robot, nominal=dataclasses.replace(self.nominal, robot=robot))

    def with_sides(self, side: np.ndarray) -> FitProblem:
        """The same problem with the backlash sides ``side`` (n, 6) (per pose and joint)."""
        return dataclasses.replace(self, conditions=dataclasses.replace(self.conditions, side=side))

    def with_side(self, joint: int, side: np.ndarray) -> FitProblem:
        """The same problem with the backlash of ``joint`` (1-based) on ``side`` (n,)."""
        s = (np.sign(self.tau) if self.conditions.side is None else self.conditions.side).copy()
        s[:, joint - 1] = side
        return self.with_sides(s)

    def with_tau(self, tau: np.ndarray) -> FitProblem:
        """The same problem with other gravity torques (n, 6) [N m]; a backlash of a joint whose
        torque changed takes the new torque's sign (a side fitted from the data)."""
        side = self.conditions.side
        if side is not None:
            side = np.where(tau != self.tau, np.sign(tau), side)
        return dataclasses.replace(self, conditions=dataclasses.replace(self.conditions, tau=tau, side=side))

    @property
    def tau(self) -> np.ndarray:
        """(n, 6) gravity torques at the commanded angles [N m]."""
        return self.conditions.tau

    def own(self, model: TrackerModel) -> TrackerModel:
        """``model``'s parameters with this problem's robot (a fit made before the robot's gravity
        bases were sized on these poses carries the robot of then)."""
        return model if model.robot is self.robot else dataclasses.replace(model, robot=self.robot)

    def response(self, model, effects, idx):
        """h (m, 3), H (m, 3, n_full), E (m, 3, k) at poses ``idx`` (``model`` with this robot)."""
        cond = self.conditions.subset(idx)
        return estimator.response(self.own(model), list(effects), self.data.q[idx], cond)

    def fit(self, effects, *, start: Fit | None = None, idx=None) -> Fit:
        """Fit the geometric parameters and the effects' values on poses ``idx`` (default all).

        Starts from ``start`` (its model's parameters, this problem's robot, and the values of
        effects it shares) or from the registered nominal model with zero effect values.
        """
        n = self.data.n
        mask = np.zeros(n, dtype=bool)
        mask[np.arange(n) if idx is None else np.asarray(idx)] = True
        known = {e.name: e for e in (start.effects if start is not None else ())}
        effs = [
            e.with_values(known[e.name].value_array() if e.name in known else np.zeros(e.n_params))
            for e in effects
        ]
        return estimator.estimate(
            self.nominal if start is None else self.own(start.model),
            self.data.q,
            self.data.eta,
            sigma=self.sigma,
            mask=mask,
            register=start is None,
            effects=effs,
            conditions=self.conditions,
            singular_ok=True,
        )

    def folds(self, k: int = K_FOLDS) -> list[np.ndarray]:
        """``k`` disjoint test sets of poses (seeded random assignment)."""
        n = self.data.n
        k = int(min(k, n))
        perm = np.random.default_rng(FOLD_SEED).permutation(n)
        return [np.sort(perm[i::k]) for i in range(k)]

    def holdout(self, full: Fit, *, k: int = K_FOLDS) -> np.ndarray:
        """(n, 3) held-out residuals by K-fold cross-validation [mm].

        Each fold's refit on the other poses is one Gauss-Newton step from ``full`` (the fit on
        every pose, the solution the fold's refit starts from): ``dx = argmin |J_train dx - r_train|``
        with ``J`` and ``r`` the weighted Jacobian and residuals at ``full``'s solution (minimum
        norm where the fold's Jacobian is rank deficient); the fold's poses are then predicted
        exactly (nonlinear response) at the stepped parameters. Leaving out 1/k of the poses moves
        the parameters by about their standard deviations, where the least-squares problem is
        linear to many digits, so the step gives the held-out residuals of full refits of each
        fold (tests/test_holdout.py compares them) at the cost of one Jacobian instead of k fits.
        """
        n = self.data.n
        every = np.arange(n)
        h, H, E = self.response(full.model, full.effects, every)
        w = np.sqrt(full.weights)[:, None] / self.sigma
        r = (self.data.eta - h) * w  # (n, 3) weighted residuals at the solution
        J = np.concatenate([H[:, :, full.free], E], axis=2) * w[:, :, None]  # (n, 3, k)
        D = np.linalg.norm(J[full.mask].reshape(-1, J.shape[2]), axis=0)
        D[D == 0] = 1.0
        out = np.empty((n, 3))
        for test in self.folds(k):
            train = full.mask.copy()
            train[test] = False
            A = J[train].reshape(-1, J.shape[2]) / D
            dxs = np.linalg.lstsq(A, r[train].reshape(-1), rcond=None)[0]
            model, effects = estimator.apply_step(self.own(full.model), full.effects, dxs / D)
            cond = self.conditions.subset(test)
            h_test = estimator.response(model, effects, self.data.q[test], cond, jac=False)
            out[test] = self.data.eta[test] - h_test
        return out

    def effect_signal(self, fit: Fit, i: int) -> np.ndarray:
        """(n, 3) contribution of effect i of ``fit`` to the measurements (linearised) [mm]."""
        _, _, E = self.response(fit.model, fit.effects, np.arange(self.data.n))
        c = sum(e.n_params for e in fit.effects[:i])
        e = fit.effects[i]
        return E[:, :, c : c + e.n_params] @ e.value_array()
