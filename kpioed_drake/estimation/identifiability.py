"""Identifiability of the estimated parameters (SPEC: "Parameters and criteria").

A column-pivoted QR of the identification Jacobian F1 at random poses, with columns normalised to
unit length (so millimetres and radians compare), tells which parameters the measurements
determine: the numerical rank, the singular values, and the parameters that trail the pivoting
order when the rank is short. The same check serves the shipped robots (a test) and a user's own
robot (``kpioed info``).

:func:`undetermined_parameters` applies the same test to the user's own poses before a calibration
(:func:`kpioed_drake.calibration.calibrate`): the parameters beyond the near-rank
(``NEAR_RANK_RTOL``) and, of every pair whose a-priori correlation exceeds ``MAX_CORRELATION`` in
magnitude, the less determined one (the later in the parameter order when the two are tied,
``CORRELATION_TIE``) are held at nominal, so a calibration never writes values the data do not
determine (e.g. the wrist parameters of a reflector on joint 6's axis).

:func:`identifiability` and :func:`projected_basis` say how far a candidate effect's columns reach
outside a model's span (the diagnosis's "absorbed" test and its alternatives).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.linalg

from kpioed_drake.robot.chain import ORIENTATION_ROW_MM
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.tracker.kpi import check_measure
from kpioed_drake.tracker.measurement import measurement_jacobian, nominal_model
from kpioed_drake.tracker.orientation import angular_jacobian, with_probe

NEAR_RANK_RTOL = 1e-3
"""Relative threshold on the diagonal of R (QR with column pivoting of the column-normalised
Jacobian): columns whose diagonal is below this times the largest are not determined. On the kr16
a design's determined columns lie decades above it and a reflector on joint 6's axis decades below;
a reflector slightly off the axis is left to the correlation test (docs/design.md)."""
MAX_CORRELATION = 0.999
"""Pairs of parameters whose a-priori correlation exceeds this in magnitude are not separable."""
CORRELATION_TIE = 1e-4
"""Correlation magnitudes closer than this are tied when :func:`undetermined_parameters` chooses which
pair to break first (pairs) and which member of a pair to hold (each member's multiple correlation
with all the other parameters, ``sqrt(1 - 1 / C_ii)``): tied candidates are taken in the parameter
order (the given columns'), so every machine holds the same one. Below it the choice would follow
the last digits of the Jacobian: the column-pivoting order of unit columns starts from norms equal
to rounding (lift7, base-compliance seed 91: tracker_ry 0.999680, tracker_z 0.999696, their pair
-0.99924, held one or the other by machine). Differences of 1e-4 near 0.9997 are stds within about
15 % of each other: both members are about equally undetermined and holding either is a gauge."""


@dataclasses.dataclass
class IdentifiabilityReport:
    """Result of :func:`check_identifiability`.

    Attributes:
        n_candidates: number of parameters tested.
        rank: numerical rank of the column-normalised Jacobian.
        singular_values: normalised singular values, largest first (largest = 1).
        unidentifiable: names of parameters the QR pivoting puts beyond the rank.
        names: the tested parameter names.
    """

    n_candidates: int
    rank: int
    singular_values: np.ndarray
    unidentifiable: list[str]
    names: list[str]

    @property
    def identifiable(self) -> bool:
        return self.rank == self.n_candidates


def check_identifiability(
    robot: Robot,
    cell: Cell,
    *,
    n_poses: int = 60,
    seed: int = 0,
    rtol: float = 1e-8,
    all_params: bool = False,
    measure: str = "point",
) -> IdentifiabilityReport:
    """Rank test of F1 at ``n_poses`` random poses drawn uniformly within the joint limits.

    Args:
        all_params: test every parameter of the vector (33 for six joints) instead of the
            estimated ones (27; shows the 6 gauge parameters that trade against others).
        measure: ``point``, or ``pose``: a 6-DoF probe's orientation rows too (times
            :data:`~kpioed_drake.robot.chain.ORIENTATION_ROW_MM`), the probe's rotations and the
            gauge with orientations (:func:`~kpioed_drake.tracker.orientation.with_probe`).
    """
    model = nominal_model(robot, cell)
    check_measure(measure, None, 0.0, n_targets=model.layout.n_targets, n_effects=0)
    pose = measure == "pose"
    model = with_probe(model) if pose else model
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.lower, robot.upper, size=(n_poses, robot.n_joints))
    T = model.layout.n_targets  # several targets: every pose measures each of them
    target = None if T == 1 else np.tile(np.arange(T), n_poses)
    _, H = measurement_jacobian(model, q if T == 1 else np.repeat(q, T, axis=0), target=target)
    cols = np.arange(H.shape[2]) if all_params else model.layout.free
    if pose:
        H = np.concatenate([H, ORIENTATION_ROW_MM * angular_jacobian(model, q)], axis=1)
    F = unit_columns(H[:, :, cols].reshape(H.shape[0] * H.shape[1], -1))
    _, R, piv = scipy.linalg.qr(F, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > rtol * d[0]))
    s = np.linalg.svd(F, compute_uv=False)
    names = [model.layout.names[i] for i in cols]
    return IdentifiabilityReport(
        n_candidates=len(cols),
        rank=rank,
        singular_values=s / s[0],
        unidentifiable=[names[i] for i in piv[rank:]],
        names=names,
    )


ZERO_COLUMN_RTOL = 1e-9
"""A column whose norm is below this fraction of the largest column norm is zero up to rounding (a
parameter the measurement does not depend on): :func:`unit_columns` leaves it zero rather than
scaling it to unit length, so it counts as undetermined."""


def unit_columns(J: np.ndarray) -> np.ndarray:
    """``J`` (m, k) with unit columns, columns that are zero up to rounding (norm at most
    :data:`ZERO_COLUMN_RTOL` times the largest) set to zero (scaled to unit length they would count as
    independent directions of rounding noise)."""
    norms = np.linalg.norm(J, axis=0)
    live = norms > ZERO_COLUMN_RTOL * max(float(norms.max(initial=0.0)), 1e-300)
    return np.where(live, J / np.where(live, norms, 1.0), 0.0)


@dataclasses.dataclass(frozen=True)
class CorrelatedPair:
    """A pair of parameters the poses do not separate (a-priori correlation above ``MAX_CORRELATION``).

    Attributes:
        held: the member held (not estimated): the one with the larger multiple correlation with
            the other parameters, or the later in the parameter order when tied.
        partner: the member kept.
        correlation: their a-priori correlation (signed).
        tied: the members' multiple correlations are within ``CORRELATION_TIE``: either could be
            held, ``held`` is the later in the parameter order.
    """

    held: str
    partner: str
    correlation: float
    tied: bool = False

    def text(self) -> str:
        """The pair and its correlation, both names first when tied (neither is the clear one)."""
        if self.tied:
            return f"{self.held} and {self.partner} (correlation {self.correlation:+.6f})"
        return f"{self.held} (correlation {self.correlation:+.6f} with {self.partner})"

    def describe(self) -> str:
        """:meth:`text`, saying which member is held when they are tied."""
        if self.tied:
            return (
                f"{self.held} and {self.partner} (correlation {self.correlation:+.6f}; tied, {self.held} "
                "held as the later in the parameter order)"
            )
        return self.text()


@dataclasses.dataclass(frozen=True)
class Undetermined:
    """Result of :func:`undetermined_parameters`: the parameters to hold at nominal, and why.

    Attributes:
        rank: names beyond the near-rank of the column-normalised Jacobian, in pivoting order.
        correlated: every pair found above ``MAX_CORRELATION``, in the order they were broken
            (:attr:`CorrelatedPair.held` is the one held at nominal).
    """

    rank: tuple[str, ...] = ()
    correlated: tuple[CorrelatedPair, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter to hold at nominal."""
        return self.rank + tuple(c.held for c in self.correlated)

    def describe(self) -> str:
        """Which parameters and why, one clause per reason."""
        parts = []
        if self.rank:
            parts.append(f"{', '.join(self.rank)} (Jacobian rank deficient)")
        parts += [c.describe() for c in self.correlated]
        return "; ".join(parts)


def undetermined_parameters(
    J: np.ndarray,
    names: Sequence[str],
    *,
    rtol: float = NEAR_RANK_RTOL,
    max_correlation: float = MAX_CORRELATION,
) -> Undetermined:
    """The parameters a weighted Jacobian does not determine.

    QR with column pivoting of ``J`` with unit columns: the columns past the first diagonal entry
    below ``rtol`` times the largest are not determined. Of the others, while some pair's a-priori
    correlation (from ``C = (F^T F)^-1``) exceeds ``max_correlation`` in magnitude, one member of the
    most correlated pair is dropped too (:func:`_break_pair`: the less determined one; ties within
    ``CORRELATION_TIE`` go by the order of ``names``, never by the pivoting).

    Args:
        J: (m, k) weighted Jacobian of the estimated parameters (m >= k) [1 / parameter unit].
        names: (k,) their names, in the parameter order (ties are broken by it).
        rtol: near-rank threshold on R's diagonal, relative to the largest.
        max_correlation: correlation magnitude above which a pair is not separable.

    Returns:
        :class:`Undetermined` (empty when every parameter is determined).
    """
    F = unit_columns(J)
    _, R, piv = scipy.linalg.qr(F, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.argmax(d <= rtol * d[0])) if np.any(d <= rtol * d[0]) else d.size
    keep = sorted(piv[:rank].tolist())  # the parameter order: ties are broken by it
    correlated = []
    while len(keep) > 1:
        pair = _break_pair(F[:, keep], max_correlation)
        if pair is None:
            break
        held, partner, r, tied = pair
        correlated.append(CorrelatedPair(names[keep[held]], names[keep[partner]], r, tied))
        del keep[held]
    return Undetermined(rank=tuple(names[i] for i in piv[rank:]), correlated=tuple(correlated))


def _break_pair(F: np.ndarray, max_correlation: float):
    """The pair of columns of ``F`` (unit columns, in the parameter order) to break next.

    The most correlated pair above ``max_correlation`` (of pairs within ``CORRELATION_TIE`` of the
    largest magnitude, the first in the order); of it the member with the larger multiple correlation
    with all the other columns (``sqrt(1 - 1 / C_ii)``: the larger a-priori std) is held, the later
    one when the two are within ``CORRELATION_TIE``.

    Returns:
        (held, partner, correlation, tied): column indices into ``F``, the pair's correlation and
        whether its members were tied; None when no pair exceeds ``max_correlation``.
    """
    C = np.linalg.inv(F.T @ F)
    s = np.sqrt(np.diag(C))
    corr = C / np.outer(s, s)
    upper = np.abs(np.triu(corr, 1))
    top = float(upper.max())
    if top <= max_correlation:
        return None
    pairs = np.argwhere(upper > top - CORRELATION_TIE)  # row-major: the first pair in the order
    i, j = (int(k) for k in pairs[0])
    multiple = np.sqrt(np.clip(1.0 - 1.0 / np.diag(C)[[i, j]], 0.0, 1.0))
    tied = bool(abs(multiple[0] - multiple[1]) < CORRELATION_TIE)
    held, partner = (j, i) if tied or multiple[1] > multiple[0] else (i, j)
    return held, partner, float(corr[i, j]), tied


# Separation of candidate columns from a model's (the diagnosis's absorbed test)
def model_factors(J_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, R)``: thin QR of the model's weighted columns (m, p) scaled to unit norm (a zero one kept)."""
    D = np.linalg.norm(J_model, axis=0)
    D[D == 0] = 1.0
    return np.linalg.qr(J_model / D)


def identifiability(
    J_model: np.ndarray, J_cand: np.ndarray, *, factors: tuple[np.ndarray, np.ndarray] | None = None
) -> dict:
    """How well candidate columns separate from the model's columns (both weighted, (m, .)).

    Returns ``remaining`` (smallest singular value of the candidate's orthonormalised columns after
    projecting out the model's span: 1 = orthogonal, 0 = absorbed), ``max_corr`` (largest canonical
    correlation with the model's columns, ``sqrt(1 - remaining^2)``) and ``condition`` (of the
    column-scaled joint matrix, from its R factor: ``[J_model/D, J_cand/D_c] = [Q, Q_2] [[R, B],
    [0, R_2]]``; LAPACK's 1-norm estimate ``trcon``, within a factor of the size of the 2-norm's).
    ``factors``: :func:`model_factors` of ``J_model``, computed once per step.
    """
    Q, R1 = model_factors(J_model) if factors is None else factors
    Dc = np.linalg.norm(J_cand, axis=0)
    if np.any(Dc == 0):
        return {"remaining": 0.0, "max_corr": 1.0, "condition": float("inf")}
    Qc, _ = np.linalg.qr(J_cand / Dc)
    sv = np.linalg.svd(Qc - Q @ (Q.T @ Qc), compute_uv=False)
    remaining = float(sv.min())
    B = Q.T @ (J_cand / Dc)
    _, R2 = np.linalg.qr(J_cand / Dc - Q @ B)
    R = np.block([[R1, B], [np.zeros((R2.shape[0], R1.shape[1])), R2]])
    rcond, info = scipy.linalg.lapack.dtrcon(R, norm="1", uplo="U") if R.size else (1.0, 0)
    return {
        "remaining": remaining,
        "max_corr": float(np.sqrt(max(0.0, 1.0 - remaining**2))),
        "condition": float(1.0 / rcond) if info == 0 and rcond > 0 else float("inf"),
    }


def projected_basis(Q: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Orthonormal basis (m, <= k) of the part of the columns C (m, k) outside the span of the
    orthonormal Q (m, p): the directions in which a candidate moves the fit's residuals."""
    Cp = C - Q @ (Q.T @ C)
    Qc, sv, _ = np.linalg.svd(Cp, full_matrices=False)
    keep = sv > 1e-9 * max(sv.max(), 1e-300)
    return Qc[:, keep]


def trades_against(
    J_kept: np.ndarray, owners: Sequence[str], J_cand: np.ndarray, *, k: int = 3
) -> tuple[list[str], float]:
    """What candidate columns trade against among a model's columns (both weighted, (m, .)).

    Each candidate column, scaled to unit length, is written as the least-squares combination of the
    model's unit columns (minimum norm); the owners of the columns with the largest weights (the
    largest over the candidate's columns, at least a tenth of the largest) are what the candidate
    trades against: the data change them to mimic it.

    Args:
        J_kept: (m, p) the model's columns.
        owners: (p,) who each column belongs to (a parameter name, or the effect a column is of);
            columns of one owner count as one.
        J_cand: (m, c) the candidate's columns.
        k: most owners returned.

    Returns:
        (owners, share): the owners, largest weight first, and the share of the candidate's
        signature within the model's span, ``1 - remaining^2`` of :func:`identifiability` (1: a
        combination of the model's columns; a zero column counts as 1).
    """
    if J_kept.shape[1] == 0:
        return [], 0.0
    A = unit_columns(J_kept)
    C = unit_columns(J_cand)
    weights = np.abs(np.linalg.lstsq(A, C, rcond=None)[0]).max(axis=1)  # (p,)
    best: dict[str, float] = {}
    for owner, w in zip(owners, weights, strict=True):
        best[owner] = max(best.get(owner, 0.0), float(w))
    ranked = sorted(best.items(), key=lambda item: -item[1])
    top = ranked[0][1] if ranked else 0.0
    names = [o for o, w in ranked[:k] if top > 0 and w >= 0.1 * top]
    remaining = identifiability(J_kept, J_cand)["remaining"]
    return names, float(1.0 - remaining**2)


def pose_identifiability(robot: Robot, cell: Cell) -> dict | None:
    """What a 6-DoF probe's orientations determine beyond points (``kpioed info``): the rank with
    orientation rows (``n_params``, ``identifiable``) and the parameters they ``add`` to the points'
    estimated set (the probe's three rotations, and what an on-axis reflector leaves: a model file's
    ``extra_gauge``); None for several targets (pose measurements take one probe)."""
    if robot.n_targets > 1:
        return None
    rep = check_identifiability(robot, cell, measure="pose")
    points = set(parameter_layout(robot).free_names)
    added = [n for n in with_probe(nominal_model(robot, cell)).layout.free_names if n not in points]
    return {"n_params": rep.rank, "identifiable": rep.identifiable, "added": added}
