"""The diagnosis report: the JSON contract and text summary, built from the diagnosis's records, and
the numbers that fill them.

- :class:`DiagnosisReport`: what :func:`kpioed_drake.diagnosis.diagnose` returns; its causes and
  steps as records (:mod:`.records`) and as the JSON's dicts (:func:`cause_dict`, :func:`step_dict`);
- :func:`fit_summary`: rms, chi^2/dof, p-value and held-out rms of a fit;
- :func:`kpi_summary`: the KPI (TCP at ``q_work``, paper eq. 24e) of the geometric and the
  extended model, its shift and its variance tr(Cs)/3;
- :func:`unexplained_rest`: what the extended model's residuals still follow when they exceed the
  noise.

The unexplained rest: when the goodness-of-fit test of the extended model rejects (``chi2 ~
chi2(dof)`` against the known sigma, p < alpha), the residuals hold an error outside the candidate
library. Its structure: the residuals in W (n, 3) are regressed, coordinate by coordinate, on each
variable of the data:

- smooth variables (a constant, v and v^2, v standardised): the joint angles ``q_1..q_6``, the gravity
  torques ``tau_2..tau_6``, ``temperature_C``, ``time_s``, ``payload_kg`` (when they vary), the
  reflector's ``reach`` (horizontal distance from the base axis) and ``height`` (z in W);
- pose regions (one mean per tercile): ``reach tercile``, ``height tercile``.

``strength`` is the fraction of the residual sum of squares (about the per-coordinate mean) the
variable explains (R^2, 0..1); ``p_value`` is the F test of that regression against none
(``3 (p - 1)`` and ``3 (n - p)`` degrees of freedom). ``follows`` lists the variables with
p < alpha, strongest first. ``excess_rms_mm`` = ``sigma sqrt(chi2/dof - 1)``: the size of the rest
per coordinate.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.calibration import kpi_and_covariance
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.records import Alternative, CandidateTest, Cause, PairTest, SelectionStep
from kpioed_drake.estimation.accuracy import Figures, accuracy
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.outputs import jsonable
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Robot
from kpioed_drake.tracker.measurement import reflector_world

MAX_FOLLOWS = 6
"""Most variables listed in the unexplained rest's ``follows``."""


@dataclasses.dataclass
class DiagnosisReport:
    """Result of :func:`~kpioed_drake.diagnosis.diagnose`; :meth:`to_json` gives the documented
    JSON contract (docs/diagnosis.md).

    Attributes:
        robot: robot name.
        n_poses: poses in the data (distinct joint values).
        n_rows: measured points (several per pose with several targets).
        sigma_mm: the noise per coordinate every test rests on [mm].
        discrepancy: the geometric model does not explain the data, or a cause was named.
        test: the goodness-of-fit test of the geometric model (chi2, dof, p_value, alpha, rejects).
        cause_records: the named effects with values, standard deviations, evidence and alternatives
            (:attr:`causes`: as the JSON's dicts, display units).
        baseline: fit summary of the geometric model (rms, chi2, held-out rms, ...).
        extended: fit summary of the extended model.
        gain: ratios extended / baseline and the KPI's change.
        kpi: TCP at q_work of both models and their variances (empty without q_work).
        residual_structure: score statistics of the candidates against the baseline residuals.
        step_records: the selection steps (:attr:`steps`: as the JSON's dicts).
        notes: remarks (candidates left out, poor fit).
        details: the fits and the problem, for plots (not part of the JSON).
        unexplained: None when the extended model fits to the noise level, else the rest's size and
            the variables it follows (:func:`unexplained_rest`).
        joint_names: the robot's joint names (reports name a cause's joint by them, index second).
        selection_stop: why the selection of effects stopped, ``{"reason", "text"}``
            (:data:`~kpioed_drake.diagnosis.fit.STOPS`).
        noise: which sigma and where it comes from (:class:`~kpioed_drake.estimation.noise.Noise`).
    """

    robot: str
    n_poses: int
    n_rows: int
    sigma_mm: float
    discrepancy: bool
    test: dict
    cause_records: tuple[Cause, ...]
    baseline: dict
    extended: dict
    gain: dict
    kpi: dict
    residual_structure: list
    step_records: tuple[SelectionStep, ...]
    notes: list
    details: dict = dataclasses.field(default_factory=dict, repr=False)
    unexplained: dict | None = None
    joint_names: tuple[str, ...] = ()
    selection_stop: dict | None = None
    noise: dict | None = None

    @functools.cached_property
    def causes(self) -> list[dict]:
        """The named causes as in the JSON (:func:`cause_dict`)."""
        out = [cause_dict(c) for c in self.cause_records]
        for c in out:
            j = c.get("joint")
            if j is not None and j <= len(self.joint_names):
                c["joint_name"] = self.joint_names[j - 1]
        return out

    @functools.cached_property
    def steps(self) -> list[dict]:
        """The selection steps as in the JSON (:func:`step_dict`)."""
        return [step_dict(s) for s in self.step_records]

    @property
    def cause_names(self) -> set[str]:
        """Names of the named causes (e.g. ``gear_cyclic:4:2``)."""
        return {c.effect.name for c in self.cause_records}

    @property
    def explanation_names(self) -> list[set[str]]:
        """Per named cause, the names of the cause and of its alternatives (what the data cannot tell
        apart)."""
        return [{c.effect.name} | {a.effect.name for a in c.alternatives} for c in self.cause_records]

    def to_json(self) -> dict:
        return jsonable(
            {
                "robot": self.robot,
                "n_poses": self.n_poses,
                "n_rows": self.n_rows,
                "sigma_mm": self.sigma_mm,
                "noise": self.noise,
                "discrepancy": self.discrepancy,
                "test": self.test,
                "causes": self.causes,
                "baseline": self.baseline,
                "extended": self.extended,
                "gain": self.gain,
                "kpi": self.kpi,
                "residual_structure": self.residual_structure,
                "steps": self.steps,
                "selection_stop": self.selection_stop,
                "notes": self.notes,
                "unexplained": self.unexplained,
            }
        )

    def summary(self) -> str:
        """A few lines for people."""
        t = self.test
        lines = [
            f"{self.robot}: {self.n_poses} poses"
            + (f" ({self.n_rows} rows)" if self.n_rows != self.n_poses else "")
            + f", sigma {self.sigma_mm:.3g} mm"
            + (f" ({self.noise['source']})" if self.noise else ""),
            f"geometric model: chi2/dof {t['chi2_per_dof']:.3f} (dof {t['dof']}, p = {t['p_value']:.3g})"
            f" -> {'DISCREPANCY' if self.discrepancy else 'explains the data to the noise level'}",
        ]
        if self.noise and self.noise["source"] == "residuals":
            lines.append(f"  noise: {self.noise['text']}")
        for c in self.causes:
            v, s = c["value"], c["std"]
            if isinstance(v, list):
                vs = ", ".join(f"{a:.4g} +- {b:.2g}" for a, b in zip(v, s, strict=True))
            else:
                vs = f"{v:.4g} +- {s:.2g}"
            where = "".join(f":{c[k]}" for k in ("joint", "harmonic", "coupled_joint") if k in c)
            if "joint_name" in c:
                where += f" [{c['joint_name']}, joint {c['joint']}]"
            ev = c["evidence"]
            lines.append(
                f"  cause {c['effect']}{where}: {vs} {c['unit']} (LR {ev['lr_stat']:.1f}, "
                f"p_corrected {ev['p_value_corrected']:.2g}, "
                f"up to {ev['tool_max_mm']:.3f} mm at the reflector)"
            )
            if c.get("description"):
                lines.append(f"    {c['description']['text']}")
            lines += _alternative_lines(c)
            if not c.get("plausible", True):
                lines.append(f"    implausible: {c['plausible_reason']}")
        if not self.causes:
            lines.append(
                "  no cause named (no candidate effect is significant, or only as a stand-in: notes)"
            )
        if self.selection_stop:
            lines.append(f"  selection stopped: {self.selection_stop['text']}")
        if self.unexplained:
            u = self.unexplained
            top = ", ".join(f"{f['variable']} (R^2 {f['strength']:.2f})" for f in u["follows"][:3])
            lines.append(
                f"  unexplained rest: chi2/dof {u['chi2_per_dof']:.3f} (p = {u['p_value']:.2g}), about "
                f"{u['excess_rms_mm']:.4f} mm per coordinate beyond the noise; "
                + (f"it follows {top}" if top else "it follows none of the data's variables")
            )
            if u.get("advice"):
                lines.append(f"  {u['advice']}")
        b, e = self.baseline, self.extended
        lines.append(
            f"held-out RMS {b['holdout_rms_mm']:.4f} -> {e['holdout_rms_mm']:.4f} mm "
            f"(ratio {self.gain['holdout_rms_ratio']:.3f}); chi2/dof {b['chi2_per_dof']:.3f} -> "
            f"{e['chi2_per_dof']:.3f}"
        )
        models = (("geometric model", b), ("extended model", e)) if self.causes else (("geometric model", b),)
        for name, fits in models:
            for f in fits["figures"].values():
                lines += Figures.from_dict(f, model=name).lines(indent="")
        if self.kpi:
            lines.append(
                f"KPI (TCP at q_work): shift {self.kpi['tcp_shift_mm']:.4f} mm; tr(Cs)/3 "
                f"{self.kpi['kpi_avg_var_mm2_baseline']:.3g} -> "
                f"{self.kpi['kpi_avg_var_mm2_extended']:.3g} mm^2"
            )
        return "\n".join(lines)


def row_dict(t: CandidateTest | PairTest) -> dict:
    """A candidate's or a pair's test as a row of the JSON's steps."""
    if isinstance(t, PairTest):
        return {"pair": [e.name for e in t.effects], **t.statistics()}
    return {"candidate": t.effect.name, **t.statistics()}


def step_dict(s: SelectionStep) -> dict:
    """A selection step as in the JSON: its candidates' rows, the pairs', what it added and removed
    (a swap: what replaced what)."""
    if s.swap is not None:
        return {
            "step": s.step,
            "added": s.added[0],
            "removed": list(s.removed),
            "swapped": dataclasses.asdict(s.swap),
            "candidates": [],
        }
    out: dict[str, Any] = {
        "step": s.step,
        "holdout_rms_mm_before": s.holdout_rms_mm_before,
        "chi2_before": s.chi2_before,
        "candidates": [row_dict(t) for t in s.candidates],
    }
    if s.pairs:
        out["pairs"] = [row_dict(t) for t in s.pairs]
    out["added"] = " + ".join(s.added) if s.added else None
    if len(s.added) == 2:
        out["pair"] = list(s.added)
    if s.removed:
        out["removed"] = list(s.removed)
    return out


def _effect_dict(e: fx.Effect) -> dict:
    """An effect as in the JSON (SPEC names, display units), with its name."""
    return {**{k: v for k, v in e.to_dict().items() if k != "tool_mm"}, "name": e.name}


def alternative_dict(a: Alternative) -> dict:
    """A competing explanation as in the JSON: the effect, its value and plausibility, the evidence;
    the gravity basis (no value of its own): the effect and the evidence."""
    if a.plausible is None:
        return {
            "effect": a.effect.family,
            "joint": a.effect.joint,
            "name": a.effect.name,
            "evidence": a.evidence,
        }
    return {
        **_effect_dict(a.effect),
        "evidence": a.evidence,
        "plausible": a.plausible,
        "plausible_reason": a.plausible_reason,
    }


def cause_dict(c: Cause) -> dict:
    """A named cause as in the JSON: the effect with its value and standard deviation (display
    units), evidence, plausibility and alternatives."""
    return {
        **_effect_dict(c.effect),
        "std": c.std[0] if len(c.std) == 1 else list(c.std),
        "evidence": c.evidence,
        "plausible": c.plausible,
        "plausible_reason": c.plausible_reason,
        "alternatives": [alternative_dict(a) for a in c.alternatives],
        "description": c.description,
    }


def _alternative_lines(c: dict) -> list[str]:
    """Summary lines of a cause's competing explanations."""
    alts = c.get("alternatives") or []
    if not alts:
        return []
    names = [c["name"]] + [a["name"] for a in alts]
    out = [
        f"    {' or '.join(names)}: the data cannot tell them apart; poses that can: a design with "
        f"discriminate '{names[0]}|{names[1]}'"
    ]
    for a in alts:
        ev = a["evidence"]
        if "lr_stat" not in ev:  # an alternative of another kind (e.g. the gravity-torque basis)
            out.append(f"    alternative {a['name']}: {ev.get('explains', 'explains the data as well')}")
            continue
        if ev.get("nested"):
            out.append(
                f"    alternative {a['name']}: significant alone (LR {ev['lr_stat']:.1f} vs "
                f"{ev['lr_stat_cause']:.1f}) and "
                f"{100 * (1 - ev['remaining_given_causes'] ** 2):.1f} % of its signature lies within "
                f"{c['name']}'s and the geometry's: the data cannot tell whether it is present as well"
            )
            continue
        out.append(
            f"    alternative {a['name']}: LR {ev['lr_stat']:.1f} vs {ev['lr_stat_cause']:.1f}, held-out RMS "
            f"{ev['holdout_rms_mm']:.4f} mm, canonical correlation {ev['canonical_correlation']:.3f}"
            + ("" if a.get("plausible", True) else "; implausible value")
        )
    return out


def fit_summary(fit: Fit, holdout: np.ndarray) -> dict:
    """rms [mm], chi2, dof, chi2/dof, p-value, held-out rms [mm] and parameter count of a fit, and
    the accuracy figures (:func:`kpioed_drake.estimation.accuracy.accuracy`) of its fit and of its
    held-out residuals (in W with the fit's tracker orientation)."""
    m, R = fit.mask, fit.model.R_WT
    t = None if fit.conditions.target is None else fit.conditions.target[m]
    figures = {
        kind.replace("-", "_"): accuracy(r[m] @ R.T, fit.q[m], kind=kind, tracker=how, target=t).to_dict()
        for kind, how, r in (("fit", "fitted", fit.residuals), ("held-out", "folds", holdout))
    }
    return {
        "figures": figures,
        "rms_mm": rms(fit.residuals),
        "chi2": fit.cost,
        "dof": fit.dof,
        "chi2_per_dof": fit.chi2_per_dof,
        "p_value": float(scipy.stats.chi2.sf(fit.cost, fit.dof)),
        "holdout_rms_mm": rms(holdout),
        "n_params": fit.n_params,
    }


def kpi_summary(prob: FitProblem, base: Fit, ext: Fit) -> dict:
    """TCP at the robot's q_work of both models, its shift and tr(Cs)/3 of each (empty without q_work)."""
    qw = prob.robot.q_work
    if qw is None:
        return {}
    s_b, Cb = kpi_and_covariance(base, qw)
    s_e, Ce = kpi_and_covariance(ext, qw)
    return {
        "q_work_deg": q_to_file(prob.robot, qw),
        "tcp_baseline_mm": s_b,
        "tcp_extended_mm": s_e,
        "tcp_shift_mm": float(np.linalg.norm(s_e - s_b)),
        "kpi_avg_var_mm2_baseline": float(np.trace(Cb) / 3.0),
        "kpi_avg_var_mm2_extended": float(np.trace(Ce) / 3.0),
        "conditions": f"no payload, temperature {fx.T_REF_C:g} C",
    }


def gain(prob: FitProblem, baseline: dict, extended: dict, kpi: dict) -> dict:
    """Ratios extended / baseline of the held-out rms, rms and chi2/dof, and the KPI's change."""
    out = {
        "holdout_rms_ratio": extended["holdout_rms_mm"] / baseline["holdout_rms_mm"],
        "rms_ratio": extended["rms_mm"] / baseline["rms_mm"],
        "chi2_per_dof_ratio": extended["chi2_per_dof"] / baseline["chi2_per_dof"],
        "holdout_rms_over_sigma": extended["holdout_rms_mm"] / prob.sigma,
    }
    if kpi:
        out["kpi_tcp_shift_mm"] = kpi["tcp_shift_mm"]
        out["kpi_avg_var_ratio"] = kpi["kpi_avg_var_mm2_extended"] / kpi["kpi_avg_var_mm2_baseline"]
    return out


def _variables(prob: FitProblem, fit: Fit) -> list[tuple[str, np.ndarray, str]]:
    """(name, values (n,), 'smooth' | 'terciles') of every variable that varies over the data."""
    d = prob.data
    p_W = reflector_world(fit.model, d.q, d.target)
    nj = d.q.shape[1]
    out = [(f"q_{j + 1}", d.q[:, j], "smooth") for j in range(nj)]
    out += [(f"tau_{j + 1} (gravity torque)", prob.tau[:, j], "smooth") for j in range(nj)]
    for name, v in (("temperature_C", d.temperature_C), ("time_s", d.time_s), ("payload_kg", d.payload_kg)):
        if v is not None:
            out.append((name, np.asarray(v, dtype=float), "smooth"))
    out += [(f"{UNUSED} {name}", np.asarray(v, dtype=float), "smooth") for name, v in d.extra]
    reach, height = np.hypot(p_W[:, 0], p_W[:, 1]), p_W[:, 2]
    out += [("reach", reach, "smooth"), ("height", height, "smooth")]
    out += [("reach tercile", reach, "terciles"), ("height tercile", height, "terciles")]
    return [x for x in out if np.ptp(x[1]) > 1e-9 * max(1.0, float(np.max(np.abs(x[1]))))]


def _design(v: np.ndarray, kind: str) -> np.ndarray:
    """(n, p) regressors of one variable, the constant included."""
    if kind == "terciles":
        edges = np.quantile(v, [1 / 3, 2 / 3])
        g = np.searchsorted(edges, v, side="right")
        X = np.stack([g == k for k in range(3)], axis=1).astype(float)
        return X[:, X.sum(axis=0) > 0]
    z = (v - v.mean()) / v.std()
    return np.stack([np.ones_like(z), z, z**2], axis=1)


def structure(prob: FitProblem, fit: Fit) -> list[dict]:
    """Every varying variable's ``{variable, strength, p_value}`` for ``fit``'s residuals, strongest first."""
    r = fit.residuals @ fit.model.R_WT.T  # (n, 3) in W
    n = r.shape[0]
    sst = float(np.sum((r - r.mean(axis=0)) ** 2))
    out = []
    for name, v, kind in _variables(prob, fit):
        X = _design(v, kind)
        beta, *_ = np.linalg.lstsq(X, r, rcond=None)
        sse = float(np.sum((r - X @ beta) ** 2))
        p = X.shape[1]
        df1, df2 = 3 * (p - 1), 3 * (n - p)
        strength = max(0.0, 1.0 - sse / sst) if sst > 0 else 0.0
        F = ((sst - sse) / df1) / (sse / df2) if sse > 0 and df1 > 0 and df2 > 0 else 0.0
        pv = float(scipy.stats.f.sf(F, df1, df2)) if df1 > 0 and df2 > 0 else 1.0
        out.append({"variable": name, "strength": strength, "p_value": pv})
    return sorted(out, key=lambda x: -x["strength"])


def unexplained_rest(prob: FitProblem, fit: Fit, *, alpha: float, robot: Robot | None = None) -> dict | None:
    """None when ``fit`` explains the data to the noise level, else the rest and what it follows.

    The data file's numeric columns that the model does not read (``Measurements.extra``) are among
    the variables; those the rest follows at the level ``alpha`` over all of them (Bonferroni) are
    listed in ``unused_columns`` with what to do (:func:`unused_advice`).

    Returns:
        ``{chi2_per_dof, p_value, alpha, excess_rms_mm, follows: [{variable, strength, p_value}],
        variables: [all of them], unused_columns: [{column, strength, p_value}], advice}`` or None.
    """
    p = float(scipy.stats.chi2.sf(fit.cost, fit.dof))
    if p >= alpha:
        return None
    allv = structure(prob, fit)
    extra = [x for x in allv if x["variable"].startswith(UNUSED + " ")]
    level = alpha / max(len(extra), 1)
    unused = [
        {"column": x["variable"][len(UNUSED) + 1 :], "strength": x["strength"], "p_value": x["p_value"]}
        for x in extra
        if x["p_value"] < level
    ]
    return {
        "chi2_per_dof": fit.chi2_per_dof,
        "p_value": p,
        "alpha": alpha,
        "excess_rms_mm": prob.sigma * float(np.sqrt(max(fit.chi2_per_dof - 1.0, 0.0))),
        "follows": [x for x in allv if x["p_value"] < alpha][:MAX_FOLLOWS],
        "variables": allv,
        "unused_columns": unused,
        "advice": unused_advice([u["column"] for u in unused], robot) if unused else None,
    }


UNUSED = "column"
"""Prefix of a data file's column the model does not read, among the rest's variables."""


def unused_advice(columns: list[str], robot: Robot | None = None) -> str:
    """What to do when the rest follows data columns the model does not use: joints of the robot's
    file off the measured chain (another branch's load acts on this one) -> describe the whole tree;
    joint-like columns of a table robot -> the same; other columns -> make them a variable."""
    off_chain = set()
    urdf = None if robot is None else robot.urdf
    if urdf is not None:
        names = {j.get("name") for j in ET.fromstring(urdf.text).findall("joint")}
        off_chain = names - set(urdf.joints)
    joints = [c for c in columns if c in off_chain or re.fullmatch(r"q\d+_(deg|mm)", c)]
    text = f"the rest follows column(s) {', '.join(columns)}, which the model does not use"
    if joints:
        return (
            text + f": {', '.join(joints)} look like joints of another branch, whose load acts on the "
            "measured one; describe the whole tree (the robot file with every branch and a target on "
            "each measured link, docs/data-formats.md) so that the model sees them"
        )
    return (
        text + ": make it a variable the model reads (a temperature as temperature_C, a time as "
        "time_s, a payload as payload_kg), or find what it measures"
    )
