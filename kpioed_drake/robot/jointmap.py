"""Joint maps: from a controller's joint angles to the model's (the ``joint_map`` of a robot file).

A robot controller reports its own joint angles ``J``; the kinematic model (paper eq. 3,
``h(p, q)``) uses its own angles ``q``. They can differ in sign, in zero offset and, for robots
with a parallelogram or coupled axes, by a coupling such as Fanuc's ``q3 = J3 + J2``. The map is
affine,

    q = A J + b,   A = diag(sign) + C,

with ``sign_i`` = +1 or -1, ``b_i`` the offset of joint i and ``C`` the couplings (``C[i, j]`` =
``factor``: joint i's model angle gets ``factor * J_j``). The general form names the controller's
axes (``controller_axes``, any number, possibly fewer than the model's joints, e.g. a passive joint
coupled to two others: ``q_t4 = -(J_t2 + J_t3)``) and gives each model joint as a sum of factors
times axes (``joints: {torso_3: {t2: -1, t3: -1}}``) plus an offset (``offsets_deg``); ``A`` is then
(n_joints, n_axes). It is part of the robot model file
(``models/README.md``, section ``joint_map``) so that measured data go in with the controller's
angles unchanged; the file reader (:mod:`kpioed_drake.files.tables`) applies it through
:func:`joints_from_file`.

Files hold degrees; the loaded :class:`JointMap` holds radians.

Joint values in files (every CSV the package reads or writes): one column per joint, ``q{i}_deg``
for a revolute joint [deg] and ``q{i}_mm`` for a prismatic one [mm] (:func:`q_columns`); inside,
radians and millimetres (:func:`q_from_file`, :func:`q_to_file`). :func:`check_joint_angles` names
the file, row and column of a value outside the robot's limits.
"""

import dataclasses
from collections.abc import Sequence

import numpy as np

from kpioed_drake.errors import InputError

N_JOINTS = 6
JOINT_COLUMNS = tuple(f"q{i}_deg" for i in range(1, N_JOINTS + 1))
"""Joint columns of the six-joint (revolute) robots."""


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

    Six-joint form: empty ``sign`` means all +1, empty ``offset_deg`` all 0. General form (any
    joint count): ``controller_axes`` with ``joints`` and ``offsets_deg``.
    """

    sign: list[float] = dataclasses.field(default_factory=list)
    offset_deg: list[float] = dataclasses.field(default_factory=list)
    couplings: list[CouplingSpec] = dataclasses.field(default_factory=list)
    controller_axes: list[str] = dataclasses.field(default_factory=list)
    """The controller's axes, in the order its files list them."""
    joints: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    """Model joint (its name, or its number 1..n) -> {axis: factor}; a joint not listed follows the
    axis of its own name."""
    offsets_deg: dict[str, float] = dataclasses.field(default_factory=dict)
    """Model joint -> offset [deg] (prismatic joints: [mm]) added to the sum."""


@dataclasses.dataclass(frozen=True)
class JointMap:
    """The affine map ``q = A J + b`` from controller angles ``J`` to model angles ``q``.

    Attributes:
        A: (n_joints, n_axes) the signs on the diagonal plus the couplings, or the general form's
            factors [-].
        b: (n_joints,) offsets [rad].
        axes: the controller's axis names (None: the six-joint form, axes = joints).
        joints: the model joints' names of the general form (None: the six-joint form).
        prismatic: (n_joints,) of the general form: offsets in mm, not rad.
    """

    A: np.ndarray
    b: np.ndarray
    axes: tuple[str, ...] | None = None
    joints: tuple[str, ...] | None = None
    prismatic: tuple[bool, ...] | None = None

    @property
    def n_axes(self) -> int:
        """Controller axes (columns of a controller's file)."""
        return int(self.A.shape[1])

    def to_model(self, J: np.ndarray) -> np.ndarray:
        """Model angles of controller angles.

        Args:
            J: (n, n_axes) controller angles [rad].

        Returns:
            q: (n, n_joints) model angles [rad].
        """
        return np.asarray(J, dtype=float) @ self.A.T + self.b

    def coupling_equations(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N, c)``: the poses the controller can command are those with ``N q = c`` (N (m, n_joints),
        orthonormal rows spanning what ``A`` leaves out; m = 0 when every pose can be commanded)."""
        U, s, _ = np.linalg.svd(self.A, full_matrices=True)
        rank = int(np.sum(s > 1e-12 * max(float(s.max()), 1.0))) if s.size else 0
        N = U[:, rank:].T
        return N, N @ self.b

    def to_controller(self, q: np.ndarray) -> np.ndarray:
        """Controller angles of model angles (the inverse map), (n, n_axes) [rad].

        Raises:
            InputError: a model pose the controller cannot command (with fewer axes than joints: one
                that breaks a coupling), naming its 1-based row.
        """
        d = (np.asarray(q, dtype=float) - self.b).T
        if self.A.shape[0] == self.A.shape[1]:
            return np.linalg.solve(self.A, d).T
        J, *_ = np.linalg.lstsq(self.A, d, rcond=None)
        miss = np.max(np.abs(self.A @ J - d), axis=0)
        bad = np.flatnonzero(miss > 1e-9)
        if bad.size:
            raise InputError(
                f"pose {bad[0] + 1}: its joint values break the joint map's coupling by "
                f"{miss[bad[0]]:.3g} rad; the controller cannot command it"
            )
        return J.T


def _six(values, default: float, name: str, where: str) -> np.ndarray:
    if not values:
        return np.full(N_JOINTS, default)
    arr = np.asarray(values, dtype=float)
    if arr.shape != (N_JOINTS,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: joint_map.{name} must have {N_JOINTS} finite numbers, got {values!r}")
    return arr


def _general(spec: JointMapSpec, where: str, joint_names, prismatic) -> JointMap:
    """The general form: ``controller_axes`` and per-joint sums."""
    axes = list(spec.controller_axes)
    n = len(joint_names)
    if len(set(axes)) != len(axes) or not all(str(a).strip() for a in axes):
        raise InputError(f"{where}: joint_map.controller_axes: expected distinct names, got {axes!r}")
    index = {name: i for i, name in enumerate(joint_names)} | {str(i + 1): i for i in range(n)}
    for key in [*spec.joints, *spec.offsets_deg]:
        if str(key) not in index:
            raise InputError(
                f"{where}: joint_map: {key!r} is not a joint of the robot "
                f"(its joints: {', '.join(joint_names)})"
            )
    A, b = np.zeros((n, len(axes))), np.zeros(n)
    given = {index[str(k)]: v for k, v in spec.joints.items()}
    for i, name in enumerate(joint_names):
        terms = given.get(i, {name: 1.0} if name in axes else None)
        if terms is None:
            raise InputError(
                f"{where}: joint_map.joints: joint {name!r} is not given and no controller axis has its name"
            )
        for axis, factor in terms.items():
            if axis not in axes:
                raise InputError(f"{where}: joint_map.joints.{name}: {axis!r} is not in controller_axes")
            if not np.isfinite(factor):
                raise InputError(
                    f"{where}: joint_map.joints.{name}.{axis}: factor must be finite, got {factor!r}"
                )
            A[i, axes.index(axis)] += float(factor)
    for key, value in spec.offsets_deg.items():
        i = index[str(key)]
        b[i] = float(value) if prismatic[i] else np.deg2rad(float(value))
    if np.linalg.matrix_rank(A) < len(axes):
        raise InputError(
            f"{where}: joint_map: two controller axes move the model alike (the map has rank < axes)"
        )
    return JointMap(
        A=A, b=b, axes=tuple(axes), joints=tuple(joint_names), prismatic=tuple(bool(x) for x in prismatic)
    )


def joint_map_from_spec(
    spec: JointMapSpec | None,
    where: str = "robot",
    *,
    joint_names: Sequence[str] | None = None,
    prismatic: np.ndarray | None = None,
) -> JointMap | None:
    """Validate a :class:`JointMapSpec` and convert it (None stays None).

    Raises:
        InputError: naming ``where`` and the field: a sign other than +1/-1, not six signs or
            offsets, a coupling with a joint outside 1..6, coupling a joint to itself, a
            non-finite factor, or a map that cannot be inverted.
    """
    if spec is None:
        return None
    if spec.controller_axes or spec.joints or spec.offsets_deg:
        if spec.sign or spec.offset_deg or spec.couplings:
            raise InputError(
                f"{where}: joint_map: give either sign/offset_deg/couplings or controller_axes/joints"
            )
        names = list(joint_names) if joint_names is not None else [f"A{i + 1}" for i in range(N_JOINTS)]
        pris = np.zeros(len(names), dtype=bool) if prismatic is None else np.asarray(prismatic, dtype=bool)
        return _general(spec, where, names, pris)
    if joint_names is not None and len(joint_names) != N_JOINTS:
        raise InputError(
            f"{where}: joint_map with sign/offset_deg/couplings is for six joints; this robot has "
            f"{len(joint_names)}: use controller_axes and joints"
        )
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
    if joint_map.axes is not None:
        axes, names = joint_map.axes, joint_map.joints
        b = [v if p else float(np.rad2deg(v)) for v, p in zip(joint_map.b, joint_map.prismatic, strict=True)]
        return JointMapSpec(
            controller_axes=list(axes),
            joints={
                names[i]: {axes[j]: float(A[i, j]) for j in np.flatnonzero(A[i])} for i in range(len(names))
            },
            offsets_deg={names[i]: b[i] for i in range(len(names)) if b[i] != 0.0},
        )
    couplings = [
        CouplingSpec(joint=i + 1, from_joint=j + 1, factor=float(A[i, j]))
        for i in range(N_JOINTS)
        for j in range(N_JOINTS)
        if i != j and A[i, j] != 0.0
    ]
    return JointMapSpec(
        sign=np.diag(A).tolist(), offset_deg=np.rad2deg(joint_map.b).tolist(), couplings=couplings
    )


def mimic_joint_map(
    names: list[str], mimics: dict, units: list[float], where: str, *, off_chain: dict | None = None
) -> JointMapSpec | None:
    """The joint map of a URDF chain's ``<mimic>`` joints: each follows its leader (multiplier times
    its value plus offset), the controller commands the others; None without mimic joints.

    A leader off the chain (a commanded joint that drives another branch, e.g. a lifting column's
    prismatic joint moving a pseudo-tip link while the chain's column stages mimic it) becomes a
    controller axis of the robot, placed where its first mimic sits on the chain.

    Args:
        names: the chain's joint names; mimics: name -> (leader, multiplier, offset);
        units: per joint, the URDF unit of an offset in the file's (1 for rad; ``MM`` for m, so
            ``offset / unit`` is mm).
        off_chain: the URDF's movable joints off the chain, name -> prismatic (a leader there must
            be of the same kind as its mimics, so that the multiplier has no unit).
    """
    if not mimics:
        return None
    off_chain = off_chain or {}
    joints, offsets, axes = {}, {}, []
    for name in names:
        if name not in mimics:
            axes.append(name)
            continue
        leader, multiplier, offset = mimics[name]
        on_chain = leader in names and leader not in mimics
        if not on_chain and leader not in off_chain:
            raise InputError(
                f"{where}: joint {name!r}: <mimic joint={leader!r}> must name a commanded (not mimic) "
                "movable joint of the URDF"
            )
        if not on_chain and off_chain[leader] != (units[names.index(name)] != 1.0):
            raise InputError(
                f"{where}: joint {name!r}: <mimic joint={leader!r}>: a leader off the chain must be of the "
                "same kind (prismatic or revolute) as the joints that mimic it"
            )
        if not on_chain and leader not in axes:
            axes.append(leader)
        joints[name] = {leader: float(multiplier)}
        if offset:
            unit = units[names.index(name)]
            offsets[name] = offset / unit if unit != 1.0 else float(np.rad2deg(offset))
    return JointMapSpec(controller_axes=axes, joints=joints, offsets_deg=offsets)


def commandable_projection(robot, q: np.ndarray) -> np.ndarray:
    """``q`` (n, n_joints) moved, the least in joint space, onto the poses the robot's controller can
    command (its joint map's coupling equations); ``q`` itself without couplings."""
    if robot.joint_map is None:
        return q
    N, c = robot.joint_map.coupling_equations()
    if not N.shape[0]:
        return q
    return q - (q @ N.T - c) @ N


def commandable_motions(robot) -> np.ndarray:
    """(n_joints, n_joints) ``I - N^T N``: the projector on the joint motions the controller can
    command (they keep the coupling equations of :func:`commandable_projection`); the identity
    without couplings."""
    nj = robot.n_joints
    if robot.joint_map is None:
        return np.eye(nj)
    N, _ = robot.joint_map.coupling_equations()
    return np.eye(nj) - N.T @ N


def q_columns(robot) -> tuple[str, ...]:
    """Joint columns of a robot's files: ``q{i}_deg`` (revolute, degrees) or ``q{i}_mm`` (prismatic,
    millimetres), one per joint; :data:`JOINT_COLUMNS` for None."""
    if robot is None:
        return JOINT_COLUMNS
    return tuple(f"q{i}_{'mm' if p else 'deg'}" for i, p in enumerate(robot.prismatic, start=1))


def q_from_file(robot, values) -> np.ndarray:
    """Joint values in file units (deg; prismatic mm) -> internal units (rad; mm); ``robot`` None:
    six revolute joints."""
    values = np.asarray(values, dtype=float)
    if robot is None:
        return np.deg2rad(values)
    return np.where(robot.prismatic, values, np.deg2rad(values))


def q_to_file(robot, q) -> np.ndarray:
    """Joint values in internal units (rad; prismatic mm) -> file units (deg; mm)."""
    q = np.asarray(q, dtype=float)
    if robot is None:
        return np.rad2deg(q)
    return np.where(robot.prismatic, q, np.rad2deg(q))


def check_joint_angles(path, q_deg: np.ndarray, robot, *, rows=None) -> None:
    """Joint values (n, n_joints) in file units within the robot's limits; a table that looks like
    radians gets a clear message.

    Args:
        path: the file (for messages); rows: (n,) its line numbers of the rows (default 2, 3, ...).

    Raises:
        InputError: naming the file, row and column.
    """
    rows = list(range(2, len(q_deg) + 2)) if rows is None else list(rows)
    lo, up = q_to_file(robot, robot.lower), q_to_file(robot, robot.upper)
    cols = q_columns(robot)
    rev = np.asarray(q_deg)[:, ~robot.prismatic]
    # Joints 4 and 6 range over +-350 deg, i.e. up to 6.1 rad: a table entirely within +-2 pi
    # (with some spread, more than three poses) is taken for radians.
    if len(q_deg) > 3 and np.ptp(rev) > 0 and np.all(np.abs(rev) <= 2.0 * np.pi + 1e-9):
        raise InputError(
            f"{path}: every joint value is within +-2 pi: the angles look like radians; "
            "columns q*_deg must hold degrees"
        )
    tol, nj = 1e-6, robot.n_joints
    for k, row in zip(rows, q_deg, strict=True):
        for j in range(nj):
            if not lo[j] - tol <= row[j] <= up[j] + tol:
                raise InputError(
                    f"{path}: row {k}, column {cols[j]!r}: {row[j]:g} {cols[j][-3:].strip('_')} is "
                    f"outside the joint range [{lo[j]:g}, {up[j]:g}] of {robot.name}"
                )


@dataclasses.dataclass(frozen=True)
class FileJoints:
    """What a file of a robot holds per pose: its joint columns and the targets it may name.

    Attributes:
        columns: the joint columns of the native files (:func:`q_columns`).
        n_columns: joint columns of a foreign file (the controller's axes through the joint map).
        what: ``"joints"`` or ``"controller axes"``, for messages.
        linear: (n_columns,) True where a column is a length (a prismatic joint, or an axis that
            drives one).
        name: the robot's name; label: its file (or name), for messages.
        n_targets: the targets (reflectors) the model defines.
    """

    columns: tuple[str, ...]
    n_columns: int
    what: str
    linear: np.ndarray
    name: str
    label: str
    n_targets: int


def file_joints(robot, *, controller: bool = False) -> FileJoints:
    """The :class:`FileJoints` of ``robot``; ``controller``: the columns hold the controller's axes
    (the joint map's, when the robot has one)."""
    jmap = robot.joint_map if controller else None
    prismatic = np.asarray(robot.prismatic)
    return FileJoints(
        columns=q_columns(robot),
        n_columns=robot.n_joints if jmap is None else jmap.n_axes,
        what="joints" if jmap is None else "controller axes",
        linear=prismatic if jmap is None else np.any(jmap.A[prismatic] != 0, axis=0),
        name=robot.name,
        label=robot.source or robot.name,
        n_targets=robot.n_targets,
    )


def joints_from_file(
    robot, values, *, path, rows, scale=None, controller: bool = False, check: bool = True
) -> np.ndarray:
    """(n, n_joints) model joint values [rad; mm] of a file's joint columns, checked against the
    limits.

    Args:
        values: (n, k) the columns as read: file units (:func:`q_columns`) without ``scale``, else
            times ``scale`` (k,) in internal units.
        path, rows: the file and its (n,) row numbers, for messages.
        controller: the columns are the controller's axes: the joint map (if any) gives the model's.
        check: check the limits (:func:`check_joint_angles`).
    """
    mapped = controller and robot.joint_map is not None
    q = q_from_file(robot, values) if scale is None else np.asarray(values) * scale
    if mapped:
        q = robot.joint_map.to_model(q)
    if check:
        as_read = scale is None and not mapped
        check_joint_angles(path, values if as_read else q_to_file(robot, q), robot, rows=rows)
    return q
