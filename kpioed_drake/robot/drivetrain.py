"""The drive train of a robot: what drives each joint, and whose angles a joint's drive may err with.

**Drive types.** A robot file says how its joints are driven (``drive:`` for every joint,
``drives: {JOINT: TYPE}`` per joint by name or 1-based number; ``models/README.md``): ``gear``
(default: a gear train or an RV reducer), ``harmonic`` (a strain-wave gear), ``cable`` (cables on
capstans and pulleys) or ``belt`` (toothed belts). The type sets the plausibility bounds of the
joint's effects (:mod:`kpioed_drake.effects.physical`): a cable or belt drive's ratio is known to a
few per cent, a harmonic drive has larger cyclic errors, cables and belts are softer than gears.

**Couplings from the structure** (the ``joint_coupling:i:j`` candidates of the diagnosis,
:func:`coupling_pairs`): joint i errs with the angle of joint j

- when the joint map makes joint i follow joint j (``q_i = ... + f q_j``, a coupled joint or a
  parallelogram: the mechanism's ratio is the map's factor only nominally; :func:`map_leaders`);
- when the drive train of joint i crosses the axis of joint j, within one branch (the joints from
  the root or a branching joint to a leaf, :func:`branches`): as on a six-joint arm, the wrist's
  drives (its last three revolute joints) cross the axes of the wrist joints before them, and the
  elbow's drive (the joint before the wrist) the axis of the joint before it (a parallelogram).
  On a six-joint arm these are 3:2, 5:4, 6:4, 6:5. No pair spans two branches (no joint's drive
  runs through a joint of another arm).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from kpioed_drake.errors import InputError

DRIVES = ("gear", "harmonic", "cable", "belt")
"""The drive types a robot file may name (``drive``, ``drives``)."""
DEFAULT_DRIVE = "gear"
WRIST = 3
"""Joints of a branch's wrist: the last three revolute joints of a branch that ends in a leaf."""


def drive_types(drive: str, drives: dict, joint_names: Iterable[str], where: str) -> tuple[str, ...]:
    """Per joint its drive type from a robot file's ``drive`` (every joint) and ``drives`` (per
    joint, by name or 1-based number; overrides ``drive``).

    Raises:
        InputError: an unknown type or joint, naming ``where`` and the field.
    """
    names = list(joint_names)

    def checked(value, field: str) -> str:
        text = str(value).strip().lower()
        if text not in DRIVES:
            raise InputError(f"{where}: {field}: expected one of {', '.join(DRIVES)}, got {value!r}")
        return text

    out = [checked(drive, "drive") if str(drive).strip() else DEFAULT_DRIVE] * len(names)
    index = {name: i for i, name in enumerate(names)} | {str(i + 1): i for i in range(len(names))}
    for key, value in (drives or {}).items():
        if str(key) not in index:
            raise InputError(
                f"{where}: drives: {key!r} is not a joint of the robot (its joints: {', '.join(names)})"
            )
        out[index[str(key)]] = checked(value, f"drives.{key}")
    return tuple(out)


def joint_drive(robot, joint: int) -> str:
    """The drive type of 1-based ``joint`` (:data:`DEFAULT_DRIVE` when the file names none)."""
    drives = getattr(robot, "drives", ()) or ()
    return drives[joint - 1] if 1 <= joint <= len(drives) else DEFAULT_DRIVE


def map_leaders(robot) -> dict[int, tuple[tuple[int, float], ...]]:
    """Per joint that the joint map makes follow others (1-based), its leaders among the model's
    joints and the map's factor of each: ``{4: ((2, -1.0), (3, -1.0))}`` for ``q_4 = -(J_2 + J_3)``.

    Six-joint form: the couplings (``A[i, j]``, i != j). General form: the controller axes of a
    joint's sum that are other model joints (an axis without a joint of its name, such as a lift's
    commanded pseudo-joint, has no angle in the data and leads no candidate).
    """
    jm = getattr(robot, "joint_map", None)
    if jm is None:
        return {}
    A, out = np.asarray(jm.A, dtype=float), {}
    if jm.axes is None:
        for i in range(A.shape[0]):
            lead = tuple((int(j) + 1, float(A[i, j])) for j in np.flatnonzero(A[i]) if j != i)
            if lead:
                out[i + 1] = lead
        return out
    names = list(robot.joint_names)
    for i, name in enumerate(names):
        terms = {jm.axes[k]: float(A[i, k]) for k in np.flatnonzero(A[i])}
        if list(terms) == [name]:
            continue  # follows its own axis
        lead = tuple((names.index(a) + 1, f) for a, f in terms.items() if a in names and a != name)
        if lead:
            out[i + 1] = lead
    return out


def _parents(robot, n_joints: int) -> np.ndarray:
    chain = getattr(robot, "chain", None)
    return np.arange(n_joints) - 1 if chain is None else np.asarray(chain.parents, dtype=int)


def branches(robot, n_joints: int | None = None) -> list[tuple[tuple[int, ...], bool]]:
    """The robot's branches: ``(joints (1-based, base to tip), ends_in_a_leaf)``; a branch runs from
    the root or a branching joint's child down to a leaf or a joint with several children (a serial
    robot is one branch)."""
    n = robot.n_joints if n_joints is None else int(n_joints)
    parent = _parents(robot, n)
    children = [np.flatnonzero(parent == i) for i in range(n)]
    out = []
    for start in range(n):
        p = parent[start]
        if p >= 0 and len(children[p]) == 1:
            continue  # inside a branch
        seg = [start]
        while len(children[seg[-1]]) == 1:
            seg.append(int(children[seg[-1]][0]))
        out.append((tuple(j + 1 for j in seg), len(children[seg[-1]]) == 0))
    return out


def drive_train_pairs(robot, n_joints: int | None = None) -> list[tuple[int, int]]:
    """``(i, j)``: joint i's drive crosses joint j's axis, within each branch ending in a leaf: the
    elbow (the revolute joint before the wrist) with the one before it, then each wrist joint with
    the wrist joints before it (six-joint arm: 3:2, 5:4, 6:4, 6:5)."""
    n = robot.n_joints if n_joints is None else int(n_joints)
    prismatic = np.asarray(getattr(robot, "prismatic", np.zeros(n, dtype=bool)), dtype=bool)
    out = []
    for seg, leaf in branches(robot, n):
        rev = [j for j in seg if not prismatic[j - 1]]
        if not leaf or len(rev) < 2:
            continue
        wrist = rev[-WRIST:]
        before = rev[: -len(wrist)]
        if len(before) >= 2:
            out.append((before[-1], before[-2]))
        out += [(wrist[b], wrist[a]) for b in range(1, len(wrist)) for a in range(b)]
    return out


def coupling_pairs(robot, n_joints: int | None = None) -> tuple[tuple[int, int], ...]:
    """The ``(i, j)`` of the ``joint_coupling:i:j`` candidates: each joint-map follower with its
    leaders (:func:`map_leaders`), then the drive-train pairs of each branch
    (:func:`drive_train_pairs`); only joints of one kind (a revolute joint's angle error from a
    prismatic joint's millimetres has no ratio)."""
    n = robot.n_joints if n_joints is None else int(n_joints)
    prismatic = np.asarray(getattr(robot, "prismatic", np.zeros(n, dtype=bool)), dtype=bool)
    pairs = [(i, j) for i, lead in map_leaders(robot).items() for j, _ in lead]
    pairs += drive_train_pairs(robot, n)
    out = []
    for i, j in pairs:
        if i != j and (i, j) not in out and max(i, j) <= n and prismatic[i - 1] == prismatic[j - 1]:
            out.append((i, j))
    return tuple(out)


def follower_factor(robot, joint: int, coupled: int | None) -> float | None:
    """The map's factor by which ``joint`` follows ``coupled`` (``coupled`` None: the largest of its
    leaders', for the joint's scale), or None when ``joint`` is no follower (of ``coupled``)."""
    lead = dict(map_leaders(robot).get(joint, ()))
    if not lead:
        return None
    if coupled is None:
        return max(abs(f) for f in lead.values())
    return abs(lead[coupled]) if coupled in lead else None
