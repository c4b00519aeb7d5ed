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
from kpioed_drake.robot.modelspec import SidecarSpec

MOVABLE = ("revolute", "continuous", "prismatic")
HELD = ("fixed", "floating", "planar")
"""Joints that are not robot joints: fixed ones, and a free (floating) or planar base (no movable
joint above it), held at its origin (the tracker frame is registered to the data, so the base's
placement is free anyway); a floating or planar joint below a movable one is refused."""


def measured_links(side: SidecarSpec, sw: str, path: Path) -> tuple[tuple[str, str], ...]:
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
    (0-based, -1: the root), the root link, and whether the URDF welds to "world".

    Every walk over the file's graph is a loop over its links (no recursion), after
    :func:`check_tree` made sure the graph is a tree: a URDF of any depth, or a malformed one,
    ends with an answer or an :class:`InputError`.
    """
    joints = root.findall("joint")
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
    links = [lk.get("name") for lk in root.findall("link")]
    children, parent_joint, root_link = check_tree(joints, links, path)
    for j in joints:
        above = _above(j.find("parent").get("link"), parent_joint)
        if j.get("type") in ("floating", "planar") and any(a.get("type") in MOVABLE for a in above):
            raise InputError(
                f"{path}: joint {j.get('name', '?')!r}: type {j.get('type')!r} is not supported below "
                "a movable joint (a free or planar base is held at its origin)"
            )
    if tips:
        used = {id(j) for t, where in tips for j in _path_to(t, parent_joint, links, where)}
        chain = [j for j in _depth_first(root_link, children) if id(j) in used and j.get("type") in MOVABLE]
    else:
        chain = _serial(root_link, children, path)
    if not chain:
        raise InputError(f"{path}: no revolute or prismatic joint")
    index = {id(j): i for i, j in enumerate(chain)}
    parents = [  # the nearest ancestor on the chain
        next((index[id(a)] for a in _above(j.find("parent").get("link"), parent_joint) if id(a) in index), -1)
        for j in chain
    ]
    return chain, np.array(parents, dtype=int), root_link, root_link == "world"


def check_tree(joints: list[ET.Element], links: list[str], path: Path) -> tuple[dict, dict, str]:
    """The URDF's joints and links form one tree: each link named once, each joint between two
    distinct links of the file, each link the child of at most one joint, no loop, one root.

    Returns:
        (link -> the joints whose parent it is, in the file's order; link -> its parent joint;
        the root link).

    Raises:
        InputError: naming the file, the link or joints and what a URDF must be.
    """
    seen: set[str] = set()
    for kind, names in (("link", links), ("joint", [j.get("name", "?") for j in joints])):
        for name in names:
            if name in seen:
                raise InputError(f"{path}: {kind} {name!r} is defined more than once (names must be unique)")
            seen.add(name)
        seen = set()
    known = set(links)
    children: dict[str, list[ET.Element]] = {}
    parent_joint: dict[str, ET.Element] = {}
    for j in joints:
        name, p, c = j.get("name", "?"), j.find("parent").get("link"), j.find("child").get("link")
        for role, link in (("parent", p), ("child", c)):
            if link not in known:
                raise InputError(f"{path}: joint {name!r}: {role} link {link!r} is not a link of the URDF")
        if p == c:
            raise InputError(f"{path}: joint {name!r}: connects link {p!r} to itself")
        if c in parent_joint:
            raise InputError(
                f"{path}: link {c!r} is the child of two joints ({parent_joint[c].get('name', '?')!r} and "
                f"{name!r}); a URDF is a tree: every link but the root has one parent joint (closed "
                "loops are not supported)"
            )
        children.setdefault(p, []).append(j)
        parent_joint[c] = j
    _check_no_loop(links, parent_joint, path)
    roots = [lk for lk in links if lk not in parent_joint]
    if len(roots) != 1:
        raise InputError(f"{path}: expected one root link, found {roots or 'none'} (not a tree)")
    return children, parent_joint, roots[0]


def _check_no_loop(links: list[str], parent_joint: dict, path: Path) -> None:
    """No link is its own ancestor (each link has at most one parent joint here)."""
    done: set[str] = set()  # links whose way up ends at a root
    for start in links:
        way, link = [], start
        while link in parent_joint and link not in done:
            if link in way:
                loop = way[way.index(link) :]
                names = ", ".join(repr(parent_joint[lk].get("name", "?")) for lk in loop)
                raise InputError(
                    f"{path}: the joints {names} form a closed loop (link {link!r} is its own ancestor); "
                    "a URDF is a tree"
                )
            way.append(link)
            link = parent_joint[link].find("parent").get("link")
        done.update(way)


def _above(link: str, parent_joint: dict):
    """The joints from ``link`` up to the root, nearest first (a tree: :func:`check_tree`)."""
    while link in parent_joint:
        yield parent_joint[link]
        link = parent_joint[link].find("parent").get("link")


def _depth_first(link: str, children: dict) -> list[ET.Element]:
    """The joints below ``link``, depth first in the URDF's order of children, so that every joint
    follows its parent (an explicit stack: no recursion however deep the tree)."""
    out, stack = [], list(reversed(children.get(link, [])))
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(reversed(children.get(j.find("child").get("link"), [])))
    return out


def _path_to(tip: str, parent_joint: dict, links: list[str], where: str) -> list[ET.Element]:
    """The joints (fixed ones too) on the path from the root to link ``tip`` (``where``: the file
    and field naming it, for the error)."""
    if tip not in links:
        raise InputError(f"{where} {tip!r} is not a link of the URDF (links: {', '.join(links)})")
    return list(_above(tip, parent_joint))[::-1]


def _movable_below(root: str, children: dict) -> dict[str, int]:
    """Link -> the movable joints below it, for every link under ``root`` (children before their
    parents: the depth-first order reversed)."""
    count: dict[str, int] = {}
    for j in reversed(_depth_first(root, children)):
        child = j.find("child").get("link")
        below = count.get(child, 0) + (j.get("type") in MOVABLE)
        parent = j.find("parent").get("link")
        count[parent] = count.get(parent, 0) + below
    return count


def _serial(root: str, children: dict, path: Path) -> list[ET.Element]:
    """The movable joints of a serial chain from ``root`` (a branch of movable joints is an error)."""
    below = _movable_below(root, children)
    chain, link = [], root
    while True:
        branches = [
            j
            for j in children.get(link, [])
            if j.get("type") in MOVABLE or below.get(j.find("child").get("link"), 0)
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


def mimics(chain: list[ET.Element], path: Path) -> dict[str, tuple[str, float, float]]:
    """The chain's ``<mimic>`` joints: name -> (leader, multiplier, offset [rad or m]).

    Raises:
        InputError: a multiplier or offset that is not one finite number (the URDF and joint named).
    """
    out = {}
    for j in chain:
        m = j.find("mimic")
        if m is None:
            continue
        values = []
        for attr, default in (("multiplier", "1"), ("offset", "0")):
            text = m.get(attr, default)
            try:
                v = float(text)
            except ValueError:
                v = float("nan")
            if not np.isfinite(v):
                raise InputError(
                    f"{path}: joint {j.get('name')!r}: <mimic {attr}={text!r}>: expected one finite number"
                )
            values.append(v)
        out[j.get("name")] = (m.get("joint", ""), *values)
    return out
