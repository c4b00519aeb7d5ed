"""Where a design's solves start: the start method of each solve and its starting poses.

Starts (:data:`~kpioed_drake.design.settings.START_METHODS`): the paper's heuristic
(:mod:`~kpioed_drake.design.heuristic`), or for the ``kpi`` criterion the approximate design
(column generation over the feasible poses, Clarabel) rounded to n poses
(:func:`~kpioed_drake.design.approximate.design.approximate_start`); with poses held fixed, the
certified approximate design's candidates chosen with their information
(:func:`~kpioed_drake.design.approximate.sequential.given_start`), and as a second start the same
rounding over the candidates of the approximate design made with their information
(:func:`~kpioed_drake.design.approximate.given.given_design`): neither start wins on every set of
measured poses (docs/online.md). The approximate design is the optimum of the KPI criterion over
weights on poses; it is not defined for the other criteria's objectives, so ``start="approximate"``
is an input error there.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.design.approximate import certificate
from kpioed_drake.design.approximate.design import ApproximateDesign, approximate_start, start_approximation
from kpioed_drake.design.approximate.given import given_design
from kpioed_drake.design.approximate.sequential import given_start
from kpioed_drake.design.heuristic import heuristic_design
from kpioed_drake.design.settings import DEFAULT_START, START_METHODS
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem


def resolve_start(
    start: str | None, criterion: str, *, given: np.ndarray | None = None, worst_case: bool = False
) -> str:
    """The start method of :func:`~kpioed_drake.design.optimize.optimize_design`: ``start``, or for
    None :data:`~kpioed_drake.design.settings.DEFAULT_START` where it applies (``kpi`` criterion, not
    the worst case of several working poses, whose approximate design would be that of their mean)
    and else ``heuristic``.

    Raises:
        InputError: an unknown start, or ``approximate`` for another criterion than ``kpi``.
    """
    if start is None:
        applies = criterion == "kpi" and not worst_case
        return DEFAULT_START if applies else "heuristic"
    if start not in START_METHODS:
        raise InputError(
            f"unknown start {start!r}; expected one of {', '.join(START_METHODS)}", fields=("start",)
        )
    if start == "approximate" and criterion != "kpi":
        raise InputError(
            f"start 'approximate' is the approximate KPI design: it needs criterion 'kpi', not {criterion!r}",
            fields=("start", "criterion"),
        )
    return start


def start_methods(start: str, starts: int, *, given: np.ndarray | None, q0: np.ndarray | None) -> list[str]:
    """The start method of each solve: ``q0`` first if given; with ``given`` poses and the
    approximate start, its two roundings (``approximate``: the certified design's candidates;
    ``given``: those of the approximate design with the measured information) count as one start,
    and further starts are heuristic (one certified design); else ``start`` each time."""
    first = "q0" if q0 is not None else start
    if given is None:
        return [first] + [start] * (starts - 1)
    two = [first, "given"] if first == "approximate" else [first]
    return two + ["heuristic"] * (starts - 1)


def start_poses(
    problem: Problem,
    start: str,
    *,
    n: int,
    seed: int,
    collision: bool,
    given: np.ndarray | None = None,
    approx: ApproximateDesign | None = None,
) -> tuple[np.ndarray, ApproximateDesign | None]:
    """(n, n_joints) [rad] starting poses of the method ``start`` with seed ``seed``, and the
    approximate design behind them (its candidates ``q`` and rows ``F``; None for the heuristic);
    with ``given`` poses the approximate start is the certified approximate design's candidates
    chosen with their information (:func:`~kpioed_drake.design.approximate.sequential.given_start`).
    ``approx``: the approximate design to round (None: :func:`start_approximation`)."""
    if start in ("approximate", "given") and given is not None:
        approx = certificate.certified_design(problem, collision=collision, seed=seed)
        if start == "given":
            approx = given_design(problem, approx, given=given, n=n, collision=collision)
        return given_start(problem, approx, n=n, given=given), approx
    if start == "approximate":
        if approx is None:
            approx = start_approximation(problem, collision=collision, seed=seed)
        return approximate_start(problem, n=n, collision=collision, seed=seed, approx=approx), approx
    return heuristic_design(problem, n=n, seed=seed, collision=collision), None


def checked_poses(
    problem: Problem, q: np.ndarray, n: int | None, name: str, *, limits: bool = True
) -> np.ndarray:
    """``q`` as a finite (n, n_joints) array (any n >= 1 if ``n`` is None), within the joint limits if
    ``limits`` (not for measured poses: they enter only through their information, and a pose
    measured at a limit comes back from a file in degrees a rounding beyond it).

    Raises:
        InputError: naming ``name``: the wrong shape, a non-finite value or a pose outside the limits.
    """
    q = np.asarray(q, dtype=float)
    nj = problem.robot.n_joints
    shape = f"({'m' if n is None else n}, {nj})"
    if q.ndim != 2 or q.shape[1] != nj or q.shape[0] != (n or q.shape[0]) or not q.size:
        raise InputError(f"{name} must be a finite {shape} array of joint angles [rad], got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InputError(f"{name} must be a finite {shape} array of joint angles [rad]")
    if limits and (np.any(q < problem.robot.lower) or np.any(q > problem.robot.upper)):
        raise InputError(f"{name}: a joint angle is outside the robot's joint limits")
    return q
