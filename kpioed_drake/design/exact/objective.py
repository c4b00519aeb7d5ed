"""The cost of the design problem (paper eq. 24a): a criterion of ``n`` poses and its gradient.

``phi(q) = criterion(F1(q))`` with ``F1 = dh/dp / sigma`` (paper eq. 24d) and ``Js = dTCP/dp`` at
``q_work`` (eq. 24e), the criteria of :mod:`kpioed_drake.estimation.criteria`. The gradient is closed form and
vectorised over poses: the adjoint ``d phi / d F1`` contracted with ``d F1 / d q``
(:meth:`kpioed_drake.estimation.problem.Problem.F1`).

Several working poses (paper, Outlook): the weighted mean of their variances is the ``kpi``
criterion of the stacked ``Js`` (:meth:`kpioed_drake.estimation.problem.Problem.Js`). The worst case
(``kpi_aggregate == "max"``) is not differentiable where two variances tie;
:meth:`DesignObjective.values_and_grads` gives each variance and its gradient, which the program
uses in an epigraph form (:class:`~kpioed_drake.design.exact.program.DesignProgram`).
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.design.settings import as_poses
from kpioed_drake.estimation.criteria import Criterion, kpi_each, resolve
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.kinematics import Frames


class DesignObjective:
    """A design criterion of ``n`` poses and its closed-form gradient.

    Args:
        problem: the identification problem.
        criterion: ``kpi``, ``param``, ``d`` or ``o1``.
        fixed_information: (k, k) information ``F1^T F1`` of further poses that are measured too
            but not varied (block sweeps of :func:`~kpioed_drake.design.optimize.optimize_design`);
            None: none.

    Attributes:
        criterion: the resolved :class:`~kpioed_drake.estimation.criteria.Criterion`.
        Js: (3, k) KPI Jacobian at ``q_work`` (several working poses: the weighted stack (3K, k));
            ``scale``: (k,) SPEC scaling of the parameters.
        worst_case: the value is the largest of the K working poses' variances (``kpi`` criterion,
            ``problem.kpi_aggregate == "max"``, K > 1).

    Raises:
        InputError: unknown criterion.
    """

    def __init__(self, problem: Problem, criterion: str, *, fixed_information: np.ndarray | None = None):
        self.criterion: Criterion = resolve(criterion)
        self.problem = problem
        self.Js = problem.Js()
        self.scale = problem.scale
        self.M0 = fixed_information
        self.worst_case = self.criterion.name == "kpi" and problem.worst_case
        self.Js_each = problem.Js_each() if self.worst_case else None

    def value(self, q: np.ndarray, *, frames: Frames | None = None) -> float:
        """Criterion of the design ``q`` (n, 6) [rad] (``frames``: its forward kinematics, if known)."""
        F1 = self.problem.F1(as_poses(q, self.problem.robot.n_joints), frames=frames)
        if self.worst_case:
            return float(np.max(kpi_each(F1, self.Js_each, M0=self.M0, with_grad=False)))
        return self.criterion.evaluate(F1, self.Js, self.scale, with_grad=False, M0=self.M0)

    def values_and_grads(
        self, q: np.ndarray, *, frames: Frames | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each working pose's variance tr(Cs_k)/3 (K,) [mm^2] and its gradient (K, n, 6) [mm^2/rad]
        (worst case only: the constraints ``t >= v_k(q)`` of the epigraph form)."""
        q = as_poses(q, self.problem.robot.n_joints)
        F1, dF1 = self.problem.F1(q, with_dq=True, frames=frames)
        values, G = kpi_each(F1, self.Js_each, M0=self.M0)
        n = q.shape[0]
        return values, np.einsum("Knak,njak->Knj", G.reshape(len(values), n, -1, F1.shape[1]), dF1)

    def value_and_grad(self, q: np.ndarray, *, frames: Frames | None = None) -> tuple[float, np.ndarray]:
        """Criterion and its gradient (n, 6) w.r.t. the joint angles [criterion units / rad].

        ``d phi/d q[k, j] = sum_{a, c} (d phi/d F1)[3k + a, c] * (d F1[3k + a, c] / d q[k, j])``.
        Worst case: the largest variance and the gradient of that one (a subgradient).
        """
        if self.worst_case:
            values, grads = self.values_and_grads(q, frames=frames)
            k = int(np.argmax(values))
            return float(values[k]), grads[k]
        q = as_poses(q, self.problem.robot.n_joints)
        F1, dF1 = self.problem.F1(q, with_dq=True, frames=frames)  # (3n, k), (n, 6, 3, k)
        value, G = self.criterion.evaluate(F1, self.Js, self.scale, M0=self.M0)
        n = q.shape[0]
        grad = np.einsum("nak,njak->nj", G.reshape(n, -1, F1.shape[1]), dF1)
        return value, grad

    def normalisation(self, value: float) -> float:
        """Size against which changes of the criterion near ``value`` are measured (the solver's
        cost scale, a sweep's relative change):
        :meth:`~kpioed_drake.estimation.criteria.Criterion.normalisation`."""
        return self.criterion.normalisation(value, self.problem.n_params)
