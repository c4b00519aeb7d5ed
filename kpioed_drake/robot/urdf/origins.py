"""A URDF robot's joint placements with estimated errors folded in, or folded back out.

The errors of joint i (:mod:`kpioed_drake.robot.chain`: offset, three translations, three small
rotations) act as ``E(e) = Trans(px, py, pz) Rx(rx) Ry(ry) Rz(rz) M(off)`` on the right of the joint's
placement, ``M(off)`` the joint's own motion by its offset. A calibrated URDF holds ``X' = X E(e)``
(:func:`fold`, :mod:`.write`); the model its calibration started from is ``X = X' E(e)^-1``
(:func:`unfold`): the reference geometry on which an extended model's effects are evaluated, as the
fit evaluated them (:class:`kpioed_drake.robot.models.Reference`).
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

from kpioed_drake.robot.chain import Chain, rot_axis

MM = 1e-3
"""Metres per millimetre (URDF lengths are in metres)."""


def error_transform(
    axis: np.ndarray, prismatic: bool, errors: np.ndarray, *, scale: float = 1.0
) -> RigidTransform:
    """``E(e)`` of one joint: ``errors`` (7,) ``off, px, py, pz, rx, ry, rz`` [rad, mm]; ``scale``
    multiplies the lengths (``MM`` for a URDF's metres)."""
    off, px, py, pz, rx, ry, rz = np.asarray(errors, dtype=float)
    R = RotationMatrix.MakeXRotation(rx) @ RotationMatrix.MakeYRotation(ry) @ RotationMatrix.MakeZRotation(rz)
    X = RigidTransform(R, np.array([px, py, pz]) * scale)
    if prismatic:
        return X @ RigidTransform(np.asarray(axis, dtype=float) * off * scale)
    return X @ RigidTransform(RotationMatrix(rot_axis(np.asarray(axis, dtype=float), off)))


def fold(
    X: RigidTransform, axis: np.ndarray, prismatic: bool, errors: np.ndarray, *, scale: float = 1.0
) -> RigidTransform:
    """``X E(e)``: a placement with the errors folded in."""
    return X @ error_transform(axis, prismatic, errors, scale=scale)


def unfold(
    X: RigidTransform, axis: np.ndarray, prismatic: bool, errors: np.ndarray, *, scale: float = 1.0
) -> RigidTransform:
    """``X E(e)^-1``: a placement with the errors folded back out."""
    return X @ error_transform(axis, prismatic, errors, scale=scale).inverse()


def unfolded_chain(chain: Chain, errors: np.ndarray) -> Chain:
    """``chain`` with ``errors`` (nj, 7) [rad, mm] folded out of every joint's placement: the chain
    whose frames with these errors are ``chain``'s frames without errors."""
    R_PJ, p_PJ = chain.R_PJ.copy(), chain.p_PJ.copy()
    for i in range(chain.n_joints):
        X = unfold(
            RigidTransform(RotationMatrix(R_PJ[i]), p_PJ[i]), chain.axis[i], chain.prismatic[i], errors[i]
        )
        R_PJ[i], p_PJ[i] = X.rotation().matrix(), X.translation()
    return dataclasses.replace(chain, R_PJ=R_PJ, p_PJ=p_PJ)


def origin(el: ET.Element) -> RigidTransform:
    """A URDF joint element's ``<origin>`` (identity where absent) [m, rad]."""
    o = el.find("origin")
    xyz = [float(x) for x in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
    rpy = [float(x) for x in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
    return RigidTransform(RollPitchYaw(rpy), xyz)


def set_origin(el: ET.Element, X: RigidTransform) -> None:
    """Write ``X`` into a URDF joint element's ``<origin>`` (xyz [m], rpy [rad], 17 digits)."""
    o = el.find("origin")
    if o is None:
        o = ET.SubElement(el, "origin")
    o.set("xyz", _fmt(X.translation()))
    o.set("rpy", _fmt(RollPitchYaw(X.rotation()).vector()))


def _fmt(v) -> str:
    return " ".join(f"{(0.0 if abs(x) < 1e-15 else float(x)):.17g}" for x in v)


def moved_origins(
    root: ET.Element, joints: Sequence[str], chain: Chain, errors: np.ndarray, *, out: bool
) -> None:
    """Fold ``errors`` (nj, 7) [rad, mm] into (``out`` False) or out of (``out`` True) the
    ``<origin>`` of the chain's joints ``joints`` (names, base to flange) in the URDF tree ``root``."""
    by_name = {j.get("name"): j for j in root.findall("joint")}
    move = unfold if out else fold
    for i, name in enumerate(joints):
        el = by_name[name]
        set_origin(el, move(origin(el), chain.axis[i], bool(chain.prismatic[i]), errors[i], scale=MM))


def unfolded_text(text: str, joints: Sequence[str], chain: Chain, errors: np.ndarray) -> str:
    """URDF ``text`` with ``errors`` folded out of the chain joints' origins."""
    root = ET.fromstring(text)
    moved_origins(root, joints, chain, errors, out=True)
    return ET.tostring(root, encoding="unicode")
