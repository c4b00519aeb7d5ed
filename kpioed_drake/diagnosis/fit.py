"""Fits of the geometric model plus any set of effects on any subset of the poses of one data set,
their held-out errors and whether one model predicts fresh poses better than another.

:class:`FitProblem` binds the data, the noise and the per-pose conditions (gravity torques at the
commanded angles, temperature, time) and fits with the package's one estimator
(:func:`kpioed_drake.estimation.estimator.estimate`); :meth:`FitProblem.holdout` gives K-fold
cross-validated residuals (each fold's refit one Gauss-Newton step from the fit on all poses).

The K-fold cross-validation predicts every pose from a fit that did not see it
(:func:`held_out_gain`). For the model without a candidate (held-out residuals
``e_before``) and with it (``e_after``) the gain of pose ``i`` is ``d_i = |e_before_i|^2 -
|e_after_i|^2`` [mm^2], summed over the rows of the pose (its targets). The candidate predicts better
when the mean gain exceeds its uncertainty, ``mean(d) > c std(d) / sqrt(n)`` with ``c =``
:data:`~kpioed_drake.diagnosis.options.GAIN_STANDARD_ERRORS` (2: the half-width of about a 95 %
interval): the paired comparison of the same poses, so that the spread of the poses' errors,
common to both models, does not hide a small but consistent gain, and a gain that a few poses make
is not taken for one.

:func:`stop_reason` words why the selection stopped (:data:`STOPS`).

:func:`independent` runs a step's independent fits (the refits of a step's candidates, each
cause's competing explanations) in worker processes forked from this one (:func:`ordered` for a loop
that may stop at the first result that settles it), when the problem is large
(:data:`~kpioed_drake.diagnosis.options.PARALLEL_MIN_ENTRIES`): the workers inherit the problem and
every cache (nothing but the task's number and its result is pickled), run the same code on the same
inputs with one BLAS thread, and the results come back in the tasks' order, so the numbers are
those of the loop in this process. Workers: :func:`kpioed_drake.parallel.workers` (``KPIOED_WORKERS``;
1: no processes).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterable, Iterator

import numpy as np
import scipy.linalg

from kpioed_drake import parallel
from kpioed_drake.diagnosis.options import (
    FOLD_SEED,
    GAIN_STANDARD_ERRORS,
    K_FOLDS,
    PARALLEL_MIN_ENTRIES,
)
from kpioed_drake.effects.model import Effect
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
        robot: the robot; of an extended model file, the robot its fit started from (the nominal
            model's, :mod:`kpioed_drake.robot.reference`), on which the effects are evaluated.
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
        if self.robot.reference is not None:  # an extended model file: its fit's robot, as the nominal's
            object.__setattr__(self, "robot", self.robot.reference.robot)
        if self.robot.payload_point is None:  # a payload acts where it acts in the fit's conditions
            robot = dataclasses.replace(self.robot, payload_point=self.nominal.p_FP)
            object.__setattr__(self, "robot", robot)
            object.__setattr__(self, "nominal", dataclasses.replace(self.nominal, robot=robot))
        if self.conditions is None:
            conditions = estimator.data_conditions(self.robot, self.data, p_FP=self.nominal.p_FP)
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

    def response(
        self, model: TrackerModel, effects: Iterable[Effect], idx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """h (m, 3), H (m, 3, n_full), E (m, 3, k) at poses ``idx`` (``model`` with this robot)."""
        cond = self.conditions.subset(idx)
        return estimator.response(self.own(model), list(effects), self.data.q[idx], cond)

    def fit(
        self,
        effects: Iterable[Effect],
        *,
        start: Fit | None = None,
        idx: np.ndarray | None = None,
        max_iter: int = 100,
    ) -> Fit:
        """Fit the geometric parameters and the effects' values on poses ``idx`` (default all).

        Starts from ``start`` (its model's parameters, this problem's robot, and the values of
        effects it shares) or from the registered nominal model with zero effect values; at most
        ``max_iter`` Levenberg-Marquardt iterations.
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
            max_iter=max_iter,
        )

    def folds(self, k: int = K_FOLDS) -> list[np.ndarray]:
        """``k`` disjoint test sets of rows (seeded random assignment of poses: the rows of one
        pose's targets are held out together, so a fold's poses are fresh to its fit)."""
        groups = pose_groups(self.data.q)
        m = int(groups.max()) + 1 if groups.size else 0
        k = int(min(k, m))
        perm = np.random.default_rng(FOLD_SEED).permutation(m)
        fold = np.empty(m, dtype=int)
        fold[perm] = np.arange(m) % k
        return [np.flatnonzero(fold[groups] == i) for i in range(k)]

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
        r, J = self._weighted_solution(full)  # over the fit's poses
        D = np.linalg.norm(J.reshape(-1, J.shape[2]), axis=0)
        D[D == 0] = 1.0
        out = np.empty((n, 3))
        for test in self.folds(k):
            train = full.mask.copy()
            train[test] = False
            train = train[full.mask]
            A = J[train].reshape(-1, J.shape[2]) / D
            dxs = scipy.linalg.lstsq(A, r[train].reshape(-1), lapack_driver="gelsy", check_finite=False)[0]
            model, effects = estimator.apply_step(self.own(full.model), full.effects, dxs / D)
            cond = self.conditions.subset(test)
            h_test = estimator.response(model, effects, self.data.q[test], cond, jac=False)
            out[test] = self.data.eta[test] - h_test
        return out

    def _weighted_solution(self, full: Fit) -> tuple[np.ndarray, np.ndarray]:
        """(m, 3) weighted residuals and (m, 3, k) weighted Jacobian at ``full``'s solution, over the m
        poses it was fitted to: its own Jacobian (the estimator's last, at the solution) when it was
        fitted to this problem's poses, conditions, robot and sigma, else evaluated here."""
        w = np.sqrt(full.weights[full.mask])[:, None] / self.sigma
        own = (
            full.q is self.data.q
            and full.conditions is self.conditions
            and full.model.robot is self.robot
            and full.sigma == self.sigma
            and full.R_TP is None
            and full.contacts is None
        )
        if own:
            return full.residuals[full.mask] * w, full.J.reshape(-1, 3, full.J.shape[1])
        h, H, E = self.response(full.model, full.effects, np.flatnonzero(full.mask))
        J = np.concatenate([H[:, :, full.free], E], axis=2) * w[:, :, None]
        return (self.data.eta[full.mask] - h) * w, J

    def effect_signal(self, fit: Fit, i: int) -> np.ndarray:
        """(n, 3) contribution of effect i of ``fit`` to the measurements (linearised) [mm]."""
        _, _, E = self.response(fit.model, fit.effects, np.arange(self.data.n))
        c = sum(e.n_params for e in fit.effects[:i])
        e = fit.effects[i]
        return E[:, :, c : c + e.n_params] @ e.value_array()


STOPS = {
    "no_candidate": "no candidate left: every candidate effect is in the model",
    "identifiability": "no candidate left that these poses can tell from the model's parameters "
    "(all absorbed)",
    "not_significant": "no candidate left is significant (likelihood-ratio test at the step's level, "
    "with a BIC gain)",
    "no_holdout_gain": "the best significant candidate does not lower the held-out error by more than "
    "its uncertainty",
    "stand_in": "the best significant candidate lowers the held-out error by no more than its uncertainty "
    "while the model still fails the goodness-of-fit test (a stand-in for an unexplained error)",
    "max_effects": "the most effects the options allow (max_effects) are in the model",
}
"""Why the stepwise selection stopped, by key (the report's ``selection_stop``)."""


@dataclasses.dataclass(frozen=True)
class HeldOutGain:
    """The held-out gain of a model over another on the same poses and folds.

    Attributes:
        before_mm: held-out RMS per coordinate without the candidate [mm].
        after_mm: held-out RMS per coordinate with it [mm].
        gain_mm2: mean gain per pose of the squared held-out error [mm^2].
        std_error_mm2: its standard error over the poses [mm^2].
        n_poses: the poses compared.
    """

    before_mm: float
    after_mm: float
    gain_mm2: float
    std_error_mm2: float
    n_poses: int

    @property
    def predicts_better(self) -> bool:
        """Whether the gain exceeds its uncertainty (:data:`~.options.GAIN_STANDARD_ERRORS` standard
        errors)."""
        return bool(self.gain_mm2 > GAIN_STANDARD_ERRORS * self.std_error_mm2)

    @property
    def ratio(self) -> float:
        """The gain in standard errors (inf for a gain without spread)."""
        if self.std_error_mm2 > 0:
            return self.gain_mm2 / self.std_error_mm2
        return float("inf") if self.gain_mm2 > 0 else 0.0

    def text(self) -> str:
        """``held-out RMS 1.71 -> 1.52 mm, gain 0.61 +- 0.05 mm^2 a pose (12.2 standard errors)``."""
        return (
            f"held-out RMS {self.before_mm:.4g} -> {self.after_mm:.4g} mm, gain {self.gain_mm2:.3g} "
            f"+- {self.std_error_mm2:.2g} mm^2 a pose ({self.ratio:.1f} standard errors)"
        )

    def as_dict(self) -> dict:
        """The fields and :attr:`ratio` (JSON)."""
        return dataclasses.asdict(self) | {"ratio": self.ratio}


def pose_groups(q: np.ndarray) -> np.ndarray:
    """(n,) pose number of each row, numbered in order of first appearance: the rows of one pose's
    targets (the same joint values) share it; data of one row a pose gives ``0, 1, ..., n - 1``."""
    q = np.asarray(q, dtype=float)
    if q.shape[0] == 0:
        return np.zeros(0, dtype=int)
    _, first, inverse = np.unique(q, axis=0, return_index=True, return_inverse=True)
    order = np.empty(len(first), dtype=int)
    order[np.argsort(first, kind="stable")] = np.arange(len(first))
    return order[inverse.reshape(-1)]


def held_out_gain(before: np.ndarray, after: np.ndarray, groups: np.ndarray) -> HeldOutGain:
    """The gain of ``after`` over ``before``, both (n, 3) held-out residuals [mm] of the same rows,
    paired by pose (``groups``, :func:`pose_groups`)."""
    before, after = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    m = int(groups.max()) + 1 if groups.size else 0
    d = np.bincount(groups, weights=np.sum(before**2, axis=1) - np.sum(after**2, axis=1), minlength=m)
    se = float(np.std(d, ddof=1) / np.sqrt(m)) if m > 1 else float("inf")
    return HeldOutGain(
        before_mm=float(np.sqrt(np.mean(before**2))),
        after_mm=float(np.sqrt(np.mean(after**2))),
        gain_mm2=float(np.mean(d)) if m else 0.0,
        std_error_mm2=se,
        n_poses=m,
    )


def stop_reason(key: str, detail: str = "") -> dict:
    """The report's record of why the selection stopped: ``{"reason": key, "text": ...}``."""
    text = STOPS[key] + (f" ({detail})" if detail else "")
    return {"reason": key, "text": text}


def independent(task: Callable[[int], object], n: int, *, size: int) -> list:
    """``[task(0), ..., task(n - 1)]``, in worker processes forked from this one
    (:func:`kpioed_drake.parallel.independent`) when ``size`` (the entries of the problem's Jacobian,
    a measure of one fit's work) reaches :data:`~.options.PARALLEL_MIN_ENTRIES` (module docstring)."""
    return parallel.independent(task, n, parallel=size >= PARALLEL_MIN_ENTRIES)


@contextlib.contextmanager
def ordered(task: Callable[[int], object], n: int, *, size: int) -> Iterator[Iterator]:
    """Within the block, an iterator over ``task(0), ..., task(n - 1)`` in order
    (:func:`kpioed_drake.parallel.ordered`: worker processes run ahead when ``size`` reaches
    :data:`~.options.PARALLEL_MIN_ENTRIES`, as :func:`independent`); a loop that stops early skips
    the tasks no worker had started."""
    with parallel.ordered(task, n, parallel=size >= PARALLEL_MIN_ENTRIES) as results:
        yield results
