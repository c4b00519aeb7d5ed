"""Which joints of a URDF tree are the robot: the chain to the measured link, or the union of the
chains to several measured links (a tree: two arms on one torso), in an order where every joint
follows its parent; ``<mimic>`` joints read for their joint map.

Only movable joints (revolute, continuous, prismatic) are robot joints; fixed ones fold into their
links. Without a measured link the URDF must be one serial chain.
"""

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from kpioed_drake.errors import InputError

MOVABLE = ("revolute", "continuous", "prismatic")
HELD = ("fixed", "floating", "planar")
"""Joints that are not robot joints: fixed ones, and a free (floating) or planar base (no movable
joint above it), held at its origin (the tracker frame is registered to the data, so the base's
placement is free anyway); a floating or planar joint below a movable one is refused."""


def measured_links(side, sw: str, path: Path) -> tuple[tuple[str, str], ...]:
    """The measured links, each with the file and field naming it (``targets[k].link`` of the
    sidecar ``sw``, or ``tip_link``)."""
    if side.targets and (side.tip_link or side.targets_mm or side.reflector_position_mm):
        raise InputError(
            f"{sw}: targets (on links) replaces tip_link, targets_mm and reflector_position_mm; give one"
        )
    for k, t in enumerate(side.targets):
        if not t.link:
            raise InputError(f"{sw}: targets[{k}].link: expected a link name of the URDF")
    tips = tuple((t.link, f"{sw}: targets[{k}].link") for k, t in enumerate(side.targets))
    if tips:
        return tips
    return ((side.tip_link, f"{path}: tip_link"),) if side.tip_link else ()


def chain_joints(
    root: ET.Element, path: Path, tips: tuple[tuple[str, str], ...] = ()
) -> tuple[list[ET.Element], np.ndarray, str, bool]:
    """The movable joints in tree order (base to flange; with ``tips``, the union of the chains to
    those links, other branches ignored; else the tree must be serial), each one's parent joint
    (0-based, -1: the root), the root link, and whether the URDF welds to "world"."""
    joints = root.findall("joint")
    children: dict[str, list[ET.Element]] = {}
    parent_joint: dict[str, ET.Element] = {}
    for j in joints:
        name, kind = j.get("name", "?"), j.get("type", "")
        if kind not in MOVABLE + HELD:
            raise InputError(
                f"{path}: joint {name!r}: type {kind!r} is not supported (revolute, continuous, "
                "prismatic, fixed; floating and planar are held at their default pose)"
            )
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None or not p.get("link") or not c.get("link"):
            raise InputError(f"{path}: joint {name!r}: needs <parent link=...> and <child link=...>")
        children.setdefault(p.get("link"), []).append(j)
        parent_joint[c.get("link")] = j
    for j in joints:
        above = _above(j.find("parent").get("link"), parent_joint)
        if j.get("type") in ("floating", "planar") and any(a.get("type") in MOVABLE for a in above):
            raise InputError(
                f"{path}: joint {j.get('name', '?')!r}: type {j.get('type')!r} is not supported below "
                "a movable joint (a free or planar base is held at its origin)"
            )
    links = [lk.get("name") for lk in root.findall("link")]
    roots = [lk for lk in links if lk not in parent_joint]
    if len(roots) != 1:
        raise InputError(f"{path}: expected one root link, found {roots or 'none'} (not a tree)")
    if tips:
        used = {id(j) for t, where in tips for j in _path_to(t, parent_joint, links, where)}
        chain = _depth_first(roots[0], children, used)
    else:
        chain = _serial(roots[0], children, path)
    if not chain:
        raise InputError(f"{path}: no revolute or prismatic joint")
    index = {id(j): i for i, j in enumerate(chain)}
    parents = [  # the nearest ancestor on the chain
        next((index[id(a)] for a in _above(j.find("parent").get("link"), parent_joint) if id(a) in index), -1)
        for j in chain
    ]
    return chain, np.array(parents, dtype=int), roots[0], roots[0] == "world"


def _above(link: str, parent_joint: dict):
    """The joints from ``link`` up to the root, nearest first."""
    while link in parent_joint:
        yield parent_joint[link]
        link = parent_joint[link].find("parent").get("link")


def _depth_first(link: str, children: dict, used: set) -> list[ET.Element]:
    """The movable joints in ``used`` (ids) below ``link``, depth first in the URDF's order of
    children, so that every joint follows its parent."""
    out = []
    for j in children.get(link, []):
        if id(j) in used and j.get("type") in MOVABLE:
            out.append(j)
        out += _depth_first(j.find("child").get("link"), children, used)
    return out


def _path_to(tip: str, parent_joint: dict, links: list[str], where: str) -> list[ET.Element]:
    """The joints (fixed ones too) on the path from the root to link ``tip`` (``where``: the file
    and field naming it, for the error)."""
    if tip not in links:
        raise InputError(f"{where} {tip!r} is not a link of the URDF (links: {', '.join(links)})")
    return list(_above(tip, parent_joint))[::-1]


def _serial(root: str, children: dict, path: Path) -> list[ET.Element]:
    """The movable joints of a serial chain from ``root`` (a branch of movable joints is an error)."""

    def movable_below(link: str) -> int:
        below = children.get(link, [])
        return sum((j.get("type") in MOVABLE) + movable_below(j.find("child").get("link")) for j in below)

    chain, link = [], root
    while True:
        branches = [
            j
            for j in children.get(link, [])
            if j.get("type") in MOVABLE or movable_below(j.find("child").get("link"))
        ]
        if len(branches) > 1:
            raise InputError(
                f"{path}: link {link!r}: the tree branches ({', '.join(j.get('name') for j in branches)}); "
                "name the measured link in the sidecar (tip_link: LINK) to use the chain to it"
            )
        if not branches:
            return chain
        if branches[0].get("type") in MOVABLE:
            chain.append(branches[0])
        link = branches[0].find("child").get("link")


def mimics(chain: list[ET.Element]) -> dict[str, tuple[str, float, float]]:
    """The chain's ``<mimic>`` joints: name -> (leader, multiplier, offset [rad or m])."""
    mimic = {j.get("name"): j.find("mimic") for j in chain if j.find("mimic") is not None}
    return {
        n: (m.get("joint", ""), float(m.get("multiplier", 1)), float(m.get("offset", 0)))
        for n, m in mimic.items()
    }
