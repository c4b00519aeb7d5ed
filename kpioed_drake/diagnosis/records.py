"""The diagnosis's records: a candidate's test, a selection step, the selection, a named cause.

Frozen dataclasses, passed between the modules and replaced (``dataclasses.replace``), never changed
in place. Each holds the numbers the report shows (JSON built from them by
:mod:`~kpioed_drake.diagnosis.report`) and what later steps need but the report does not (a
candidate's projected basis, its fit and held-out residuals). Effects are named by their canonical
text (:attr:`kpioed_drake.effects.Effect.name`, e.g. ``gear_cyclic:4:2``) throughout: the keys of
``evidence`` and the names in ``removed``, ``added_with`` and the steps.

:func:`describe_causes`: each named cause in words a calibration engineer reads: what it is
physically, the joint and link it acts on, its size at the reflector over the data, and what a
mass-free basis stands for. The size is that of the cause's contribution to the measurements at the
fitted values (the linearised signal, its 3-D norm per measured point): median and largest over the
data's rows [mm].
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.fit import Fit, FitProblem, HeldOutGain
from kpioed_drake.effects import compliance as cp
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects import lateral_basis as lb
from kpioed_drake.effects.model import Effect
from kpioed_drake.robot.drivetrain import follower_factor
from kpioed_drake.robot.models import Robot


def _statistics(test) -> dict:
    """``{key: value}`` of a test's ``STATISTICS`` that are not None, in order (tuples as lists)."""
    out = {}
    for item in test.STATISTICS:
        key, name = item if isinstance(item, tuple) else (item, item)
        value = getattr(test, name)
        if value is not None:
            out[key] = list(value) if isinstance(value, tuple) else value
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class CandidateTest:
    """One candidate's test in a selection step (a row of the step's record).

    Attributes:
        effect: the candidate.
        remaining, max_corr, condition: its identifiability beside the current model
            (:func:`~kpioed_drake.diagnosis.selection.identifiability`).
        score: score statistic (the linearised likelihood ratio) of its best side; None: not scored.
        n_sides: sides a backlash was scored with (:mod:`~kpioed_drake.diagnosis.sides`); None: one.
        lr_stat: likelihood ratio of the refit against the current model (chi2 difference); None:
            not refitted. dof: its degrees of freedom (the candidate's parameters).
        p_value: marginal p-value of ``lr_stat``; p_value_corrected: family-wise over the step
            (weighted min-p, :mod:`~kpioed_drake.estimation.multiplicity`).
        delta_bic: ``lr_stat - dof ln(3 n)``, less ``side_penalty`` for a backlash of several sides.
        side_penalty: ``2 ln K_eff`` of the choice among its sides
            (:func:`~kpioed_drake.diagnosis.sides.side_penalty`); None: one side.
        holdout_rms_mm: held-out RMS of the model with it (the step's best candidate only) [mm].
        status: why it was not refitted or not added, or None.
        basis: (3 n, k) orthonormal basis of its columns outside the model's span, at its expected
            side (for the pair step); None: not scored.
        side: (n,) the side its score chose, for a backlash scored with several; None: the
            problem's side.
        side_bases: the bases of all its sides (for ``side_penalty``); None: one side.
        weight: its normalized weight in the step's weighted min-p test; None: not scored.
        fit: the refit with it, when it is significant with a BIC gain; None otherwise.
        holdout: (n, 3) held-out residuals of ``fit`` (the step's best candidate only) [mm].
    """

    effect: fx.Effect
    remaining: float
    max_corr: float
    condition: float
    score: float | None = None
    n_sides: int | None = None
    lr_stat: float | None = None
    dof: int | None = None
    p_value: float | None = None
    p_value_corrected: float | None = None
    delta_bic: float | None = None
    side_penalty: float | None = None
    holdout_rms_mm: float | None = None
    status: str | None = None
    basis: np.ndarray | None = dataclasses.field(default=None, repr=False)
    side: np.ndarray | None = dataclasses.field(default=None, repr=False)
    side_bases: tuple | None = dataclasses.field(default=None, repr=False)
    weight: float | None = None
    fit: Fit | None = dataclasses.field(default=None, repr=False)
    holdout: np.ndarray | None = dataclasses.field(default=None, repr=False)
    holdout_gain: HeldOutGain | None = dataclasses.field(default=None, repr=False)

    @property
    def effects(self) -> tuple[fx.Effect, ...]:
        """What the test would add: the candidate."""
        return (self.effect,)

    STATISTICS = (
        "remaining",
        "max_corr",
        "condition",
        "score",
        ("side_patterns", "n_sides"),
        "lr_stat",
        "dof",
        "p_value",
        "p_value_corrected",
        "delta_bic",
        "side_penalty",
        "holdout_rms_mm",
        "status",
    )
    """The report's keys of :meth:`statistics`, in order (``(key, attribute)`` where they differ)."""

    def statistics(self) -> dict:
        """The numbers of the test in the report's order (its row without the candidate's name)."""
        return _statistics(self)


@dataclasses.dataclass(frozen=True, eq=False)
class PairTest:
    """The joint test of two correlated candidates (a row of a pair step, :mod:`.pairs`).

    Attributes:
        effects: the two candidates.
        canonical_correlation: largest canonical correlation of their projected bases.
        score: score statistic of the span of both; dof: its dimension.
        p_value, p_value_corrected: marginal and family-wise over the step's pairs (min-p) p-values,
            of ``score``, then of ``lr_stat`` once refitted.
        lr_stat: likelihood ratio of the refit with both; None: not refitted.
        delta_bic: ``lr_stat - (k_a + k_b) ln(3 n)``.
        lr_given_other: likelihood ratio of each member given the other (a, b).
        holdout_rms_mm: held-out RMS of the model with both [mm] (an accepted refit only).
        status: why the pair was not added, or None.
        fit, holdout: the refit with both and its (n, 3) held-out residuals [mm] (accepted refit only).
        holdout_gain: the gain of ``holdout`` with its uncertainty (an added pair only).
    """

    effects: tuple[fx.Effect, fx.Effect]
    canonical_correlation: float
    score: float
    dof: int
    p_value: float
    p_value_corrected: float
    lr_stat: float | None = None
    delta_bic: float | None = None
    lr_given_other: tuple[float, float] | None = None
    holdout_rms_mm: float | None = None
    status: str | None = None
    fit: Fit | None = dataclasses.field(default=None, repr=False)
    holdout: np.ndarray | None = dataclasses.field(default=None, repr=False)
    holdout_gain: HeldOutGain | None = dataclasses.field(default=None, repr=False)

    STATISTICS = (
        "canonical_correlation",
        "score",
        "dof",
        "p_value",
        "p_value_corrected",
        "lr_stat",
        "delta_bic",
        "lr_given_other",
        "holdout_rms_mm",
        "status",
    )
    """The report's keys of :meth:`statistics`, in order."""

    def statistics(self) -> dict:
        """The numbers of the test in the report's order (its row without the pair's names)."""
        return _statistics(self)


@dataclasses.dataclass(frozen=True)
class Swap:
    """A cause replaced by a candidate that fits significantly better given the other causes.

    Attributes:
        replaced: the cause's name; by: the candidate's name.
        lr_stat: likelihood ratio of the candidate given the other causes; lr_stat_replaced: the cause's.
    """

    replaced: str
    by: str
    lr_stat: float
    lr_stat_replaced: float


@dataclasses.dataclass(frozen=True)
class StandIn:
    """A significant candidate not named: a stand-in for an error outside the candidate list.

    Attributes:
        name: the candidate; holdout_gain: the fraction by which it lowers the held-out RMS;
        lr_stat: its likelihood ratio; reason: why it is a stand-in (a phrase).
    """

    name: str
    holdout_gain: float
    lr_stat: float
    reason: str


@dataclasses.dataclass(frozen=True, eq=False)
class SelectionStep:
    """One step of the stepwise selection (or a swap of a cause, :mod:`.alternatives`).

    Attributes:
        step: 1-based number.
        candidates: the tests of the step's candidates (none for a swap).
        holdout_rms_mm_before: held-out RMS of the model before the step [mm] (None for a swap).
        chi2_before: chi2 of the model before the step (None for a swap).
        pairs: the pair step's tests, when one ran after a step that added no single candidate.
        added: names of what the step added: none, a candidate or a pair.
        removed: names of the effects the backward step removed (for a swap: the replaced cause).
        swap: the swap, for a swap step.
    """

    step: int
    candidates: tuple[CandidateTest, ...] = ()
    holdout_rms_mm_before: float | None = None
    chi2_before: float | None = None
    pairs: tuple[PairTest, ...] = ()
    added: tuple[str, ...] = ()
    removed: tuple[str, ...] = ()
    swap: Swap | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Selection:
    """The state and outcome of the selection (:func:`~kpioed_drake.diagnosis.selection.select_effects`),
    replaced at each change.

    Attributes:
        problem: the fit problem of the current model: its conditions hold the side of each backlash
            as last chosen by a step (the expected side until then) and the gravity torques (a
            joint's torque fitted from the data once :mod:`.elastic_basis` has named one).
        fit: the extended model's fit (the baseline if nothing was added).
        holdout: (n, 3) its held-out residuals [mm].
        steps: the selection steps.
        evidence: per chosen effect's name, the statistics that put it in the model (JSON-ready;
            replaced, not changed in place).
        stand_ins: significant candidates left unnamed because their held-out gain was within its
            uncertainty while the model still failed the goodness-of-fit test.
        swaps: causes replaced by a candidate that fits significantly better given the other causes
            (:func:`~kpioed_drake.diagnosis.alternatives.settle`).
        stop: why the selection stopped, ``{"reason": key, "text": ...}``
            (:data:`~kpioed_drake.diagnosis.fit.STOPS`); None until it has.
    """

    problem: FitProblem
    fit: Fit
    holdout: np.ndarray
    steps: tuple[SelectionStep, ...] = ()
    evidence: Mapping[str, dict] = dataclasses.field(default_factory=dict)
    stand_ins: tuple[StandIn, ...] = ()
    swaps: tuple[Swap, ...] = ()
    stop: dict | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Alternative:
    """A competing explanation of a cause: what the data cannot tell apart from it.

    Attributes:
        effect: the alternative, with its fitted values (a candidate refitted in the cause's
            place) or without (the gravity basis of the cause's joint: the cause with other masses).
        evidence: its statistics (JSON-ready).
        plausible: whether its value is physically plausible (:mod:`~kpioed_drake.effects.physical`);
            None for the gravity basis, which has no value of its own in the report.
        plausible_reason: why not, or None.
    """

    effect: fx.Effect
    evidence: dict
    plausible: bool | None = None
    plausible_reason: str | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Cause:
    """A named effect of the extended model.

    Attributes:
        effect: the effect with its fitted values.
        std: standard deviations of its values (display units, as ``effect.display_values``).
        evidence: the statistics that named it, its final likelihood ratio given the other effects
            and its size at the reflector (JSON-ready).
        plausible: whether its value is physically plausible; plausible_reason: why not, or None.
        alternatives: the competing explanations the data cannot tell apart from it.
        description: the cause in words, its joint and link and its size at the reflector
            (:func:`~kpioed_drake.diagnosis.alternatives.describe`).
    """

    effect: fx.Effect
    std: tuple[float, ...]
    evidence: dict
    plausible: bool
    plausible_reason: str | None
    alternatives: tuple[Alternative, ...] = ()
    description: dict = dataclasses.field(default_factory=dict)


_WHAT = {
    "joint_elasticity": "joint {j} twists under the gravity torque it carries (a torsional compliance)",
    gb.FAMILY: "joint {j} twists under the gravity torque of the links it carries",
    "lateral_compliance": "the bearing of joint {j} tilts under the gravity moment across its axis",
    lb.FAMILY: "the bearing of joint {j} tilts under the gravity moment of the links it carries, across "
    "its axis",
    "gear_cyclic": "the gear of joint {j} errs cyclically, {h} time(s) a turn of the joint",
    "joint_scale": "the gear ratio (encoder scale) of joint {j} is off: an angle error growing with "
    "the angle",
    "joint_coupling": "joint {j} errs with the angle of joint {c}, whose axis its drive train crosses",
    "backlash": "joint {j} has play: it rests on one flank or the other with the sign of its gravity torque",
    "thermal_expansion": "the robot's links grow with the temperature",
    "tracker_scale": "the tracker's distances scale with the temperature (the air's refractive index)",
    "tracker_drift": "the tracker's frame drifts with the time",
    cp.COLUMN: "the lifting column bends with the carriage height under the gravity moment above joint {j}",
    cp.BASE: "the base (or floor) tilts under the robot's gravity moment",
    cp.LATERAL: "the bearing of joint {j} tilts under the gravity moment across its axis",
}
"""What each effect family is, physically (``{j}``: joint, ``{h}``: harmonic, ``{c}``: coupled joint)."""

_BASIS = (
    "The model file gives no masses, so the torque is fitted as {n} combination(s) of the carried "
    "links' mass moments (m, m c): the basis stands for the unknown masses and centres of mass times "
    "the joint's compliance; it predicts the deflection at other poses, not the masses themselves"
)


def child_links(robot: Robot) -> tuple[str, ...]:
    """The link each joint moves (its child link): a URDF robot's link names, else ``link i``."""
    names = tuple(f"link {i}" for i in range(1, robot.n_joints + 1))
    if robot.urdf is None:
        return names
    try:
        root = ET.fromstring(robot.urdf.text)
    except ET.ParseError:
        return names
    child = {
        j.get("name"): j.find("child").get("link")
        for j in root.findall("joint")
        if j.find("child") is not None
    }
    return (
        tuple(child.get(n, d) for n, d in zip(robot.urdf.joints, names, strict=False))
        + names[len(robot.urdf.joints) :]
    )


def describe(
    effect: Effect, robot: Robot, signal: np.ndarray, *, links: tuple[str, ...] | None = None
) -> dict:
    """The words and sizes of one named cause.

    Args:
        effect: the cause (:class:`~kpioed_drake.effects.Effect`, fitted).
        robot: the robot (joint and link names).
        signal: (n, 3) its contribution to the measured points [mm].
        links: :func:`child_links` of ``robot`` (computed when None).

    Returns:
        ``{"text", "median_mm", "max_mm", "joint_name", "link"}`` (the last two for a joint's effect).
    """
    size = np.linalg.norm(np.asarray(signal, dtype=float), axis=1)
    med, top = (float(np.median(size)), float(np.max(size))) if size.size else (0.0, 0.0)
    out = {"median_mm": med, "max_mm": top}
    j = effect.joint
    what = _WHAT.get(effect.family, effect.family).format(j=j, h=effect.harmonic, c=effect.coupled)
    factor = follower_factor(robot, j, effect.coupled) if effect.family == "joint_coupling" else None
    if factor is not None:
        what = (
            f"joint {j} follows joint {effect.coupled} by a ratio other than the joint map's factor "
            f"({factor:g} in size): the coupling's mechanism"
        )
    where = ""
    if j is not None and 1 <= j <= robot.n_joints:
        links = child_links(robot) if links is None else links
        out["joint_name"], out["link"] = robot.joint_names[j - 1], links[j - 1]
        where = f" (joint {j} is '{out['joint_name']}', moving link '{out['link']}')"
    text = f"{what}{where}; at the reflector {med:.3g} mm median, {top:.3g} mm at most over the {size.size} "
    text += "points"
    if effect.family in (gb.FAMILY, lb.FAMILY):
        text += ". " + _BASIS.format(n=effect.n_params)
    return out | {"text": text}


def describe_causes(causes: Sequence[Cause], robot: Robot, prob: FitProblem, fit: Fit) -> tuple:
    """``causes`` (:class:`~kpioed_drake.diagnosis.records.Cause`, the effects of ``fit`` in order)
    with their ``description``: each one's contribution at ``fit`` on every row of ``prob``."""
    _, _, E = prob.response(fit.model, fit.effects, np.arange(prob.data.n))
    links, out, c = child_links(robot), [], 0
    for cause, e in zip(causes, fit.effects, strict=True):
        signal = E[:, :, c : c + e.n_params] @ e.value_array()
        c += e.n_params
        out.append(dataclasses.replace(cause, description=describe(cause.effect, robot, signal, links=links)))
    return tuple(out)
