"""The inputs of a contact design from files and text: plane sets, a robot's default planes, a pivot.

A plane set is a YAML file (``planes:``, a list of ``{normal: [x, y, z], offset_mm: d}``, the entries
of a calibrated model file's ``contact_environment``; an optional ``description``) or a CSV file
with the header ``nx,ny,nz,offset_mm``, one plane a row. Each plane is ``normal . x = offset_mm`` in
W (the robot's base frame) [mm]; the normal points to the plane's free side, where the flange is,
and is normalised when read. A robot's default planes are ``models/planes/NAME.yaml`` (the kr16's
are the table, two walls and tilted plate of docs/contacts.md). A pivot is ``x,y,z`` in W [mm].
"""

import csv
import dataclasses
import io
from pathlib import Path

import numpy as np

from kpioed_drake.design.contact.surfaces import Planes, planes
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.modelspec import MODELS_DIR, PlaneSpec, load_yaml_typed

PLANE_COLUMNS = ("nx", "ny", "nz", "offset_mm")
"""The columns of a plane-set CSV."""


@dataclasses.dataclass
class PlaneSetSpec:
    """A plane-set YAML file (real annotations, no ``from __future__ import annotations``: Drake's
    typed loader reads them)."""

    description: str = ""
    planes: list[PlaneSpec] = dataclasses.field(default_factory=list)


def default_planes_path(robot: Robot) -> Path:
    """``models/planes/NAME.yaml``: the robot's default plane set (it may not exist)."""
    return MODELS_DIR / "planes" / f"{robot.name}.yaml"


def _plane_yaml(path: Path) -> tuple[np.ndarray, np.ndarray]:
    spec = load_yaml_typed(path, PlaneSetSpec)
    for k, p in enumerate(spec.planes):
        if len(p.normal) != 3:
            raise InputError(f"{path}: planes[{k}].normal: expected [x, y, z], got {p.normal}")
    return np.array([p.normal for p in spec.planes], dtype=float).reshape(-1, 3), np.array(
        [p.offset_mm for p in spec.planes], dtype=float
    )


def _plane_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        rows = [
            r for r in csv.reader(io.StringIO(path.read_text(encoding="utf-8"))) if any(c.strip() for c in r)
        ]
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    header = [h.strip() for h in rows[0]] if rows else []
    if missing := [c for c in PLANE_COLUMNS if c not in header]:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; expected the header {','.join(PLANE_COLUMNS)}"
        )
    at = [header.index(c) for c in PLANE_COLUMNS]
    values = np.zeros((len(rows) - 1, 4))
    for r, row in enumerate(rows[1:]):
        for j, (c, i) in enumerate(zip(PLANE_COLUMNS, at, strict=True)):
            cell = row[i].strip() if i < len(row) else ""
            try:
                values[r, j] = float(cell)
            except ValueError:
                raise InputError(f"{path}: row {r + 2}, column {c!r}: {cell!r} is not a number") from None
    return values[:, :3], values[:, 3]


def read_planes(path: str | Path) -> Planes:
    """The plane set of a YAML or CSV file (module docstring).

    Raises:
        InputError: naming the file (and the row and column of a CSV): a missing file or column, a
            cell that is no number, no plane, a zero or non-finite normal.
    """
    path = Path(path)
    N, d = _plane_csv(path) if path.suffix.lower() == ".csv" else _plane_yaml(path)
    if not d.size:
        raise InputError(f"{path}: no planes")
    for k in np.flatnonzero(~(np.linalg.norm(N, axis=1) > 0))[:1]:
        raise InputError(f"{path}: plane {k + 1}: the normal is zero")
    try:
        return planes(N, d)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def robot_planes(robot: Robot, path: str | Path | None) -> Planes:
    """The planes of ``path``, or (None) the robot's default planes (:func:`default_planes_path`).

    Raises:
        InputError: :func:`read_planes`' errors; no file given and no default for the robot.
    """
    if path is not None:
        return read_planes(path)
    default = default_planes_path(robot)
    if not default.is_file():
        raise InputError(
            f"{robot.name}: no default plane set ({default} does not exist); give planes (a YAML or "
            "CSV file)",
            fields=("planes",),
        )
    return read_planes(default)


def parse_pivot(text: str | None) -> np.ndarray | None:
    """``"x,y,z"`` [mm] as (3,) (None: None).

    Raises:
        InputError: not three finite comma-separated numbers.
    """
    if text is None:
        return None
    try:
        vals = np.array([float(x) for x in text.split(",")])
    except ValueError:
        vals = np.zeros(0)
    if vals.shape != (3,) or not np.all(np.isfinite(vals)):
        raise InputError(
            f"pivot_mm: expected x,y,z: three finite comma-separated numbers [mm], got {text!r}",
            fields=("pivot_mm",),
        )
    return vals
