"""Joint maps: from a controller's joint angles to the model's (the ``joint_map`` of a robot file).

A robot controller reports its own joint angles ``J``; the kinematic model (paper eq. 3,
``h(p, q)``) uses its own angles ``q``. They can differ in sign, in zero offset and, for robots
with a parallelogram or coupled axes, by a coupling such as Fanuc's ``q3 = J3 + J2``. The map is
affine,

    q = A J + b,   A = diag(sign) + C,

with ``sign_i`` = +1 or -1, ``b_i`` the offset of joint i and ``C`` the couplings (``C[i, j]`` =
``factor``: joint i's model angle gets ``factor * J_j``). It is part of the robot model file
(``models/README.md``, section ``joint_map``) so that measured data go in with the controller's
angles unchanged; :func:`kpioed_drake.tracker.formats.read_foreign` applies it.

Files hold degrees; the loaded :class:`JointMap` holds radians.
"""

import dataclasses

import numpy as np

from kpioed_drake.errors import InputError

N_JOINTS = 6


@dataclasses.dataclass
class CouplingSpec:
    """One coupling term of a joint map: model joint ``joint`` gets ``factor`` times controller
    joint ``from_joint`` (joints 1-based)."""

    joint: int = 0
    from_joint: int = 0
    factor: float = 0.0


@dataclasses.dataclass
class JointMapSpec:
    """The ``joint_map`` section of a robot file (degrees).

    Empty ``sign`` means all +1, empty ``offset_deg`` all 0.
    """

    sign: list[float] = dataclasses.field(default_factory=list)
    offset_deg: list[float] = dataclasses.field(default_factory=list)
    couplings: list[CouplingSpec] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class JointMap:
    """The affine map ``q = A J + b`` from controller angles ``J`` to model angles ``q``.

    Attributes:
        A: (6, 6) the signs on the diagonal plus the couplings [-].
        b: (6,) offsets [rad].
    """

    A: np.ndarray
    b: np.ndarray

    def to_model(self, J) -> np.ndarray:
        """Model angles of controller angles.

        Args:
            J: (n, 6) controller angles [rad].

        Returns:
            q: (n, 6) model angles [rad].
        """
        return np.asarray(J, dtype=float) @ self.A.T + self.b

    def to_controller(self, q) -> np.ndarray:
        """Controller angles of model angles (the inverse map), (n, 6) [rad]."""
        return np.linalg.solve(self.A, (np.asarray(q, dtype=float) - self.b).T).T


def _six(values, default: float, name: str, where: str) -> np.ndarray:
    if not values:
        return np.full(N_JOINTS, default)
    arr = np.asarray(values, dtype=float)
    if arr.shape != (N_JOINTS,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: joint_map.{name} must have {N_JOINTS} finite numbers, got {values!r}")
    return arr


def joint_map_from_spec(spec: JointMapSpec | None, where: str = "robot") -> JointMap | None:
    """Validate a :class:`JointMapSpec` and convert it (None stays None).

    Raises:
        InputError: naming ``where`` and the field: a sign other than +1/-1, not six signs or
            offsets, a coupling with a joint outside 1..6, coupling a joint to itself, a
            non-finite factor, or a map that cannot be inverted.
    """
    if spec is None:
        return None
    sign = _six(spec.sign, 1.0, "sign", where)
    if not np.all(np.isin(sign, (-1.0, 1.0))):
        raise InputError(f"{where}: joint_map.sign entries must be 1 or -1, got {spec.sign!r}")
    b = np.deg2rad(_six(spec.offset_deg, 0.0, "offset_deg", where))
    A = np.diag(sign)
    for k, c in enumerate(spec.couplings):
        w = f"{where}: joint_map.couplings[{k}]"
        if not (1 <= c.joint <= N_JOINTS and 1 <= c.from_joint <= N_JOINTS):
            raise InputError(
                f"{w}: joint and from_joint must be joint numbers 1..{N_JOINTS}, "
                f"got {c.joint}, {c.from_joint}"
            )
        if c.joint == c.from_joint:
            raise InputError(f"{w}: a joint cannot be coupled to itself (use sign and offset_deg)")
        if not np.isfinite(c.factor):
            raise InputError(f"{w}: factor must be finite, got {c.factor!r}")
        A[c.joint - 1, c.from_joint - 1] += c.factor
    if abs(np.linalg.det(A)) < 1e-9:
        raise InputError(f"{where}: joint_map cannot be inverted (the couplings cancel a joint)")
    return JointMap(A=A, b=b)


def joint_map_spec(joint_map: JointMap | None) -> JointMapSpec | None:
    """The file section of a loaded map (degrees), e.g. to write a model file back."""
    if joint_map is None:
        return None
    A = joint_map.A
    couplings = [
        CouplingSpec(joint=i + 1, from_joint=j + 1, factor=float(A[i, j]))
        for i in range(N_JOINTS)
        for j in range(N_JOINTS)
        if i != j and A[i, j] != 0.0
    ]
    return JointMapSpec(
        sign=np.diag(A).tolist(), offset_deg=np.rad2deg(joint_map.b).tolist(), couplings=couplings
    )
