"""The effects of an extended model file: its ``effects:`` entries as effects with values, and back.

A model file holds each effect as a :class:`~kpioed_drake.robot.modelspec.EffectSpec` (its text
name, values and standard deviations in display units, and for ``joint_elasticity_basis`` the
basis the values belong to); :func:`model_effects` turns a loaded robot's entries into
:class:`~kpioed_drake.effects.model.Effect` objects, :func:`effect_specs` writes estimated effects.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.effects.gravity_basis import check_basis, joint_basis
from kpioed_drake.effects.model import BASIS_FAMILIES, UNITS, Effect, parse_effect
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.modelspec import EffectSpec


def model_effects(robot: Robot) -> list[Effect]:
    """The effects of ``robot``'s model file with their values (internal units); [] for a
    geometric model. A ``joint_elasticity_basis`` entry's basis is the robot's for that joint
    (:func:`~kpioed_drake.effects.gravity_basis.joint_basis` reads it from the file's entries).

    Raises:
        InputError: the file and field (``effects[k].name`` ...) of a bad entry.
    """
    out: list[Effect] = []
    for k, spec in enumerate(robot.effects):
        at = f"{robot.effects_where}: effects[{k}]"
        text = f"{spec.name}=" + ",".join(repr(float(v)) for v in spec.values)
        try:
            eff = parse_effect(text, n_joints=robot.n_joints)
        except InputError as exc:
            raise InputError(f"{at}.name/values: {exc}") from None
        if spec.unit and spec.unit != UNITS[eff.family]:
            raise InputError(f"{at}.unit: {eff.family} values are in {UNITS[eff.family]}, got {spec.unit!r}")
        if eff.family in BASIS_FAMILIES:
            eff = _stored_basis(robot, eff, spec, at)
        if any(e.key == eff.key for e in out):
            raise InputError(f"{at}.name: {eff.name} is given more than once")
        out.append(eff)
    return out


def _stored_basis(robot: Robot, eff: Effect, spec: EffectSpec, at: str) -> Effect:
    if not spec.basis_rms:
        raise InputError(f"{at}.basis_rms: {eff.name} needs its basis (basis_rms, basis_directions)")
    try:
        jb = check_basis(robot, eff.joint, spec.basis_rms, spec.basis_directions)
    except InputError as exc:
        raise InputError(f"{at}.basis_rms: {exc}") from None
    sizes = (jb.rank, jb.rank + 1) if eff.family == BASIS_FAMILY else (jb.rank,)
    if eff.n_basis not in sizes:
        want = " or ".join(str(k) for k in sizes)
        raise InputError(f"{at}.values: expected {want} values, got {eff.n_basis}")
    return eff


def effect_specs(
    effects: Sequence[Effect], std: np.ndarray | None = None, *, robot: Robot | None = None
) -> list[EffectSpec]:
    """Model-file entries of estimated ``effects`` (display units).

    Args:
        effects: effects with values, in the order of their parameters.
        std: (sum of n_params,) standard deviations of their values (internal units), or None.
        robot: the robot the values were estimated on (its basis is stored with a
            ``joint_elasticity_basis``; required for one).
    """
    out, c = [], 0
    for e in effects:
        s = None if std is None else np.asarray(std[c : c + e.n_params], dtype=float)
        c += e.n_params
        spec = EffectSpec(
            name=e.name,
            values=e.display_values(),
            std=[] if s is None else e.display_values(s),
            unit=UNITS[e.family],
        )
        if e.family in BASIS_FAMILIES:
            jb = joint_basis(robot, e.joint) if e.family == BASIS_FAMILY else lb.lateral_basis(robot, e.joint)
            spec.basis_rms = jb.D.tolist()
            spec.basis_directions = jb.V.tolist()
        out.append(spec)
    return out
