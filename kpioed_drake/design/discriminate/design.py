"""Designs that tell two explanations apart (T-optimality, Atkinson and Fedorov 1975).

Two competing explanations A and B of a discrepancy (effects of :mod:`kpioed_drake.effects`, e.g.
``joint_scale:2`` and ``gear_cyclic:2:1``) are told apart by the likelihood-ratio test of A on top
of the geometry and B (A true: does the data need A beyond B?) and the same test the other way. If
A is true with parameters ``theta_A`` (k_A,), the test statistic is non-central chi-square with
k_A degrees of freedom and non-centrality

    lambda_A = theta_A^T J_A^T (I - P_[G, B]) J_A theta_A / sigma^2
             = theta_A^T (C_AA)^-1 theta_A,

``P_[G, B]`` the projector on the weighted columns of the geometry and B, ``C_AA`` the block of A
in the covariance ``Cp = (F1^T F1)^-1`` of the model with geometry, A and B (Schur complement).
Its power at level alpha is ``P(chi2_kA(lambda_A) > chi2_{kA, 1-alpha})``.

The design maximises the smaller of the two non-centralities through a linear functional of
``Cp``, the form of the KPI criterion: each explanation h gives "KPI rows" ``w_h`` on its
parameters and the variance ``v_h = sum_rows w^T Cp w``; the worst of the two (the KPI's worst
case, an epigraph in :class:`~kpioed_drake.design.exact.program.DesignProgram`) is minimised with the
same collision avoidance, constraints and solvers as the KPI design.

- The size of h given (``joint_scale:2=300``; all its parameters): one row
  ``w = theta / |theta|^2``, so ``v = theta^T C theta / |theta|^4``. For one parameter
  ``v = 1 / lambda`` exactly; for several, ``1 / v <= lambda`` (Cauchy-Schwarz).
- No size given: the amplitude ``|theta|`` of
  :data:`~kpioed_drake.design.discriminate.explanations.DEFAULT_SIZES` in an unknown direction: rows
  ``e_i / |theta|``, ``v = tr(C_hh) / |theta|^2``, and ``1 / v`` is a lower bound of the worst
  direction's ``lambda = |theta|^2 lambda_min(C_hh^-1)``, which is what is reported.

A backlash's signature ``sign(tau_i)`` jumps where the gravity torque changes sign and has no
derivative to follow: the criterion uses ``tanh(tau_i / tau0)`` instead
(:data:`BACKLASH_SMOOTHING`); the reported non-centralities use the sign.

Effects that need per-pose conditions (temperature: ``thermal_expansion``, ``tracker_scale``;
time: ``tracker_drift``) cannot be told apart by poses alone: :func:`discrimination_design` refuses
them with the span an even ramp of the condition would need
(:func:`~kpioed_drake.design.discriminate.explanations.condition_spread`); ``kpioed design`` gives them a
measurement plan instead, poses and their conditions (:mod:`~kpioed_drake.design.discriminate.conditions`,
:func:`~kpioed_drake.design.discriminate.plan.plan_design`). Texts, sizes, non-centralities and powers:
:mod:`kpioed_drake.design.discriminate.explanations`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from kpioed_drake.design.discriminate.explanations import (
    CONDITION_FAMILIES,
    DEFAULT_ALPHA,
    OPTION,
    Pair,
    condition_message,
    condition_spread,
    discriminate_error,
    noncentralities,
    parse_pair,
    power,
)
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.optimize import optimize_design
from kpioed_drake.design.report import DesignError, DesignReport
from kpioed_drake.effects import extension_columns, gravity_torques, reference_poses
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem
from kpioed_drake.robot.kinematics import Frames
from kpioed_drake.tracker.measurement import measurement_jacobian

BACKLASH_SMOOTHING = 0.05
"""A backlash's signature ``sign(tau_i)`` is smoothed in the design criterion to
``tanh(tau_i / tau0)``, tau0 = this fraction of the largest |tau_i| over the joint box."""


@dataclasses.dataclass(frozen=True)
class DiscriminationProblem(Problem):
    """The identification problem of geometry, any further extensions and A, B, whose "working
    poses" are the two explanations: :meth:`Js_each` gives their rows ``w_h`` (K = 2, worst case),
    so every KPI design tool minimises ``max(v_A, v_B)`` (module docstring) unchanged."""

    rows: np.ndarray | None = None
    """(2, 3, k) rows ``sqrt(3) w_h`` (up to 3 per explanation) on the extended parameter vector."""
    backlash_tau0: tuple = ()
    """Per backlash extension (column, joint, tau0 [N m]): the design smooths its signature
    ``sign(tau_i)`` (zero derivative, jumps where tau_i = 0: SNOPT stalls there) to
    ``tanh(tau_i / tau0)``; the reported non-centralities use the sign."""

    @property
    def n_kpis(self) -> int:
        return int(self.rows.shape[0])

    def Js_each(self) -> np.ndarray:
        return self.rows

    def F1(
        self, q: np.ndarray, *, with_dq: bool = False, frames: Frames | None = None
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        return self.smoothed(q, super().F1(q, with_dq=with_dq, frames=frames), with_dq=with_dq, frames=frames)

    def smoothed(
        self,
        q: np.ndarray,
        out: np.ndarray | tuple[np.ndarray, np.ndarray],
        *,
        with_dq: bool = False,
        frames: Frames | None = None,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """``out`` (F1 (3n, k), with ``with_dq`` also dF1 (n, 6, 3, k)) of the poses ``q`` with each
        backlash column replaced by its smoothed signature (:attr:`backlash_tau0`)."""
        if not self.backlash_tau0:
            return out
        F1, dF1 = (out[0].copy(), out[1].copy()) if with_dq else (out.copy(), None)
        q = np.atleast_2d(q)
        n = q.shape[0]
        H, *dH = measurement_jacobian(self.model, q, with_dq=with_dq, frames=frames)[1:]
        tau = gravity_torques(self.robot, q, p_FP=self.model.p_FQ, with_dq=with_dq)
        tau, dtau = tau if with_dq else (tau, None)
        F3 = F1.reshape(n, 3, -1)
        for col, joint, tau0 in self.backlash_tau0:
            c = self.model.layout.joint_angle(joint)
            th = np.tanh(tau[:, joint - 1] / tau0)
            G = H[:, :, c] / self.sigma  # (n, 3) the joint's angle column
            F3[:, :, col] = G * th[:, None]
            if with_dq:
                dth = (1.0 - th**2)[:, None] * dtau[:, joint - 1, :] / tau0  # (n, 6)
                dF1[:, :, :, col] = dH[0][:, :, :, c] / self.sigma * th[:, None, None]
                dF1[:, :, :, col] += dth[:, :, None] * G[:, None, :]
        return (F1, dF1) if with_dq else F1


def _offsets(problem: Problem) -> list[int]:
    """Index of each extension's first parameter in the extended parameter vector."""
    start = problem.model.layout.n_free
    out = []
    for e in problem.extensions:
        out.append(start)
        start += e.n_params
    return out


def explanation_indices(problem: Problem, pair: Pair) -> list[np.ndarray]:
    """For each explanation, the indices of its parameters in ``problem``'s parameter vector."""
    keys = [e.key for e in problem.extensions]
    offs = _offsets(problem)
    out = []
    for h in pair:
        i = keys.index(h.effect.key)
        out.append(offs[i] + np.arange(h.effect.n_params))
    return out


def discrimination_problem(base: Problem, pair: Pair) -> DiscriminationProblem:
    """The :class:`DiscriminationProblem` of ``base`` (extended by both explanations)."""
    rows = np.zeros((2, 3, base.n_params))
    for r, (h, idx) in enumerate(zip(pair, explanation_indices(base, pair), strict=True)):
        theta = h.theta
        size = float(np.linalg.norm(theta))
        if h.direction_known:
            rows[r, 0, idx] = theta / size**2
        else:
            rows[r, np.arange(len(idx)), idx] = 1.0 / size
    smooth = []
    for e, off in zip(base.extensions, _offsets(base), strict=True):
        if e.family == "backlash":
            tau = gravity_torques(base.robot, reference_poses(base.robot), p_FP=base.model.p_FQ)
            smooth.append((off, e.joint, BACKLASH_SMOOTHING * float(np.max(np.abs(tau[:, e.joint - 1])))))
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Problem)}
    fields.update(kpi_weights=None, kpi_aggregate="max")
    return DiscriminationProblem(**fields, rows=np.sqrt(3.0) * rows, backlash_tau0=tuple(smooth))


def assessment(base: Problem, pair: Pair, q: np.ndarray, *, alpha: float = DEFAULT_ALPHA) -> dict:
    """Non-centrality and power of both tests for the poses ``q`` (n, 6) [rad]."""
    F1 = base.F1(np.atleast_2d(q))
    return tests_record(
        pair, noncentralities(F1, explanation_indices(base, pair), pair), len(np.atleast_2d(q)), alpha
    )


def tests_record(pair: Pair, lam: np.ndarray, n: int, alpha: float) -> dict:
    """``n_poses`` and per explanation its test, ``lambda`` (of ``lam`` (2,)), ``df`` and ``power``."""
    out = {"n_poses": int(n)}
    for h, other, x in zip(pair, pair[::-1], lam, strict=True):
        out[h.effect.name] = {
            "test": f"{h.effect.name} true: needed on top of the geometry and {other.effect.name}",
            "lambda": float(x),
            "df": h.effect.n_params,
            "power": power(x, h.effect.n_params, alpha),
        }
    return out


@dataclasses.dataclass
class DiscriminationReport(DesignReport):
    """A :class:`DesignReport` of a discrimination design with its ``discrimination`` record
    (pair, assumed sizes, non-centrality and power of both tests before and after)."""

    discrimination: dict | None = None

    def summary(self) -> dict:
        out = super().summary()
        out["discrimination"] = self.discrimination
        return out


def discrimination_lines(rec: dict) -> list[str]:
    """Printed lines of a ``discrimination`` record: the assumed sizes and, per test, the
    non-centrality and power before and after."""
    sizes = "; ".join(
        f"{name} {s['amplitude']:.4g} {s['unit']} ({s['size_source']})"
        for name, s in zip(rec["pair"], rec["assumed"], strict=True)
    )
    lines = [f"  telling apart {' and '.join(rec['pair'])} at level {rec['alpha']:g}; assumed: {sizes}"]
    before, after = rec["before"], rec["after"]
    for name in rec["pair"]:
        b, a = before[name], after[name]
        lines.append(
            f"  {name} true: lambda {b['lambda']:.3g} -> {a['lambda']:.3g}, power {b['power']:.3f} -> "
            f"{a['power']:.3f} ({before['poses']} -> {after['poses']})"
        )
    return lines


def _kpi_values(base: Problem, q) -> dict:
    """``kpi_avg_var_mm2`` and ``param_crit`` of the poses ``q`` in the extended model (NaN where
    they do not determine its parameters)."""
    try:
        return base.criteria(q)
    except InputError:
        return {"kpi_avg_var_mm2": float("nan"), "param_crit": float("nan")}


def checked_pair(problem: Problem, pair_text: str, alpha: float) -> Pair:
    """The two explanations of ``pair_text`` (:func:`parse_pair`), neither also an extension of
    ``problem``, and ``alpha`` in (0, 1); else :class:`~kpioed_drake.errors.InputError`."""
    pair = parse_pair(pair_text, problem.model)
    names = {e.key for e in problem.extensions}
    for h in pair:
        if h.effect.key in names:
            raise discriminate_error(f"{h.effect.name} is also given to extend", "extend")
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha!r}")
    return pair


def heuristic_start(options: dict) -> str:
    """The optimiser's start of a discrimination design, popped from ``options``: the heuristic
    (the approximate design is one of the KPI at a working pose)."""
    start = options.pop("start", None) or "heuristic"
    if start != "heuristic":
        raise discriminate_error(f"the optimiser starts from the heuristic design (got start {start!r})")
    return start


def optimize_discrimination(
    dprob: Problem, *, n: int, given: np.ndarray | None, **options: Any
) -> DesignReport:
    """:func:`~kpioed_drake.design.optimize.optimize_design` of ``dprob``'s worst case from the
    heuristic start; a failure is reported as the discriminate design's."""
    start = heuristic_start(options)
    try:
        return optimize_design(dprob, criterion="kpi", n=n, given=given, start=start, **options)
    except DesignError as exc:
        if exc.result is not None:
            exc.result.criterion = "discriminate"
        raise DesignError(
            str(exc).replace("the kpi design", "the discriminate design"), exc.result, fields=exc.fields
        ) from None


def discrimination_design(
    problem: Problem,
    pair_text: str,
    *,
    n: int,
    given: np.ndarray | None = None,
    alpha: float = DEFAULT_ALPHA,
    **options: Any,
) -> tuple[DiscriminationReport, Problem]:
    """Poses that tell the two explanations of ``pair_text`` apart (module docstring).

    Args:
        problem: the identification problem (its extensions are estimated too, as nuisance).
        pair_text: ``"A|B"`` (:func:`parse_pair`).
        n: new poses.
        given: (m, 6) [rad] poses already measured (the first data set): held fixed; "before" is
            them alone. None: "before" is the heuristic design of ``n`` poses with the same seed.
        alpha: level of the tests.
        options: further arguments of :func:`~kpioed_drake.design.optimize.optimize_design`
            (``collision``, ``solver``, ``seed``, ``starts``, ``allow_infeasible``, ``start``).

    Returns:
        the result (its ``kpi_avg_var_mm2``, ``param_crit`` those of the extended model) and the
        extended problem (geometry, extensions, A, B).

    Raises:
        InputError: a bad pair (:func:`parse_pair`), an effect that needs per-pose conditions (with
            the span of temperature or time the data needs), other bad arguments.
    """
    pair = checked_pair(problem, pair_text, alpha)
    seed, collision = int(options.get("seed", 0)), options.get("collision", True)
    if any(h.effect.family in CONDITION_FAMILIES for h in pair):
        n_q = max(n, problem.min_poses())
        q = given if given is not None else heuristic_design(problem, n=n_q, seed=seed, collision=collision)
        spans = condition_spread(problem, pair, q, alpha=alpha)
        source = "given" if given is not None else "heuristic"
        raise InputError(condition_message(pair, spans, len(q), source, alpha), fields=(OPTION,))
    zero = [dataclasses.replace(h.effect, values=None) for h in pair]  # columns at zero, as in a design
    base = dataclasses.replace(problem, extensions=(*problem.extensions, *zero))
    probe = heuristic_design(base, n=base.min_poses(), seed=0, collision=False)
    for h in pair:
        if not np.any(extension_columns(base.model, probe, [h.effect])):
            raise discriminate_error(f"{h.effect.name} does not change the measurements of {base.robot.name}")
    dprob = discrimination_problem(base, pair)
    q_before = given if given is not None else heuristic_design(base, n=n, seed=seed, collision=collision)
    before = assessment(base, pair, q_before, alpha=alpha)
    before["poses"] = "given" if given is not None else "heuristic"
    res = optimize_discrimination(dprob, n=n, given=given, **options)
    q_all = res.q if given is None else np.concatenate([given, res.q])
    after = assessment(base, pair, q_all, alpha=alpha)
    after["poses"] = "given + design" if given is not None else "design"
    crit = _kpi_values(base, q_all)
    fields = result_fields(res, crit, None if given is None else _kpi_values(base, given))
    criterion = (
        "the larger of v_A, v_B; 1/v_h <= lambda_h, a backlash's signature smoothed "
        "(kpioed_drake.design.discriminate.design)"
    )
    record = discrimination_record(pair, alpha, criterion, res, before, after)
    return DiscriminationReport(**fields, discrimination=record), base


def result_fields(res: DesignReport, crit: dict, alone: dict | None) -> dict:
    """The fields of a discrimination result from the optimiser's ``res``: criterion
    ``discriminate``, the KPI values ``crit`` of the extended model (combined design) and, with
    given poses, their own (``alone``), not the criterion's."""
    fields = {f.name: getattr(res, f.name) for f in dataclasses.fields(DesignReport)}
    fields.update(criterion="discriminate", kpi_vars_mm2=None, **crit)
    if res.given is not None:
        fields["given"] = {
            **res.given,
            "given_kpi_avg_var_mm2": alone["kpi_avg_var_mm2"],
            "given_param_crit": alone["param_crit"],
        }
    return fields


def discrimination_record(
    pair: Pair, alpha: float, criterion: str, res: DesignReport, before: dict, after: dict
) -> dict:
    """The ``discrimination`` record: pair, assumed sizes, level, criterion, ``1/v_h`` of the
    optimiser's ``res``, and both tests ``before`` and ``after``."""
    return {
        "pair": [h.effect.name for h in pair],
        "assumed": [h.to_dict() for h in pair],
        "alpha": alpha,
        "criterion": criterion,
        "criterion_inverse_v": [1.0 / v for v in (res.kpi_vars_mm2 or [float("nan")] * 2)],
        "before": before,
        "after": after,
    }
