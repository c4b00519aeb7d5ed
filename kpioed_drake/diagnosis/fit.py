"""Fits of the geometric model plus any set of effects on any subset of the poses of one data set.

:class:`FitProblem` binds the data, the noise and the per-pose conditions (gravity torques at the
commanded angles, temperature, time) and fits with the package's one estimator
(:func:`kpioed_drake.estimation.estimator.estimate`); :meth:`FitProblem.holdout` gives K-fold
cross-validated residuals (each fold's refit one Gauss-Newton step from the fit on all poses).
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.diagnosis.common import FOLD_SEED, K_FOLDS
from kpioed_drake.estimation import estimator
from kpioed_drake.estimation.estimator import EstimationResult
from kpioed_drake.robot.models import Robot, load_cell
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import nominal_model

Fit = EstimationResult
"""A fit of the geometric parameters and some effects (``effects``, ``Cp`` of both)."""


class FitProblem:
    """Data + sigma + the cached conditions: fits of any set of effects on any subset of poses.

    Attributes:
        robot: the robot; data: the measurements; sigma: noise per coordinate [mm].
        cell: the cell; nominal: the nominal model (the start of every fit without ``start``).
        conditions: per-pose inputs of the effects over all poses; the gravity torques hold the
            payload at the nominal reflector point (fixed during the fit, so that the residual
            function stays the same for every parameter value).
        side_patterns: ``{joint: (K, n)}`` candidate sides of a backlash whose side the file's masses
            leave uncertain (:func:`kpioed_drake.diagnosis.sides.side_patterns`); empty: the side of
            ``conditions`` only.
    """

    def __init__(self, robot: Robot, data: Measurements, sigma: float, *, cell=None):
        self.robot, self.data, self.sigma = robot, data, float(sigma)
        self.cell = load_cell(robot=robot) if cell is None else cell
        self.nominal = nominal_model(robot, self.cell)
        self.conditions = estimator.data_conditions(robot, data, p_FP=self.nominal.p_FQ)
        self.side_patterns = {}

    @property
    def tau(self) -> np.ndarray:
        """(n, 6) gravity torques at the commanded angles [N m]."""
        return self.conditions.tau

    def response(self, model, effects, idx):
        """h (m, 3), H (m, 3, n_full), E (m, 3, k) at poses ``idx``."""
        return estimator.response(model, list(effects), self.data.q[idx], self.conditions.subset(idx))

    def fit(self, effects, *, start: Fit | None = None, idx=None) -> Fit:
        """Fit the geometric parameters and the effects' values on poses ``idx`` (default all).

        Starts from ``start`` (its model and the values of effects it shares) or from the
        registered nominal model with zero effect values.
        """
        n = self.data.n
        mask = np.zeros(n, dtype=bool)
        mask[np.arange(n) if idx is None else np.asarray(idx)] = True
        known = {e.key: e for e in (start.effects if start is not None else ())}
        effs = [
            e.with_values(known[e.key].value_array() if e.key in known else np.zeros(e.n_params))
            for e in effects
        ]
        return estimator.estimate(
            self.nominal if start is None else start.model,
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
        linear to many digits: on the UR5's 1000 poses the held-out RMS agrees with full
        Levenberg-Marquardt refits of each fold to better than 1e-6 relative, at the cost of one
        Jacobian instead of k fits.
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
            model, effects = estimator.apply_step(full.model, full.effects, dxs / D)
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
