"""The calibration report: goodness of fit, parameters, tracker, KPI, in JSON and as text.

:class:`CalibrationReport` holds the outcome of :func:`kpioed_drake.calibration.calibrate` in
internal units (mm, rad); :meth:`CalibrationReport.to_dict` is the JSON report of
``kpioed calibrate --json`` (mm, deg) and :meth:`CalibrationReport.summary` the text summary.
Row numbers follow :data:`kpioed_drake.tracker.data.ROW_CONVENTION`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.math import RollPitchYaw, RotationMatrix
from scipy.stats import chi2 as chi2_dist

from kpioed_drake.calibration.robust import orientation_scale_line, removed_text
from kpioed_drake.estimation.accuracy import Figures, OrientationFigures, accuracy, orientation_accuracy
from kpioed_drake.estimation.estimator import EstimationResult
from kpioed_drake.files.tables import ROW_CONVENTION
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Robot
from kpioed_drake.robot.parameters import parameter_joint, parameter_layout
from kpioed_drake.tracker.data import Measurements, counted, n_poses
from kpioed_drake.tracker.measurement import TrackerModel

N_CORRELATIONS = 10
"""Correlations listed in the report (the strongest)."""


@dataclasses.dataclass
class CalibrationReport:
    """Outcome of :func:`~kpioed_drake.calibration.calibrate` (internal units) plus :meth:`to_dict`
    in file units.

    Attributes:
        robot: the nominal robot.
        nominal: the nominal model.
        result: the final estimation.
        data: the measurements.
        q_work: (6,) working pose of the KPI [rad].
        outliers: indices (0-based into the data) of the removed poses, in removal order.
        normalized: (n,) studentised residual statistics of the final fit (chi^2(3) under H0).
        normalized_rot: (n,) their orientation part with a 6-DoF probe's orientations, else None.
        outlier_threshold: the chi^2(3) threshold of the last test (or None if not tested).
        outlier_alpha: family-wise level of the outlier test (None: no test).
        kpi: (3,) TCP at q_work in W [mm].
        kpi_cov: (3, 3) its covariance [mm^2].
        kpi_nominal: (3,) TCP of the nominal model [mm].
        warnings: human-readable remarks (non-convergence, poor fit, outlier cap, parameters held).
        robust: the outlier screening against the residuals' robust scale
            (:meth:`kpioed_drake.calibration.robust.Screening.to_dict`; empty if not run).
        identifiability: ``at_nominal`` / ``at_solution``: the parameters held because the poses do
            not determine them, found on the registered nominal model and at the estimate.
    """

    robot: Robot
    nominal: TrackerModel
    result: EstimationResult
    data: Measurements
    q_work: np.ndarray
    outliers: list[int]
    normalized: np.ndarray
    outlier_threshold: float | None
    outlier_alpha: float | None
    kpi: np.ndarray
    kpi_cov: np.ndarray
    kpi_nominal: np.ndarray
    warnings: list[str]
    robust: dict = dataclasses.field(default_factory=dict)
    identifiability: dict = dataclasses.field(default_factory=dict)
    normalized_rot: np.ndarray | None = None

    # --- derived numbers ---------------------------------------------------------------------
    @property
    def model(self) -> TrackerModel:
        return self.result.model

    @property
    def held_at_nominal(self) -> list[str]:
        """Parameters the robot's layout estimates but this fit held at nominal (the poses do not
        determine them: :func:`kpioed_drake.estimation.identifiability.undetermined_parameters`); a
        tracker-pose coordinate held at the solution keeps its estimate and is in :attr:`held_at_estimate`."""
        return [n for n in self._held() if n not in self.model.layout.tracker_names]

    @property
    def held_at_estimate(self) -> list[str]:
        """Tracker-pose coordinates the solution does not determine, held at their first fit's value."""
        return [n for n in self._held() if n in self.model.layout.tracker_names]

    def _held(self) -> list[str]:
        estimated = set(self.model.layout.free_names)
        probe = self.model.layout.probe
        return [n for n in parameter_layout(self.robot, probe=probe).free_names if n not in estimated]

    @property
    def used(self) -> np.ndarray:
        return self.result.mask

    @property
    def rms_residual_mm(self) -> float:
        r = self.result.residuals[self.used]
        return float(np.sqrt(np.mean(r**2)))

    @property
    def max_residual_mm(self) -> float:
        return float(np.max(np.linalg.norm(self.result.residuals[self.used], axis=1)))

    def figures(self) -> Figures:
        """The accuracy figures of the fit (:func:`kpioed_drake.estimation.accuracy.accuracy`): the
        used rows' residuals in W, the tracker frame estimated in the fit."""
        used = self.used
        target = None if self.data.target is None else self.data.target[used]
        r_W = self.result.residuals[used] @ self.model.R_WT.T
        return accuracy(r_W, self.data.q[used], kind="fit", tracker="fitted", target=target)

    def orientation_figures(self) -> OrientationFigures | None:
        """The orientation figures of the fit (a 6-DoF probe's data; None without orientations):
        the used rows' rotation errors in W, the tracker frame estimated in the fit."""
        e = self.result.rot_residuals
        if e is None:
            return None
        return orientation_accuracy(e[self.used] @ self.model.R_WT.T, kind="fit", tracker="fitted")

    def probe(self) -> dict | None:
        """The JSON's ``probe`` block: the estimated orientation of the probe frame P on the flange
        (deg) and its small rotations' standard deviations; None without orientations."""
        R, sigma_rot = self.model.R_FP, self.result.sigma_rot
        if not self.model.layout.probe or R is None or sigma_rot is None:
            return None
        lay = self.model.layout
        return {
            "R_FP": R.tolist(),
            "rpy_deg": np.rad2deg(RollPitchYaw(RotationMatrix(R)).vector()).tolist(),
            "rotation_std_deg": np.rad2deg(self.result.std[lay.free_probe_rotation]).tolist(),
            "sigma_rot_deg_median": float(np.rad2deg(np.median(sigma_rot))),
            "note": "orientation of the 6-DoF probe's frame P on the flange (its origin: the reflector "
            "offset); rotation_std_deg: small rotations about the flange axes; sigma_rot_deg_median: the "
            "orientation noise the fit weighted with (the rows' own, else sigma_deg)",
        }

    @property
    def chi2(self) -> float:
        return self.result.cost

    @property
    def dof(self) -> int:
        return self.result.dof

    @property
    def chi2_per_dof(self) -> float | None:
        return self.result.cost / self.dof if self.dof > 0 else None

    @property
    def p_value(self) -> float | None:
        """P(chi^2_dof >= observed): small means the residuals are larger than the noise explains."""
        return float(chi2_dist.sf(self.result.cost, self.dof)) if self.dof > 0 else None

    @property
    def outlier_rows(self) -> list[int]:
        rows = np.asarray(self.data.rows)
        return [int(rows[i]) for i in sorted(self.outliers)]

    @property
    def aposteriori_factor(self) -> float | None:
        """sqrt(chi2/dof): a-posteriori standard deviations are the a-priori ones times this."""
        return None if self.chi2_per_dof is None else float(np.sqrt(self.chi2_per_dof))

    @property
    def rejects(self) -> bool:
        """The goodness-of-fit test rejects the model at the 0.1 % level (residuals too large)."""
        return self.p_value is not None and self.p_value < 1e-3

    def parameter_table(self) -> list[dict]:
        """All parameters (33 for six joints): name, value, nominal, std (mm/deg), unit, estimated."""
        lay = self.model.layout
        rotation = set(range(lay.size)[lay.tracker_rotation]) | set(range(lay.size)[lay.probe_rotation])
        free = list(lay.free)
        std = self.result.std
        std_post = np.sqrt(np.diag(self.result.Cp_scaled))  # NaN without degrees of freedom
        out = []
        for i, name in enumerate(lay.names):
            ang = bool(lay.is_angle[i])
            conv = np.rad2deg if ang else (lambda x: x)
            est = i in free
            value = float(conv(self.model.p[i]))
            nominal: float | None = float(conv(self.nominal.p[i]))
            if i in rotation:  # small rotations about the estimated tracker (probe) axes: zero after rebasing
                nominal = None
            row = {
                "name": name,
                "value": value,
                "nominal": nominal,
                "deviation": None if nominal is None else value - nominal,
                "std": float(conv(std[free.index(i)])) if est else 0.0,
                "std_aposteriori": (float(conv(std_post[free.index(i)])) if est and self.dof > 0 else None),
                "unit": "deg" if ang else "mm",
                "estimated": est,
                "joint_name": _joint_name(self.robot, name),
            }
            out.append(row)
        return out

    def correlations(self, k: int = N_CORRELATIONS) -> list[dict]:
        """The ``k`` strongest correlations between estimated parameters."""
        Cp = self.result.Cp
        s = np.sqrt(np.diag(Cp))
        R = Cp / np.outer(s, s)
        names = self.result.free_names + [n for e in self.result.effects for n in e.param_names]
        iu = np.triu_indices_from(R, 1)
        order = np.argsort(-np.abs(R[iu]))[:k]
        return [{"a": names[iu[0][j]], "b": names[iu[1][j]], "correlation": float(R[iu][j])} for j in order]

    @property
    def effects(self) -> tuple:
        """The estimated non-geometric effects with their values (empty: the geometric model)."""
        return tuple(self.result.effects)

    def effect_std(self) -> tuple[np.ndarray, np.ndarray]:
        """(k,) a-priori and a-posteriori standard deviations of the effects' values (internal
        units, in their order; the a-posteriori ones NaN without degrees of freedom)."""
        n = self.model.layout.n_free
        post = np.sqrt(np.diag(self.result.Cp_scaled))[n:] if self.dof > 0 else np.full(self.result.k, np.nan)
        return self.result.std[n:], post

    def effect_table(self) -> list[dict]:
        """The estimated effects: name, values, std (a priori and a posteriori), unit (display units)."""
        std, post = self.effect_std()
        out, c = [], 0
        for e in self.effects:
            sl = slice(c, c + e.n_params)
            c += e.n_params
            row = e.to_dict()
            row.update(
                joint_name=_joint_name(self.robot, f"theta{e.joint}") if e.joint else None,
                name=e.name,
                values=e.display_values(),
                std=e.display_values(std[sl]),
                std_aposteriori=e.display_values(post[sl]) if self.dof > 0 else None,
            )
            out.append(row)
        return out

    def kpi_reference(self) -> dict:
        """What the KPI shift is measured against: the model the user gave (``--robot``), with
        its reflector offset (the robot file's when it has one, else the cell file's)."""
        return {
            "model": self.robot.source or self.robot.name,
            "reflector_mm": self.nominal.p_FQ.tolist(),
            "reflector_from": "robot file" if self.robot.p_FQ is not None else "cell file",
            "note": "kpi_nominal_mm is the TCP at q_work of this model before calibration; the KPI "
            "shift is kpi_mm - kpi_nominal_mm",
        }

    def tracker(self) -> dict:
        """The estimated tracker pose and its standard deviations (JSON units)."""
        R = self.model.R_WT
        rpy = RollPitchYaw(RotationMatrix(R)).vector()
        std = self.result.std
        lay = self.model.layout
        return {
            "R_WT": R.tolist(),
            "rpy_deg": np.rad2deg(rpy).tolist(),
            "p_WT_mm": self.model.p_WT.tolist(),
            "p_WT_std_mm": std[lay.free_tracker_position].tolist(),
            "rotation_std_deg": np.rad2deg(std[lay.free_tracker_rotation]).tolist(),
            "note": "tracker frame T in W as estimated (p_W = R_WT p_T + p_WT); rotation_std_deg: small "
            "rotations about the tracker axes",
        }

    def to_dict(self) -> dict:
        """The JSON report (millimetres and degrees)."""
        return {
            **self._fit_dict(),
            **self._kpi_dict(),
            "parameters": self.parameter_table(),
            "parameter_std_note": "a-priori standard deviations from the given sigma",
            "correlations": self.correlations(),
            "tracker": self.tracker(),
            **({"probe": self.probe()} if self.model.layout.probe else {}),
            **self._targets_dict(),
            "poses": self._poses_list(),
            "held_at_nominal": list(self.held_at_nominal),
            "held_at_estimate": list(self.held_at_estimate),
            "identifiability": self._identifiability_dict(),
            "robust": dict(self.robust),
            "effects": self.effect_table(),
            "effects_note": "non-geometric effects estimated with the geometry (an extended model; empty: "
            "the geometric model), display units as in the effect text syntax; the KPI is at no payload "
            "and the reference temperature",
            "warnings": list(self.warnings),
        }

    def _poses_list(self) -> list[dict]:
        """The JSON report's ``poses``: per row its residual and outlier statistic."""
        res = self.result
        poses = []
        for i in range(self.data.n):
            r = res.residuals[i]
            poses.append(
                {
                    "row": int(np.asarray(self.data.rows)[i]),
                    "used": bool(res.mask[i]),
                    "residual_mm": r.tolist(),
                    "residual_norm_mm": float(np.linalg.norm(r)),
                    "normalized_chi2": float(self.normalized[i]),
                    "p_value": float(chi2_dist.sf(self.normalized[i], 3)),
                    **self._orientation_statistic(i),
                }
            )
        return poses

    def _orientation_statistic(self, i: int) -> dict:
        """Row ``i``'s orientation statistic (``normalized_chi2_orientation``) of a pose fit, else nothing."""
        t = self.normalized_rot
        return {} if t is None else {"normalized_chi2_orientation": float(t[i])}

    def _fit_dict(self) -> dict:
        """The JSON report's head: the data, the iteration, the goodness of fit and the outlier test."""
        res = self.result
        return {
            "robot": self.robot.name,
            "data": self.data.path,
            "n_poses": n_poses(self.data),
            "n_rows": self.data.n,
            "n_used": int(np.count_nonzero(self.used)),
            "counts_note": "n_poses: distinct poses (joint values); n_rows: rows, one per pose and target; "
            "n_used: rows used in the fit; n_outliers and outlier_rows: rows",
            "sigma_mm": res.sigma,
            "q_work_deg": q_to_file(self.robot, self.q_work).tolist(),
            "converged": bool(res.converged),
            "iterations": int(res.iterations),
            "stop_reason": res.message,
            "rms_residual_mm": self.rms_residual_mm,
            "rms_residual_note": "root mean square over the coordinates of the used poses",
            "max_residual_mm": self.max_residual_mm,
            "figures": {"fit": self.figures().to_dict(), **self._orientation_dict()},
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_per_dof": self.chi2_per_dof,
            "p_value": self.p_value,
            "n_outliers": len(self.outliers),
            "outlier_rows": self.outlier_rows,
            "row_convention": ROW_CONVENTION,
            "outlier_test": {
                "statistic": "studentised residual r^T (sigma^2 (I - H_ii))^-1 r ~ chi2(3) (with "
                "orientations also their own, normalized_chi2_orientation; robust.orientation)",
                "alpha_familywise": self.outlier_alpha,
                "threshold": self.outlier_threshold,
            },
        }

    def _sigma_rot_text(self) -> str:
        """``, orientations sigma 0.01 deg`` (the median over rows and axes) of a pose fit, else ""."""
        s = self.result.sigma_rot
        return "" if s is None else f", orientations sigma {np.rad2deg(np.median(s)):.3g} deg (median)"

    def _orientation_dict(self) -> dict:
        """``orientation_fit`` (the figures' orientation block) with a probe's orientations, else nothing."""
        fig = self.orientation_figures()
        return {} if fig is None else {"orientation_fit": fig.to_dict()}

    def _kpi_dict(self) -> dict:
        """The JSON report's KPI entries: the TCP at q_work and its covariance."""
        return {
            "kpi_mm": self.kpi.tolist(),
            "kpi_cov_mm2": self.kpi_cov.tolist(),
            "kpi_std_mm": np.sqrt(np.diag(self.kpi_cov)).tolist(),
            "kpi_avg_var_mm2": float(np.trace(self.kpi_cov) / 3.0),
            "kpi_cov_mm2_aposteriori": (self.kpi_cov * self.chi2_per_dof).tolist()
            if self.chi2_per_dof is not None
            else None,
            "kpi_nominal_mm": self.kpi_nominal.tolist(),
            "kpi_reference": self.kpi_reference(),
            "kpi_note": "TCP (reflector point) at q_work in W; covariance Js Cp Js^T with Cp = (F1^T F1)^-1 "
            "from the given sigma; the a-posteriori version is scaled by chi2/dof",
        }

    def _targets_dict(self) -> dict:
        """The JSON report's ``reflector`` and ``targets``: the estimated offsets in the flange frame."""
        std, lay = self.result.std, self.model.layout
        return {
            "reflector": {
                "p_FQ_mm": self.model.p_FQ.tolist(),
                "std_mm": std[lay.free_target(0)].tolist(),
                "note": "estimated reflector offset in the flange frame; the cell file is not changed",
            },
            "targets": [
                {
                    "target": t + 1,
                    "p_FQ_mm": self.model.target_offsets[t].tolist(),
                    "std_mm": std[lay.free_target(t)].tolist(),
                }
                for t in range(lay.n_targets)
            ],
        }

    def _identifiability_dict(self) -> dict:
        """The JSON report's ``identifiability``: what was held or dropped and where it was found."""
        return {
            "at_nominal": list(self.identifiability.get("at_nominal", [])),
            "at_solution": list(self.identifiability.get("at_solution", [])),
            "effects_dropped": list(self.identifiability.get("effects_dropped", [])),
            "note": "parameters held at nominal because these poses do not determine them: found on "
            "the registered nominal model before the fit, and on the Jacobian at the estimate; "
            "effects_dropped: effects of an extended fit these poses cannot tell from the geometry "
            "or the effects before them (not estimated; the warnings say what each trades against)",
        }

    def summary(self) -> str:
        """A human-readable summary."""
        d = self
        n_used = int(np.count_nonzero(d.used))
        used = f"{n_used} used" if d.data.n == n_poses(d.data) else f"{n_used} rows used"
        model = f" + {', '.join(e.name for e in self.effects)}" if self.effects else ""
        lines = [
            f"{d.robot.name}{model}: calibrated from {d.data.path}: {counted(d.data)}, "
            f"{used}, {d.result.n_params} parameters, sigma {d.result.sigma:g} mm{self._sigma_rot_text()}",
            f"  converged: {d.result.converged} ({d.result.iterations} iterations; {d.result.message})",
            *self.figures().lines(),
            *(f.lines() if (f := self.orientation_figures()) is not None else []),
        ]
        if d.dof > 0:
            lines.append(f"  chi2/dof = {d.chi2_per_dof:.3f} (dof {d.dof}), p-value {d.p_value:.3g}")
        if d.outliers:
            lines.append(
                f"  outliers removed: {len(d.outliers)} ({removed_text(self.robust, d.outlier_rows)})"
            )
        else:
            lines.append("  outliers removed: none")
        if self.robust.get("scale_mm") is not None:
            rb = self.robust
            lines.append(
                f"  robust scale of the residuals {rb['scale_mm']:.4g} mm per coordinate "
                f"(sigma {rb['sigma_mm']:g} mm): "
                + (
                    f"gross errors tested at {rb['sigma_effective_mm']:.4g} mm; {rb['n_removed']} rows "
                    f"removed, {rb['n_downweighted']} down-weighted"
                    if self.outlier_alpha is not None
                    else "no outlier test"
                )
            )
        if (line := orientation_scale_line(self.robust, self.outlier_alpha is not None)) is not None:
            lines.append(line)
        sd = np.sqrt(np.diag(d.kpi_cov))
        lines.append(
            "  KPI (TCP at q_work in W): "
            + ", ".join(f"{v:.4f} +- {s:.4f}" for v, s in zip(d.kpi, sd, strict=True))
            + f" mm; tr(Cs)/3 = {np.trace(d.kpi_cov) / 3:.3e} mm^2"
        )
        dev = d.kpi - d.kpi_nominal
        lines.append(
            f"  KPI shift from the given model ({d.kpi_reference()['model']}): {np.linalg.norm(dev):.4f} mm"
        )
        table = [p for p in d.parameter_table() if p["estimated"] and p["deviation"] is not None]
        table = [p for p in table if not p["name"].startswith("tracker")]
        table.sort(key=lambda p: -abs(p["deviation"]) / max(p["std"], 1e-300))
        post = d.rejects and d.aposteriori_factor is not None
        lines.append(
            "  largest deviations from nominal (in standard deviations)"
            + (
                f"; a-posteriori std = a-priori x {d.aposteriori_factor:.3g} (the fit rejects):"
                if post
                else ":"
            )
        )
        for p in table[:6]:
            extra = f" (a-posteriori {p['std_aposteriori']:.5f})" if post else ""
            at = f" ({p['joint_name']})" if p["joint_name"] else ""
            lines.append(
                f"    {p['name'] + at:<18} {p['deviation']:+.5f} +- {p['std']:.5f}{extra} {p['unit']}"
            )
        if self.effects:
            lines.append("  effects (estimated with the geometry):")
        for row in self.effect_table():
            vals = ", ".join(f"{v:.4g} +- {s:.2g}" for v, s in zip(row["values"], row["std"], strict=True))
            at = f" [{row['joint_name']}]" if row["joint_name"] else ""
            lines.append(f"    {row['name'] + at:<24} {vals} {row['unit']}")
        for w in d.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def _joint_name(robot, name: str) -> str | None:
    """The robot's name of a joint parameter's joint (``theta2`` of kr16: ``A2``), else None."""
    j = parameter_joint(name)
    return robot.joint_names[j - 1] if j is not None and j <= len(robot.joint_names) else None
