"""Named variants of the study's problem: the assumptions the paper leaves open, one change each.

The paper (Jost et al. 2017, sections 3.2-3.4) does not publish everything that sets the absolute
values of Tables 6-8: which parameters it estimates (Table 2: "Zero offsets of the underlined values
are considered in OED"; the underlines are lost in our copy), how the incidence limit of Table 4
("angle between sensor surface and laser beam >= 30 deg") is measured, the working pose q_work,
the scaling P of Cp in eq. (25) and where the KPI point (the TCP of eq. 12) sits relative to the
reflector. A :class:`Variant` is one documented choice for these; :func:`variant_problem` builds
its :class:`~kpioed_drake.estimation.problem.Problem` through the keyword options of
:func:`~kpioed_drake.estimation.problem.make_problem`. The ``default`` variant is SPEC's problem, exactly
``make_problem(robot)``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import Problem, make_problem
from kpioed_drake.robot.models import load_robot
from kpioed_drake.robot.parameters import FIXED_NAMES, parameter_layout

DEFAULT = "default"
"""Name of SPEC's problem (task ids and file names carry no variant suffix)."""

JOINT_OFFSETS = ("theta2", "theta3", "theta4", "theta5")
"""The joint zero offsets that are not gauge (theta1 and theta6 are held by SPEC's gauge)."""

PAPER_TCP_FROM_REFLECTOR_MM = (89.58, 2.84, -327.03)
"""The origin of the paper's TCP frame k seen from the reflector, flange axes [mm]: the paper's
Table 3 reflector position ``k c`` negated."""


@dataclasses.dataclass(frozen=True)
class Variant:
    """One choice of the assumptions the paper leaves open."""

    name: str
    """Identifier (``kpioed study --variant NAME``; part of task ids unless ``default``)."""
    description: str
    """What it changes against SPEC's problem, and why it is a reading of the paper."""
    estimate_only: tuple[str, ...] | None = None
    """Geometric parameters estimated besides the tracker pose and the reflector offset (the rest
    held at nominal); None: SPEC's 27."""
    max_incidence_deg: float | None = None
    """Incidence limit from the reflector's axis [deg]; None: the cell's (30)."""
    param_scaling: str = "reach"
    """Scaling of phi_A(Cp): ``reach`` (SPEC) or ``none`` (paper eq. 25 with the identity)."""
    tool_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """KPI point relative to the reflector, flange axes [mm]."""
    kpi_point: str = "reflector"
    """``reflector`` (plus ``tool_offset_mm``) or ``flange`` (the flange origin)."""
    q_work_shift_deg: tuple[float, ...] = (0.0,) * 6
    """Added to the model file's working pose [deg]."""


def _variants(*vs: Variant) -> dict[str, Variant]:
    return {v.name: v for v in vs}


VARIANTS: dict[str, Variant] = _variants(
    Variant(
        DEFAULT,
        "SPEC's problem: 27 parameters, incidence <= 30 deg from the axis, SPEC q_work, "
        "Cp scaled by the reach, the reflector as KPI point",
    ),
    Variant(
        "offsets",
        "only the joint zero offsets theta2-theta5 (Table 2's 'zero offsets') with the tracker pose "
        "and the reflector offset: 13 parameters",
        estimate_only=JOINT_OFFSETS,
    ),
    Variant(
        "incidence60",
        "incidence <= 60 deg from the reflector's axis (= at least 30 deg from the sensor surface, "
        "Table 4's wording)",
        max_incidence_deg=60.0,
    ),
    Variant(
        "pose-side",
        "working pose turned by -90 deg about joint 1 (beside the car, away from the tracker); "
        "with theta1 in the gauge this only rotates Cs, so tr(Cs) cannot change",
        q_work_shift_deg=(-90.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    ),
    Variant(
        "pose-wrist",
        "working pose with the wrist bent by +60 deg about joint 5",
        q_work_shift_deg=(0.0, 0.0, 0.0, 0.0, 60.0, 0.0),
    ),
    Variant(
        "unscaled",
        "phi_A(Cp) without scaling (paper eq. 25 with the identity: angles in radians)",
        param_scaling="none",
    ),
    Variant(
        "tool",
        "KPI point = the origin of the paper's TCP frame k (the reflector sits at Table 3's "
        "(-89.58, -2.84, 327.03) mm from it), a tool point 340 mm from the reflector",
        tool_offset_mm=PAPER_TCP_FROM_REFLECTOR_MM,
    ),
    Variant(
        "flange",
        "KPI point = the flange origin, frame k of the paper, as a point of the robot: the same point "
        "as `tool`, but it does not move with the estimated reflector offset",
        kpi_point="flange",
    ),
)
"""The variants of the sensitivity study (docs/studies.md, "Why our numbers differ")."""


def combine(name: str, parts: list[Variant], description: str | None = None) -> Variant:
    """One variant making all the changes of ``parts`` (each changes different fields).

    Raises:
        InputError: two parts change the same field.
    """
    base = Variant(DEFAULT, "")
    changes: dict[str, object] = {}
    for part in parts:
        for f in dataclasses.fields(Variant)[2:]:
            value = getattr(part, f.name)
            if value == getattr(base, f.name):
                continue
            if f.name in changes:
                raise InputError(f"variant {name}: two parts change {f.name}", fields=("variant",))
            changes[f.name] = value
    text = description or "; ".join(p.description for p in parts)
    return dataclasses.replace(base, name=name, description=text, **changes)


def get_variant(name: str) -> Variant:
    """The variant called ``name``; ``a+b+...`` combines named variants (:func:`combine`).

    Raises:
        InputError: an unknown name, or parts that change the same field.
    """
    if not isinstance(name, str) or not all(part in VARIANTS for part in name.split("+")):
        raise InputError(
            f"variant {name!r}: expected one of {', '.join(VARIANTS)} or a+b of them", fields=("variant",)
        )
    if "+" not in name:
        return VARIANTS[name]
    return combine(name, [VARIANTS[part] for part in name.split("+")])


def variant_problem(robot: str, variant: str | Variant = DEFAULT) -> Problem:
    """The problem of ``robot`` under a variant (``default``: exactly ``make_problem(robot)``).

    Raises:
        InputError: an unknown variant or robot, or a shifted working pose outside the joint limits.
    """
    v = variant if isinstance(variant, Variant) else get_variant(variant)
    r = load_robot(robot)
    fixed = None
    if v.estimate_only is not None:
        layout = parameter_layout(r)
        geometric = layout.names[layout.joints]
        fixed = FIXED_NAMES + tuple(n for n in geometric if n not in v.estimate_only + FIXED_NAMES)
    q_work = None
    if any(v.q_work_shift_deg):
        if r.q_work is None:
            raise InputError(f"{r.name}: variant {v.name} shifts q_work, but the model file has none")
        q_work = r.q_work + np.deg2rad(v.q_work_shift_deg)
    return make_problem(
        r,
        q_work=q_work,
        fixed=fixed,
        max_incidence_deg=v.max_incidence_deg,
        param_scaling=v.param_scaling,
        tool_offset_mm=v.tool_offset_mm,
        kpi_point=v.kpi_point,
    )


SENSITIVITY_VARIANTS: tuple[str, ...] = (
    *VARIANTS,
    *(
        f"{kpi}+{other}"
        for kpi in ("tool", "flange")
        for other in ("offsets", "incidence60", "unscaled", "pose-wrist")
    ),
)
"""The variants of the sensitivity study (``studies/sensitivity.py``): each single change, then
each of the two KPI points of the paper's frame k combined with each other change that can move
the numbers (``pose-side`` cannot)."""

CLOSEST = "tool"
"""The variant closest to the paper's Table 6 in the sensitivity study (docs/studies.md): the
smallest mean gap of the two gains and an absolute level within a few per cent of the paper's; no
combination with a further change came closer."""
