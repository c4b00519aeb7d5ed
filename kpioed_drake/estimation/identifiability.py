"""Identifiability of the estimated parameters (SPEC: "Parameters and criteria").

A column-pivoted QR of the identification Jacobian F1 at random poses, with columns normalised to
unit length (so millimetres and radians compare), tells which parameters the measurements
determine: the numerical rank, the singular values, and the parameters that trail the pivoting
order when the rank is short. The same check serves the shipped robots (a test) and a user's own
robot (``kpioed info``).

:func:`undetermined_parameters` applies the same test to the user's own poses before a calibration
(:func:`kpioed_drake.calibration.calibrate`): the parameters beyond the near-rank
(``NEAR_RANK_RTOL``) and, of every pair whose a-priori correlation exceeds ``MAX_CORRELATION`` in
magnitude, the one later in the pivoting order are held at nominal, so a calibration never writes
values the data do not determine (e.g. the wrist parameters of a reflector on joint 6's axis).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg

from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.tracker.measurement import measurement_jacobian, nominal_model

NEAR_RANK_RTOL = 1e-3
"""Relative threshold on the diagonal of R (QR with column pivoting of the column-normalised
Jacobian): columns whose diagonal is below this times the largest are not determined. On the kr16
a design's determined columns lie decades above it and a reflector on joint 6's axis decades below;
a reflector slightly off the axis is left to the correlation test (docs/design.md)."""
MAX_CORRELATION = 0.999
"""Pairs of parameters whose a-priori correlation exceeds this in magnitude are not separable."""


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
) -> IdentifiabilityReport:
    """Rank test of F1 at ``n_poses`` random poses drawn uniformly within the joint limits.

    Args:
        all_params: test every parameter of the vector (33 for six joints) instead of the
            estimated ones (27; shows the 6 gauge parameters that trade against others).
    """
    model = nominal_model(robot, cell)
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.lower, robot.upper, size=(n_poses, robot.n_joints))
    T = model.layout.n_targets  # several targets: every pose measures each of them
    target = None if T == 1 else np.tile(np.arange(T), n_poses)
    _, H = measurement_jacobian(model, q if T == 1 else np.repeat(q, T, axis=0), target=target)
    cols = np.arange(H.shape[2]) if all_params else model.layout.free
    F = unit_columns(H[:, :, cols].reshape(3 * T * n_poses, -1))
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
class Undetermined:
    """Result of :func:`undetermined_parameters`: the parameters to hold at nominal, and why.

    Attributes:
        rank: names beyond the near-rank of the column-normalised Jacobian, in pivoting order.
        correlated: ``(held, partner, correlation)`` of every pair found above ``MAX_CORRELATION``
            (``held`` is the one held at nominal).
    """

    rank: tuple[str, ...] = ()
    correlated: tuple[tuple[str, str, float], ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter to hold at nominal."""
        return self.rank + tuple(c[0] for c in self.correlated)

    def describe(self) -> str:
        """Which parameters and why, one clause per reason."""
        parts = []
        if self.rank:
            parts.append(f"{', '.join(self.rank)} (Jacobian rank deficient)")
        parts += [f"{a} (correlation {r:+.6f} with {b})" for a, b, r in self.correlated]
        return "; ".join(parts)


def undetermined_parameters(
    J: np.ndarray,
    names,
    *,
    rtol: float = NEAR_RANK_RTOL,
    max_correlation: float = MAX_CORRELATION,
) -> Undetermined:
    """The parameters a weighted Jacobian does not determine.

    QR with column pivoting of ``J`` with unit columns: the columns past the first diagonal entry
    below ``rtol`` times the largest are not determined. Of the others, while some pair's a-priori
    correlation (from ``(F^T F)^-1``) exceeds ``max_correlation`` in magnitude, the one later in the
    pivoting order (the less independent) is dropped too.

    Args:
        J: (m, k) weighted Jacobian of the estimated parameters (m >= k) [1 / parameter unit].
        names: (k,) their names.
        rtol: near-rank threshold on R's diagonal, relative to the largest.
        max_correlation: correlation magnitude above which a pair is not separable.

    Returns:
        :class:`Undetermined` (empty when every parameter is determined).
    """
    F = unit_columns(J)
    _, R, piv = scipy.linalg.qr(F, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.argmax(d <= rtol * d[0])) if np.any(d <= rtol * d[0]) else d.size
    keep = list(piv[:rank])
    correlated = []
    while len(keep) > 1:
        C = np.linalg.inv(F[:, keep].T @ F[:, keep])
        s = np.sqrt(np.diag(C))
        corr = C / np.outer(s, s)
        np.fill_diagonal(corr, 0.0)
        i, j = np.unravel_index(np.argmax(np.abs(corr)), corr.shape)
        if abs(corr[i, j]) <= max_correlation:
            break
        held, partner = (keep[j], keep[i]) if j > i else (keep[i], keep[j])
        correlated.append((names[held], names[partner], float(corr[i, j])))
        keep.remove(held)
    return Undetermined(rank=tuple(names[i] for i in piv[rank:]), correlated=tuple(correlated))
