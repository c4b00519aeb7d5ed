"""The diagnosis report: JSON contract, text summary and the numbers that fill them.

- :class:`DiagnosisReport`: what :func:`kpioed_drake.diagnosis.diagnose` returns;
- :func:`fit_summary`: rms, chi^2/dof, p-value and held-out rms of a fit;
- :func:`kpi_summary`: the KPI (TCP at ``q_work``, paper eq. 24e) of the geometric and the
  extended model, its shift and its variance tr(Cs)/3;
- :func:`causes`: the named effects with values, standard deviations and evidence.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.calibration import kpi_and_covariance
from kpioed_drake.designio import jsonable, q_to_file
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.selection import Selection
from kpioed_drake.estimation import rms


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

    @property
    def cause_keys(self) -> set:
        """{(family, joint, harmonic)} of the named causes."""
        return {(c["effect"], c.get("joint"), c.get("harmonic")) for c in self.causes}

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
            where = "".join(f":{c[k]}" for k in ("joint", "harmonic") if k in c)
            ev = c["evidence"]
            lines.append(
                f"  cause {c['effect']}{where}: {vs} {c['unit']} (LR {ev['lr_stat']:.1f}, "
                f"p_corrected {ev['p_value_corrected']:.2g}, "
                f"up to {ev['tool_max_mm']:.3f} mm at the reflector)"
            )
        if not self.causes:
            lines.append("  no candidate effect is significant")
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


def causes(prob: FitProblem, sel: Selection) -> list[dict]:
    """The effects of the extended model: values and standard deviations (display units) and the
    evidence (the step's statistics, the final LR given all other effects, the size at the tool)."""
    ext = sel.fit
    std = np.sqrt(np.clip(np.diag(ext.Cp), 0, None))
    out, c = [], ext.layout.effects.start
    for i, e in enumerate(ext.effects):
        d = e.to_dict()
        dv = e.display_values(std[c : c + e.n_params])
        c += e.n_params
        d["std"] = dv[0] if len(dv) == 1 else dv
        d.pop("tool_mm", None)
        sig = prob.effect_signal(ext, i)
        ev = dict(sel.evidence.get(e.key, {}))
        # the final LR of this effect given all others (re-fitted without it)
        f0 = prob.fit([x for x in ext.effects if x.key != e.key], start=ext)
        ev["lr_stat_final"] = max(f0.cost - ext.cost, 0.0)
        ev["tool_max_mm"] = float(np.max(np.linalg.norm(sig, axis=1)))
        ev["tool_rms_mm"] = float(np.sqrt(np.mean(np.sum(sig**2, axis=1))))
        d["evidence"] = ev
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
