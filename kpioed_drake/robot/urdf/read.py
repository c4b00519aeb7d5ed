"""Robots from URDF: Drake's ``Parser`` reads the file into a MultibodyPlant; this module reads the
serial chain, limits, inertias and collision geometry back out of it (plus a sidecar YAML file).

The robot is the chain of revolute, continuous (without limits) and prismatic joints from the root
to the sidecar's ``tip_link``, or the union of the chains to the links of its ``targets`` (a tree:
each shared joint once, :mod:`.tree`), other branches ignored, or the whole tree when it is serial;
fixed joints are folded into the neighbouring links; ``<mimic>`` joints follow their leader (a
joint map, :func:`~kpioed_drake.robot.jointmap.mimic_joint_map`). Link i of the robot
is the child link of the i-th movable joint (its URDF frame is the joint frame, so the chain of
:mod:`kpioed_drake.robot.chain` is Drake's own); link 0 is W, the base pose ``X_WB`` folded into joint 1's
placement: the URDF's own weld to a link named ``world``, or the sidecar's ``base_xyz_mm`` /
``base_rpy_deg`` (default identity). Gravity is Drake's, -z of W.

Collision geometry becomes capsules: a cylinder (or ``drake:capsule``) the capsule of its radius
along its axis; a sphere one of zero length; a box one along its longest side with the radius of
the half diagonal of the other two; meshes are skipped (give capsules in the sidecar instead).

The sidecar ``<name>.kpioed.yaml`` next to ``<name>.urdf`` (optional) holds what a URDF lacks
(:class:`SidecarSpec`); ``models/README.md`` documents it. Units: the URDF metres and radians; the
sidecar, as every model file, millimetres and degrees (prismatic joint values in millimetres).
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex, PrismaticJoint
from pydrake.systems.framework import Context

from kpioed_drake.errors import InputError
from kpioed_drake.robot.chain import Chain, auto_gauge, param_names
from kpioed_drake.robot.jointmap import JointMap, joint_map_from_spec, mimic_joint_map
from kpioed_drake.robot.modelspec import SidecarSpec, shared_fields
from kpioed_drake.robot.urdf.numbers import (
    MAX_LENGTH_M,
    check_numbers,
    checked_limits,
    floats,
    sidecar_limits,
)
from kpioed_drake.robot.urdf.tree import MOVABLE, chain_joints, measured_links, mimics

MM = 1e-3
_GENERIC_REFLECTOR = np.array([80.0, -60.0, 150.0])
"""Reflector offset [mm] for the automatic gauge when the sidecar gives none (off every axis)."""


@dataclasses.dataclass(frozen=True)
class UrdfSource:
    """What :func:`add_urdf` needs to rebuild the robot in another plant."""

    path: str
    text: str  # the URDF without visual and collision elements
    X_WB: RigidTransform | None  # weld of the root link (None: the URDF welds to "world")
    root: str
    joints: tuple[str, ...]  # the movable joints, base to flange
    target_placements: tuple = ()  # per sidecar target: (R_OL (3, 3), p_OL (3,) [mm]) of its link
    unfolded: np.ndarray | None = None  # (n, 7) errors folded out of the file's joints (a reference)


def sidecar_path(path: Path) -> Path:
    """``robot.urdf`` -> ``robot.kpioed.yaml`` beside it."""
    return path.with_name(path.stem + ".kpioed.yaml")


def _origin(el, where: str) -> RigidTransform:
    o = el.find("origin")
    xyz, rpy = floats(o, "xyz", "0 0 0", where), floats(o, "rpy", "0 0 0", where)
    if xyz.shape != (3,) or rpy.shape != (3,):
        raise InputError(f"{where}: origin needs three xyz and three rpy values")
    return RigidTransform(RollPitchYaw(rpy), xyz)


def _parse_xml(path: Path) -> ET.Element:
    try:
        root = ET.fromstring(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except ET.ParseError as exc:
        line, col = exc.position
        raise InputError(f"{path}: malformed URDF (XML error at line {line}, column {col + 1})") from None
    if root.tag != "robot":
        raise InputError(f"{path}: not a URDF (the root element is <{root.tag}>, expected <robot>)")
    return root


def _stripped(root: ET.Element, masses=(), chain=(), where: str = "") -> str:
    """The URDF text without visual and collision elements, with the sidecar's mass overrides and
    floating or planar joints (a free base) fixed at their origin (:data:`.tree.HELD`)."""
    root = ET.fromstring(ET.tostring(root))
    for j in root.findall("joint"):
        if j.get("type") in ("floating", "planar"):
            j.set("type", "fixed")
    links = {lk.get("name"): lk for lk in root.findall("link")}
    for k, m in enumerate(masses):
        w = f"{where}: masses[{k}]"
        if not 1 <= m.link <= len(chain):
            raise InputError(f"{w}: link must be in 1..{len(chain)}, got {m.link}")
        if not (np.isfinite(m.mass_kg) and m.mass_kg > 0):
            raise InputError(f"{w}: mass_kg must be a finite number > 0, got {m.mass_kg!r}")
        lk = links[chain[m.link - 1].find("child").get("link")]
        inertial = lk.find("inertial")
        if inertial is None:
            inertial = ET.SubElement(lk, "inertial")
            ET.SubElement(inertial, "inertia", {k: "0" for k in ("ixy", "ixz", "iyz")})
        mass = inertial.find("mass")
        old = float(mass.get("value")) if mass is not None else 0.0
        mass = ET.SubElement(inertial, "mass") if mass is None else mass
        mass.set("value", repr(float(m.mass_kg)))
        tensor = inertial.find("inertia")
        for key in ("ixx", "iyy", "izz"):  # scaled, or a 50 mm solid sphere without a URDF mass
            v = float(tensor.get(key, "0")) * m.mass_kg / old if old > 0 else 0.001 * m.mass_kg
            tensor.set(key, repr(v))
        if m.com_mm:
            o = inertial.find("origin")
            o = ET.SubElement(inertial, "origin") if o is None else o
            o.set("xyz", " ".join(repr(float(x) * MM) for x in _vec(m.com_mm, f"{w}.com_mm")))
    for lk in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in lk.findall(tag):
                lk.remove(el)
    return ET.tostring(root, encoding="unicode")


def add_urdf(plant: MultibodyPlant, source: UrdfSource) -> ModelInstanceIndex:
    """Parse the robot into ``plant`` (not finalized) and weld its root; returns the model instance."""
    try:
        (inst,) = Parser(plant).AddModelsFromString(source.text, "urdf")
    except Exception as exc:  # Drake's parser raises RuntimeError with its diagnostic
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{source.path}: Drake could not parse the URDF: {msg}") from None
    if source.X_WB is not None:
        root = plant.GetBodyByName(source.root, inst)
        plant.WeldFrames(plant.world_frame(), root.body_frame(), source.X_WB)
    return inst


def movable_joints(plant: MultibodyPlant, inst: ModelInstanceIndex, source: UrdfSource) -> list:
    """The plant's joints of the chain, base to flange."""
    return [plant.GetJointByName(n, inst) for n in source.joints]


def read_urdf_robot(path: Path | str, load_yaml: Callable) -> dict:
    """The fields of a :class:`kpioed_drake.robot.models.Robot` of a URDF file and its sidecar.

    Args:
        path: the URDF file.
        load_yaml: ``(path, schema) -> spec`` (the model files' YAML loader, errors name the file).

    Returns:
        the Robot fields; ``capsules`` as tuples ``(name, link, radius, a, b)`` [mm].

    Raises:
        InputError: malformed XML, an unsupported joint type, a branching tree, a bad sidecar.
    """
    path = Path(path)
    xml, side, sw = _read_files(path, load_yaml)
    chain_xml, parents, root, welded = chain_joints(xml, path, measured_links(side, sw, path))
    mimicked = mimics(chain_xml, path)  # the URDF's own joint map: its errors name the URDF
    X_WB = _base_pose(side, welded, sw, path)
    names = tuple(j.get("name") for j in chain_xml)
    overrides = sidecar_limits(side, sw)
    text = _stripped(checked_limits(xml, overrides, path), side.masses, chain_xml, sw)
    source = UrdfSource(str(path), text, X_WB, root, names)
    plant, ctx, inst, joints = _finalized_plant(source)
    R_PJ, p_PJ, axis, pris, lo, up, bodies = _joint_frames(plant, ctx, joints, parents, path)
    lo, up = _limits(overrides, names, pris, lo, up, sw, path)
    tree = bool(np.any(parents != np.arange(len(joints)) - 1))
    chain = Chain(R_PJ=R_PJ, p_PJ=p_PJ, axis=axis, prismatic=pris, parent=parents if tree else None)
    masses, coms, owner = _inertia(plant, ctx, bodies)
    if side.capsules:
        caps = _side_capsules(side, len(joints), sw)
    else:
        caps = _capsules(xml, plant, ctx, inst, bodies, owner, path)
    if side.targets:
        p_FQ, targets, target_links, placed = _link_targets(side, plant, ctx, inst, bodies, owner, sw)
        source = dataclasses.replace(source, target_placements=placed)
    else:
        (p_FQ, targets), target_links = _reflector(side, sw), None
    q_work = _q_work(side, pris, lo, up, sw)
    X_WT = _tracker_pose(side, sw)
    pairs = _link_pairs(side, parents, sw)
    joint_map = _joint_map(side, xml, names, mimicked, pris, sw, path)
    refl = p_FQ if targets is None else targets
    gauge = _gauge(side, chain, lo, up, refl, sw, path, joint_map, target_links)
    conventions = tuple("prismatic" if p else "revolute" for p in pris)
    table = dict(name=side.name or path.stem, conventions=conventions, lower=lo, upper=up)
    links = dict(capsules=caps, masses=masses, coms=coms, self_pairs=tuple(pairs), q_work=q_work)
    frames = dict(p_FQ=p_FQ, X_WT=X_WT, targets=targets, joint_names=names, joint_map=joint_map)
    urdf = dict(geometry=np.zeros((len(joints), 7)), chain=chain, gauge=gauge, urdf=source)
    return dict(
        **table,
        **links,
        **frames,
        **urdf,
        source=str(path),
        target_links=target_links,
        estimated_errors=side.estimated_errors,
        **shared_fields(side, sw, names),
    )


def _read_files(path: Path, load_yaml: Callable) -> tuple[ET.Element, SidecarSpec, str]:
    """The URDF's XML (its numbers checked), the sidecar (empty without a file) and its path."""
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    xml = _parse_xml(path)
    check_numbers(xml, path)
    side_path = sidecar_path(path)
    side = load_yaml(side_path, SidecarSpec) if side_path.is_file() else SidecarSpec()
    return xml, side, str(side_path)


def _finalized_plant(source: UrdfSource) -> tuple[MultibodyPlant, Context, ModelInstanceIndex, list]:
    """A plant of the robot alone (finalized), its default context, model instance and joints."""
    plant = MultibodyPlant(0.0)
    inst = add_urdf(plant, source)
    plant.Finalize()
    return plant, plant.CreateDefaultContext(), inst, movable_joints(plant, inst, source)


def _joint_map(
    side: SidecarSpec,
    xml: ET.Element,
    names: tuple[str, ...],
    mimicked: dict,
    pris: np.ndarray,
    sw: str,
    path: Path,
) -> JointMap | None:
    """The sidecar's joint map, else the URDF's ``<mimic>`` joints' (joints off the chain named)."""
    off_chain = {
        j.get("name"): j.get("type") == "prismatic"
        for j in xml.iter("joint")
        if j.get("type") in MOVABLE and j.get("name") not in names
    }
    jwhere = sw if side.joint_map else str(path)
    jmap = side.joint_map or mimic_joint_map(
        list(names), mimicked, [MM if p else 1.0 for p in pris], jwhere, off_chain=off_chain
    )
    return joint_map_from_spec(jmap, jwhere, joint_names=names, prismatic=pris)


def _base_pose(side, welded: bool, sw: str, path: Path) -> RigidTransform | None:
    """The root link's weld ``X_WB`` from the sidecar's ``base_xyz_mm`` / ``base_rpy_deg`` (identity
    when neither is given), or None when the URDF welds its root to "world" itself."""
    X_WB = None
    if side.base_xyz_mm or side.base_rpy_deg:
        if welded:
            raise InputError(f"{sw}: base_xyz_mm/base_rpy_deg given, but {path} welds its root to 'world'")
        xyz = _vec(side.base_xyz_mm or [0, 0, 0], f"{sw}: base_xyz_mm") * MM
        rpy = np.deg2rad(_vec(side.base_rpy_deg or [0, 0, 0], f"{sw}: base_rpy_deg"))
        X_WB = RigidTransform(RollPitchYaw(rpy), xyz)
    elif not welded:
        X_WB = RigidTransform()
    return X_WB


def _joint_frames(plant: MultibodyPlant, ctx, joints, parents, path: Path):
    """The chain read from the finalized plant: per joint its placement ``R_PJ`` (n, 3, 3), ``p_PJ``
    (n, 3) [mm] in the parent link's frame, unit ``axis`` (n, 3), ``prismatic`` (n,) and the URDF's
    limits ``lo``, ``up`` (n,) [rad; prismatic mm]; and the bodies, world first, then each joint's
    child link (``parents``: each joint's parent joint, -1: W)."""
    n = len(joints)
    R_PJ, p_PJ, axis = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    pris = np.array([isinstance(j, PrismaticJoint) for j in joints])
    lo, up = np.zeros(n), np.zeros(n)
    bodies = [plant.world_body()]
    for i, j in enumerate(joints):
        X_P = plant.EvalBodyPoseInWorld(ctx, bodies[parents[i] + 1])
        X_PJ = X_P.inverse().multiply(j.frame_on_parent().CalcPoseInWorld(ctx))
        R_PJ[i], p_PJ[i] = X_PJ.rotation().matrix(), X_PJ.translation() / MM
        a = j.translation_axis() if pris[i] else j.revolute_axis()
        axis[i] = np.asarray(a) / np.linalg.norm(a)
        s = 1.0 / MM if pris[i] else 1.0
        lo[i], up[i] = j.position_lower_limits()[0] * s, j.position_upper_limits()[0] * s
        bodies.append(j.child_body())
        X_CM = j.frame_on_child().CalcPose(ctx, j.child_body().body_frame())
        if not X_CM.IsNearlyIdentity(1e-12):
            raise InputError(f"{path}: joint {j.name()!r}: the child link's frame is not the joint frame")
    return R_PJ, p_PJ, axis, pris, lo, up, bodies


def _reflector(side, sw: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The reflector offset ``p_FQ`` (3,) and the targets (T, 3) in the flange frame [mm], None where
    the sidecar gives none."""
    p_FQ, targets = None, None
    if side.reflector_position_mm:
        p_FQ = _vec(side.reflector_position_mm, f"{sw}: reflector_position_mm")
    if side.targets_mm:  # several targets: target 1 is the reflector (as targets_mm of a YAML robot)
        targets = np.array([_vec(t, f"{sw}: targets_mm[{k}]") for k, t in enumerate(side.targets_mm)])
        if p_FQ is not None and not np.allclose(p_FQ, targets[0], rtol=0.0, atol=1e-9):
            raise InputError(
                f"{sw}: reflector_position_mm differs from targets_mm[0] (target 1 is the reflector)"
            )
        p_FQ = targets[0]
    return p_FQ, targets


def _link_targets(side, plant, ctx, inst, bodies, owner, sw: str):
    """``p_FQ`` (3,), the targets (T, 3; None for one) in their moving links' frames [mm], those
    links' frame indices (T,) and each named link's placement in its moving link, from the
    sidecar's ``targets`` (each in its named link's frame)."""
    offsets, links, placements = [], [], []
    for k, t in enumerate(side.targets):
        body = plant.GetBodyByName(t.link, inst)
        i = owner.get(int(body.index()))
        if i is None:
            raise InputError(f"{sw}: targets[{k}].link {t.link!r} does not move with the robot's joints")
        if i == 0:
            raise InputError(f"{sw}: targets[{k}].link {t.link!r} is fixed to the base (no joint moves it)")
        X_OL = plant.EvalBodyPoseInWorld(ctx, bodies[i]).inverse() @ plant.EvalBodyPoseInWorld(ctx, body)
        offsets.append(X_OL @ (_vec(t.position_mm, f"{sw}: targets[{k}].position_mm") * MM) / MM)
        links.append(i)
        placements.append((X_OL.rotation().matrix(), X_OL.translation() / MM))
    targets = np.array(offsets)
    many = targets if len(targets) > 1 else None
    return targets[0], many, np.array(links, dtype=int), tuple(placements)


def _tracker_pose(side, sw: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The sidecar's tracker pose ``(p_WT (3,) [mm], R_WT (3, 3))``, or None."""
    X_WT = None
    if side.tracker_position_mm:
        rpy = np.deg2rad(_vec(side.tracker_rpy_deg or [0.0, 0.0, 0.0], f"{sw}: tracker_rpy_deg"))
        R_WT = RollPitchYaw(rpy).ToRotationMatrix().matrix()
        X_WT = (_vec(side.tracker_position_mm, f"{sw}: tracker_position_mm"), R_WT)
    return X_WT


def _link_pairs(side, parents: np.ndarray, sw: str) -> list[tuple[int, int]]:
    """The self-collision pairs (lower link first) of links 0..n, after checking them and the
    beam links (neighbours: a link and its parent link, ``parents`` (n,) per joint, -1: W)."""
    n = len(parents)
    pairs = []
    for pr in side.self_collision_pairs:
        ok = len(pr) == 2 and all(0 <= x <= n for x in pr)
        if not ok or min(pr) == max(pr) or parents[max(pr) - 1] + 1 == min(pr):
            raise InputError(
                f"{sw}: self_collision_pairs entry {pr} must be two non-neighbour links in 0..{n}"
            )
        pairs.append((int(min(pr)), int(max(pr))))
    if any(not 0 <= x <= n for x in side.beam_links):
        raise InputError(f"{sw}: beam_links must be link indices in 0..{n}, got {side.beam_links}")
    return pairs


def _gauge(side, chain, lo, up, p_FQ, sw, path, joint_map=None, links=None) -> tuple[str, ...]:
    if side.gauge:
        unknown = sorted(set(side.gauge) - set(param_names(chain.n_joints)))
        if unknown:
            raise InputError(f"{sw}: gauge names {unknown}, not joint parameters of {path}")
        return tuple(side.gauge)
    try:
        p = _GENERIC_REFLECTOR if p_FQ is None else p_FQ
        return auto_gauge(chain, lo, up, p, joint_map=joint_map, links=links)
    except ValueError as exc:
        msg = f"{path}: automatic gauge: {exc}; name the parameters to hold in {sw} (gauge:)"
        raise InputError(msg) from None


def _vec(values, where: str, size: int = 3) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: expected {size} finite numbers, got {values!r}")
    return arr


def _limits(overrides, names, pris, lo, up, sw, path):
    lo, up = lo.copy(), up.copy()
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise InputError(f"{sw}: limits: unknown joints {unknown} (joints: {', '.join(names)})")
    for i, name in enumerate(names):
        if name in overrides:
            lower, upper = overrides[name]
            lo[i], up[i] = (lower, upper) if pris[i] else np.deg2rad([lower, upper])
        elif not (np.isfinite(lo[i]) and np.isfinite(up[i])):
            if pris[i]:
                raise InputError(f"{path}: prismatic joint {name!r} has no limits; give them in {sw}")
            lo[i], up[i] = -2.0 * np.pi, 2.0 * np.pi  # a continuous joint: one turn either way
    return lo, up


def _q_work(side, pris, lo, up, sw):
    if not side.q_work:
        return None
    qw = _vec(side.q_work, f"{sw}: q_work", size=len(pris))
    q = np.where(pris, qw, np.deg2rad(qw))
    bad = np.flatnonzero((q < lo) | (q > up))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{sw}: q_work[{k}] = {qw[k]:g} is outside joint {k + 1}'s limits")
    return q


def _inertia(plant, ctx, bodies):
    """Masses (n+1,) [kg], centres of mass (n+1, 3) [mm] per link (welded bodies merged), owner map."""
    n = len(bodies) - 1
    masses, coms, owner = np.zeros(n + 1), np.zeros((n + 1, 3)), {}
    for i, body in enumerate(bodies):
        X_WL = plant.EvalBodyPoseInWorld(ctx, body)
        mc = np.zeros(3)
        for b in plant.GetBodiesWeldedTo(body):
            owner[int(b.index())] = i
            if i == 0 and b.index() == plant.world_body().index():
                continue
            m = b.default_mass()
            X_LB = X_WL.inverse().multiply(plant.EvalBodyPoseInWorld(ctx, b))
            masses[i] += m
            mc += m * (X_LB @ np.asarray(b.default_com())) / MM
        coms[i] = mc / masses[i] if masses[i] > 0 else 0.0
    return masses, coms, owner


def _capsules(xml, plant, ctx, inst, bodies, owner, path):
    out = []
    for lk in xml.findall("link"):
        name = lk.get("name")
        if name == "world":
            continue
        body = plant.GetBodyByName(name, inst)
        if int(body.index()) not in owner:  # a link of a branch off the measured chain
            continue
        i = owner[int(body.index())]
        X_WO = plant.EvalBodyPoseInWorld(ctx, bodies[i])
        X_OL = X_WO.inverse().multiply(plant.EvalBodyPoseInWorld(ctx, body))
        for k, col in enumerate(lk.findall("collision")):
            where = f"{path}: link {name!r} collision {k}"
            geo = _capsule_geometry(col, where)
            if geo is None:
                continue
            r, a, b = geo
            X = X_OL.multiply(_origin(col, where))
            out.append((col.get("name") or f"{name}_{k}", i, r / MM, (X @ a) / MM, (X @ b) / MM))
    return tuple(out)


def _capsule_geometry(col, where):
    """Radius [m] and end points (3,) [m] in the collision origin frame, or None (a mesh)."""
    g = col.find("geometry")
    shape = None if g is None or not len(g) else g[0]
    if shape is None:
        raise InputError(f"{where}: no geometry")
    tag = shape.tag.split("}")[-1]
    if tag in ("cylinder", "capsule"):
        r, length = (floats(shape, k, "nan", where, bound=MAX_LENGTH_M)[0] for k in ("radius", "length"))
        half = np.array([0.0, 0.0, 0.5 * length])
        sizes = (r, length)
    elif tag == "sphere":
        r = floats(shape, "radius", "nan", where, bound=MAX_LENGTH_M)[0]
        half, sizes = np.zeros(3), (r,)
    elif tag == "box":
        size = floats(shape, "size", "nan nan nan", where, bound=MAX_LENGTH_M)
        k = int(np.argmax(size))
        half = np.zeros(3)
        half[k] = 0.5 * size[k]
        r, sizes = 0.5 * float(np.linalg.norm(np.delete(size, k))), tuple(size)
    else:
        return None
    if min(sizes) < 0:
        raise InputError(f"{where}: <{tag}>: expected sizes >= 0, got {', '.join(f'{s:g}' for s in sizes)}")
    return r, -half, half


def _side_capsules(side, n, sw):
    out = []
    for k, c in enumerate(side.capsules):
        w = f"{sw}: capsules[{k}]"
        if not 0 <= c.link <= n:
            raise InputError(f"{w}: link must be in 0..{n}, got {c.link}")
        if not (np.isfinite(c.radius_mm) and c.radius_mm > 0):
            raise InputError(f"{w}: radius_mm must be a finite number > 0, got {c.radius_mm!r}")
        a, b = _vec(c.a_mm, f"{w}.a_mm"), _vec(c.b_mm, f"{w}.b_mm")
        out.append((c.name or f"link{c.link}_{k}", c.link, float(c.radius_mm), a, b))
    return tuple(out)
