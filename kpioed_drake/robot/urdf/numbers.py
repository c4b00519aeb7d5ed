"""The numbers of a URDF, checked before Drake reads them: Drake asserts (and ends the process) on a
``<limit>`` whose lower bound lies above its upper one, and only warns of a negative mass; a
hostile file (an element nested thousands deep, a length of 1e300) must be answered here, naming
the file, the joint or link and the attribute.

A ``<limit>`` attribute is one finite number; ``lower <= upper`` and ``velocity >= 0``. The
sidecar's ``limits`` (degrees; prismatic joints millimetres) replace a joint's URDF limits, also in
the text Drake parses: a URDF whose own limits are wrong is usable when the sidecar gives that
joint's. A mass is a finite number >= 0, an inertia's entries finite, an origin within
:data:`MAX_LENGTH_M` of its frame, a geometry's sizes >= 0.
"""

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.modelspec import SidecarSpec

MM = 1e-3
LIMIT_ATTRIBUTES = ("lower", "upper", "effort", "velocity")
MAX_DEPTH = 64
"""Deepest element nesting accepted (a URDF's is five or six: robot, link, collision, geometry,
shape); the serialisation of a deeper tree recurses past Python's limit."""
MAX_LENGTH_M = 1e3
"""Largest origin offset [m] of a robot's frames (a kilometre: no robot; beyond, products overflow)."""
INERTIA = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")


def floats(
    el: ET.Element | None, attr: str, default: str, where: str, *, bound: float = math.inf
) -> np.ndarray:
    """Attribute ``attr`` of ``el`` (``default`` when absent) as numbers, each finite and at most
    ``bound`` in size.

    Raises:
        InputError: ``where``, the attribute and its text.
    """
    text = el.get(attr, default) if el is not None else default
    try:
        vals = np.array([float(x) for x in text.split()])
    except ValueError:
        raise InputError(f"{where}: {attr}={text!r} is not a list of numbers") from None
    if not np.all(np.isfinite(vals)):
        raise InputError(f"{where}: {attr}={text!r} is not finite")
    if np.any(np.abs(vals) > bound):
        raise InputError(f"{where}: {attr}={text!r}: expected values of at most {bound:g} in size")
    return vals


def check_numbers(root: ET.Element, path: Path) -> None:
    """The URDF's nesting, origins and inertias (module docstring), before anything else reads them.

    Raises:
        InputError: the file, the element (link, joint) and the attribute.
    """
    stack = [(root, 1)]
    while stack:  # a loop, not recursion: any depth is answered
        el, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise InputError(f"{path}: elements nested deeper than {MAX_DEPTH} (<{el.tag}>); not a URDF")
        stack.extend((child, depth + 1) for child in el)
    for kind in ("link", "joint"):
        for el in root.iter(kind):
            where = f"{path}: {kind} {el.get('name', '?')!r}"
            for origin in el.iter("origin"):
                floats(origin, "xyz", "0 0 0", where, bound=MAX_LENGTH_M)
                floats(origin, "rpy", "0 0 0", where, bound=MAX_LENGTH_M)
    for link in root.iter("link"):
        where = f"{path}: link {link.get('name', '?')!r}"
        for mass in link.iter("mass"):
            if floats(mass, "value", "0", f"{where} <mass>")[0] < 0:
                raise InputError(f"{where}: <mass value={mass.get('value')!r}>: expected a number >= 0")
        for inertia in link.iter("inertia"):
            for attr in INERTIA:
                floats(inertia, attr, "0", f"{where} <inertia>")


def sidecar_limits(side: SidecarSpec, sw: str) -> dict[str, tuple[float, float]]:
    """The sidecar's ``limits`` by joint name (its units), each finite with lower < upper.

    Raises:
        InputError: the sidecar, the joint and what was expected.
    """
    out = {}
    for lim in side.limits:
        if not (np.isfinite(lim.lower) and np.isfinite(lim.upper) and lim.lower < lim.upper):
            raise InputError(f"{sw}: limits of joint {lim.joint!r}: need finite lower < upper")
        out[lim.joint] = (float(lim.lower), float(lim.upper))
    return out


def _number(el: ET.Element, attr: str, where: str) -> float | None:
    text = el.get(attr)
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise InputError(f"{where}: <limit {attr}={text!r}>: expected one finite number")
    return value


def checked_limits(root: ET.Element, overrides: dict[str, tuple[float, float]], path: Path) -> ET.Element:
    """A copy of the URDF ``root`` whose movable joints' limits Drake accepts.

    Args:
        root: the URDF.
        overrides: the sidecar's limits by joint name (:func:`sidecar_limits`): written into those
            joints' ``<limit>`` (radians, metres), whatever the URDF says.
        path: the URDF, for messages.

    Raises:
        InputError: a limit attribute that is not one finite number, lower above upper, or a
            negative velocity limit, of a joint the sidecar does not override (file, joint, values).
    """
    root = ET.fromstring(ET.tostring(root))
    for j in root.iter("joint"):
        name, el = j.get("name", "?"), j.find("limit")
        if el is None:
            continue
        where = f"{path}: joint {name!r}"
        checked = LIMIT_ATTRIBUTES[2:] if name in overrides else LIMIT_ATTRIBUTES
        values = {a: _number(el, a, where) for a in checked}
        if values["velocity"] is not None and values["velocity"] < 0:
            raise InputError(f"{where}: <limit velocity={el.get('velocity')!r}>: expected a number >= 0")
        if name in overrides:
            scale = MM if j.get("type") == "prismatic" else math.pi / 180.0
            el.set("lower", repr(overrides[name][0] * scale))
            el.set("upper", repr(overrides[name][1] * scale))
        elif (values["lower"] or 0.0) > (values["upper"] or 0.0):  # a missing one is 0 (URDF)
            raise InputError(
                f"{where}: <limit lower={el.get('lower')!r} upper={el.get('upper')!r}>: the lower limit is "
                "above the upper one; correct it, or give the joint's limits in the sidecar (limits:)"
            )
    return root
