"""Identifiability of the estimated parameters (SPEC: "Parameters and criteria").

A column-pivoted QR of the identification Jacobian F1 at random poses, with columns normalised to
unit length (so millimetres and radians compare), tells which parameters the measurements
determine: the numerical rank, the singular values, and the parameters that trail the pivoting
order when the rank is short. The same check serves the shipped robots (a test) and a user's own
robot (``kpioed info``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg

from kpioed_drake.measurement import measurement_jacobian, nominal_model
from kpioed_drake.models import Cell, Robot


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
    q = rng.uniform(robot.lower, robot.upper, size=(n_poses, 6))
    _, H = measurement_jacobian(model, q)
    cols = np.arange(H.shape[2]) if all_params else model.layout.free
    F = H[:, :, cols].reshape(3 * n_poses, -1)
    F = F / np.maximum(np.linalg.norm(F, axis=0), 1e-300)
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
