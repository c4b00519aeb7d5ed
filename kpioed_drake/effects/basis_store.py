"""The mass-free bases a robot carries: sized on a data set's poses or stored in its model file.

A basis (``D`` the column scales, ``V`` the identifiable directions of the scaled first mass
moments, :mod:`.gravity_basis`, :mod:`.lateral_basis`) belongs to the robot object it was sized for
(``Robot.gravity_bases``, keyed by the effect's name, e.g. ``joint_elasticity_basis:3``), never to
the process: another data set of the same robot starts from the reference basis again.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.robot.models import Robot


@dataclasses.dataclass(frozen=True)
class ReducedBasis:
    """One joint's identifiable basis of scaled moments (gravity's or a lateral compliance's).

    Attributes:
        joint: 1-based joint.
        D: (p,) RMS of each column over the reference poses' rows.
        V: (p, r) the identifiable directions of the scaled moments (orthonormal).
    """

    joint: int
    D: np.ndarray
    V: np.ndarray

    @property
    def rank(self) -> int:
        """r, the identifiable directions' count."""
        return self.V.shape[1]


def own_basis(robot: Robot, name: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(D, V)`` of the basis ``robot`` carries for the effect ``name`` (e.g.
    ``joint_elasticity_basis:3``): its ``gravity_bases`` (sized on data), then its model file's
    ``effects:`` entry; None if it has none."""
    for key, D, V in robot.gravity_bases:
        if key == name:
            return np.asarray(D, dtype=float), np.asarray(V, dtype=float).reshape(len(D), -1)
    for spec in robot.effects:
        if spec.name == name and spec.basis_rms:
            D = np.asarray(spec.basis_rms, dtype=float)
            return D, np.asarray(spec.basis_directions, dtype=float).reshape(len(D), -1)
    return None


def with_basis(robot: Robot, name: str, D: np.ndarray, V: np.ndarray) -> Robot:
    """``robot`` with ``D`` (p,), ``V`` (p, r) as the basis of the effect ``name`` (``robot``
    itself unchanged)."""
    bases = {key: (key, d, v) for key, d, v in robot.gravity_bases}
    bases[name] = (name, np.asarray(D, dtype=float), np.asarray(V, dtype=float))
    return dataclasses.replace(robot, gravity_bases=tuple(bases[k] for k in sorted(bases)))
