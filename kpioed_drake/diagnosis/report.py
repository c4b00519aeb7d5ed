"""The diagnosis report: JSON contract, text summary and the numbers that fill them.

- :class:`DiagnosisReport`: what :func:`kpioed_drake.diagnosis.diagnose` returns;
- :func:`fit_summary`: rms, chi^2/dof, p-value and held-out rms of a fit;
- :func:`kpi_summary`: the KPI (TCP at ``q_work``, paper eq. 24e) of the geometric and the
  extended model, its shift and its variance tr(Cs)/3;
- :func:`causes`: the named effects with values, standard deviations and evidence, their competing
  explanations (:mod:`.alternatives`) and plausibility (:mod:`.physical`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.calibration import kpi_and_covariance
from kpioed_drake.diagnosis.alternatives import settle
from kpioed_drake.diagnosis.common import ALPHA, K_FOLDS
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.selection import Selection
from kpioed_drake.effects.physical import plausibility
from kpioed_drake.estimation.estimator import rms
from kpioed_drake.tracker.csvio import jsonable, q_to_file


@dataclasses.dataclass
class DiagnosisReport:
    """Result of :func:`~kpioed_drake.diagnosis.diagnose`; :meth:`to_json` gives the documented
    JSON contract (docs/diagnosis.md).

    Attributes:
        robot: robot name.
        n_poses: poses in the data.
        sigma_mm: the known noise per coordinate [mm].
        discrepancy: the geometric model does not explain the data, or a cause was named.
        test: the goodness-of-fit test of the geometric model (chi2, dof, p_value, alpha, rejects).
        causes: the named effects with values, standard deviations and evidence (display units).
        baseline: fit summary of the geometric model (rms, chi2, held-out rms, ...).
        extended: fit summary of the extended model.
        gain: ratios extended / baseline and the KPI's change.
        kpi: TCP at q_work of both models and their variances (empty without q_work).
        residual_structure: score statistics of the candidates against the baseline residuals.
        steps: the selection steps.
        notes: remarks (candidates left out, poor fit).
        details: the fits and the problem, for plots (not part of the JSON).
        unexplained: None when the extended model fits to the noise level, else the rest's size and
            the variables it follows (:func:`~kpioed_drake.diagnosis.rest.unexplained_rest`).
    """

    robot: str
    n_poses: int
    sigma_mm: float
    discrepancy: bool
    test: dict
    causes: list
    baseline: dict
    extended: dict
    gain: dict
    kpi: dict
    residual_structure: list
    steps: list
    notes: list
    details: dict = dataclasses.field(default_factory=dict, repr=False)
    unexplained: dict | None = None

    @property
    def cause_keys(self) -> set:
        """{(family, joint, harmonic)} of the named causes."""
        return {_key(c) for c in self.causes}

    @property
    def explanation_keys(self) -> list[set]:
        """Per named cause, the keys of the cause and of its alternatives (what the data cannot tell
        apart); keys as :attr:`cause_keys`, for a coupling (family, joint, coupled joint)."""
        return [{_key(c)} | {_key(a) for a in c.get("alternatives", [])} for c in self.causes]

    def to_json(self) -> dict:
        return jsonable(
            {
                "robot": self.robot,
                "n_poses": self.n_poses,
                "sigma_mm": self.sigma_mm,
                "discrepancy": self.discrepancy,
                "test": self.test,
                "causes": self.causes,
                "baseline": self.baseline,
                "extended": self.extended,
                "gain": self.gain,
                "kpi": self.kpi,
                "residual_structure": self.residual_structure,
                "steps": self.steps,
                "notes": self.notes,
                "unexplained": self.unexplained,
            }
        )

    def summary(self) -> str:
        """A few lines for people."""
        t = self.test
        lines = [
            f"{self.robot}: {self.n_poses} poses, sigma {self.sigma_mm:g} mm",
            f"geometric model: chi2/dof {t['chi2_per_dof']:.3f} (dof {t['dof']}, p = {t['p_value']:.3g})"
            f" -> {'DISCREPANCY' if self.discrepancy else 'explains the data to the noise level'}",
        ]
        for c in self.causes:
            v, s = c["value"], c["std"]
            if isinstance(v, list):
                vs = ", ".join(f"{a:.4g} +- {b:.2g}" for a, b in zip(v, s, strict=True))
            else:
                vs = f"{v:.4g} +- {s:.2g}"
            where = "".join(f":{c[k]}" for k in ("joint", "harmonic", "coupled_joint") if k in c)
            ev = c["evidence"]
            lines.append(
                f"  cause {c['effect']}{where}: {vs} {c['unit']} (LR {ev['lr_stat']:.1f}, "
                f"p_corrected {ev['p_value_corrected']:.2g}, "
                f"up to {ev['tool_max_mm']:.3f} mm at the reflector)"
            )
            lines += _alternative_lines(c)
            if not c.get("plausible", True):
                lines.append(f"    implausible: {c['plausible_reason']}")
        if not self.causes:
            lines.append(
                "  no cause named (no candidate effect is significant, or only as a stand-in: notes)"
            )
        if self.unexplained:
            u = self.unexplained
            top = ", ".join(f"{f['variable']} (R^2 {f['strength']:.2f})" for f in u["follows"][:3])
            lines.append(
                f"  unexplained rest: chi2/dof {u['chi2_per_dof']:.3f} (p = {u['p_value']:.2g}), about "
                f"{u['excess_rms_mm']:.4f} mm per coordinate beyond the noise; "
                + (f"it follows {top}" if top else "it follows none of the data's variables")
            )
        b, e = self.baseline, self.extended
        lines.append(
            f"held-out RMS {b['holdout_rms_mm']:.4f} -> {e['holdout_rms_mm']:.4f} mm "
            f"(ratio {self.gain['holdout_rms_ratio']:.3f}); chi2/dof {b['chi2_per_dof']:.3f} -> "
            f"{e['chi2_per_dof']:.3f}"
        )
        if self.kpi:
            lines.append(
                f"KPI (TCP at q_work): shift {self.kpi['tcp_shift_mm']:.4f} mm; tr(Cs)/3 "
                f"{self.kpi['kpi_avg_var_mm2_baseline']:.3g} -> "
                f"{self.kpi['kpi_avg_var_mm2_extended']:.3g} mm^2"
            )
        return "\n".join(lines)


def _key(c: dict) -> tuple:
    """(family, joint, harmonic or coupled joint) of a cause or alternative dict."""
    return (c["effect"], c.get("joint"), c.get("harmonic", c.get("coupled_joint")))


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
    """rms [mm], chi2, dof, chi2/dof, p-value, held-out rms [mm] and parameter count of a fit."""
    return {
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


def _plausible(prob: FitProblem, e, std) -> dict:
    ok, why = plausibility(e, std, tau=prob.tau, time_s=prob.data.time_s)
    return {"plausible": ok, "plausible_reason": why}


def causes(
    prob: FitProblem, sel: Selection, pool=(), *, alpha: float = ALPHA, k_folds: int = K_FOLDS
) -> list[dict]:
    """The effects of the extended model: values and standard deviations (display units), the
    evidence (the step's statistics, the final LR given all other effects, the size at the tool),
    ``plausible`` / ``plausible_reason`` (:mod:`.physical`) and ``alternatives``: the candidates of
    ``pool`` the data cannot tell apart from the cause (:mod:`.alternatives`; a cause that one of
    them beats is swapped first, in place on ``sel``)."""
    settled = settle(prob, sel, pool, alpha=alpha, k_folds=k_folds)
    ext = sel.fit
    std = np.sqrt(np.clip(np.diag(ext.Cp), 0, None))
    out, c = [], ext.layout.effects.start
    for i, e in enumerate(ext.effects):
        d = e.to_dict()
        d["name"] = e.name
        e_std = std[c : c + e.n_params]
        dv = e.display_values(e_std)
        c += e.n_params
        d["std"] = dv[0] if len(dv) == 1 else dv
        d.pop("tool_mm", None)
        sig = prob.effect_signal(ext, i)
        ev = dict(sel.evidence.get(e.key, {}))
        # the final LR of this effect given all others (re-fitted without it)
        f0, found = settled[e.key]
        ev["lr_stat_final"] = max(f0.cost - ext.cost, 0.0)
        ev["tool_max_mm"] = float(np.max(np.linalg.norm(sig, axis=1)))
        ev["tool_rms_mm"] = float(np.sqrt(np.mean(np.sum(sig**2, axis=1))))
        d["evidence"] = ev
        d.update(_plausible(prob, e, e_std))
        d["alternatives"] = []
        for b, fb, ev_b in found:
            a = {k: v for k, v in b.to_dict().items() if k != "tool_mm"}
            a["name"] = b.name
            a["evidence"] = ev_b
            b_std = np.sqrt(np.clip(np.diag(fb.Cp), 0, None))[fb.layout.effects][-b.n_params :]
            a.update(_plausible(prob, b, b_std))
            d["alternatives"].append(a)
        out.append(d)
    return out


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
