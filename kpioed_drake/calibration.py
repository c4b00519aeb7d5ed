"""Calibration from measured laser-tracker data (SPEC "Measured data and model discrepancy").

- :func:`read_measurements`: read and validate a measurement CSV (``q1_deg`` ... ``q6_deg``,
  ``x_mm``, ``y_mm``, ``z_mm``; optional ``temperature_C``, ``time_s``, ``payload_kg``).
- :func:`calibrate`: rigid registration of the tracker, Levenberg-Marquardt on the 27 estimated
  parameters (:mod:`kpioed_drake.estimation`), robust outlier handling, goodness of fit and the KPI
  (TCP at ``q_work`` in W) with its covariance.
- :func:`calibrated_robot_yaml`: the calibrated robot as a model file (same schema as
  ``models/robots/*.yaml``) usable as ``--robot path.yaml``.
- :func:`calibrate_file`: the whole ``kpioed calibrate`` workflow; outputs are written only after
  everything succeeded, each atomically.

Outlier test (normalised residuals): for every used pose i the studentised statistic
``t_i = r_i^T (sigma^2 (I - H_ii))^-1 r_i`` (``H_ii`` the 3x3 block of the hat matrix) is chi^2(3)
distributed if the model is right. The largest ``t_i`` is compared with the chi^2(3) quantile at
level ``alpha / n`` (Bonferroni; ``alpha`` = family-wise false-alarm probability, default 0.01); if
it exceeds it, that pose is removed and the fit repeated, until no pose exceeds the threshold, at
most ``max_outlier_fraction`` of the poses are removed, or removing one more would leave fewer than
10 poses. Many "outliers" are a sign of model discrepancy rather than of bad points (see
``kpioed diagnose``); the report warns when the cap is reached.

Row numbers in reports are CSV record numbers, header = row 1, so the k-th data row is row k + 1
(blank lines are skipped and not counted).
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import chi2 as chi2_dist

from kpioed_drake import estimation
from kpioed_drake.designio import (
    Q_COLUMNS,
    atomic_write_json,
    atomic_write_text,
    check_joint_angles,
    parse_float_column,
    parse_q_work,
    read_csv_table,
    row_numbers,
)
from kpioed_drake.errors import InputError
from kpioed_drake.measurement import TrackerModel, kpi_jacobian, nominal_model
from kpioed_drake.models import (
    N_JOINTS,
    CapsuleSpec,
    JointSpec,
    LinkSpec,
    Robot,
    RobotSpec,
    load_cell,
    load_robot,
)

XYZ_COLUMNS = ("x_mm", "y_mm", "z_mm")
REQUIRED_COLUMNS = Q_COLUMNS + XYZ_COLUMNS
OPTIONAL_COLUMNS = ("temperature_C", "time_s", "payload_kg")
ROW_CONVENTION = "CSV record number, header = row 1 (data row k is row k + 1; blank lines not counted)"
MIN_POSES_FOR_OUTLIER_TEST = 10
N_CORRELATIONS = 10


# ----------------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class MeasurementData:
    """A validated measurement table.

    Attributes:
        path: the file (or a label for in-memory data).
        q: (n, 6) commanded joint angles [rad].
        eta: (n, 3) reflector positions in the tracker frame [mm].
        temperature_C, time_s, payload_kg: (n,) or None when the column is absent.
        rows: (n,) row numbers as in :data:`ROW_CONVENTION`.
    """

    path: str
    q: np.ndarray
    eta: np.ndarray
    temperature_C: np.ndarray | None = None
    time_s: np.ndarray | None = None
    payload_kg: np.ndarray | None = None
    rows: np.ndarray | None = None

    def __post_init__(self):
        if self.rows is None:
            object.__setattr__(self, "rows", np.arange(2, self.q.shape[0] + 2))

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    @classmethod
    def from_table(cls, table, robot: Robot | None = None, *, path: str = "<table>") -> MeasurementData:
        """From a DataFrame in the file format (degrees), e.g. from :func:`simulation.simulate`."""
        for c in REQUIRED_COLUMNS:
            if c not in table:
                raise InputError(f"{path}: missing column {c!r}")
        q_deg = np.column_stack([np.asarray(table[c], dtype=float) for c in Q_COLUMNS])
        eta = np.column_stack([np.asarray(table[c], dtype=float) for c in XYZ_COLUMNS])
        if not (np.all(np.isfinite(q_deg)) and np.all(np.isfinite(eta))):
            raise InputError(f"{path}: non-finite joint angle or position")
        if robot is not None:
            check_joint_angles(path, q_deg, robot)
        opt = {c: np.asarray(table[c], dtype=float) if c in table else None for c in OPTIONAL_COLUMNS}
        return cls(path=path, q=np.deg2rad(q_deg), eta=eta, **opt)


def _near_name(a: str, b: str) -> bool:
    """Case/underscore-insensitive equality or one edit apart (a likely misspelling)."""
    a2, b2 = a.lower().replace(" ", "").replace("-", "_"), b.lower()
    if a2 == b2:
        return True
    if abs(len(a2) - len(b2)) > 1:
        return False
    if len(a2) == len(b2):
        return sum(x != y for x, y in zip(a2, b2, strict=True)) <= 1
    short, long_ = (a2, b2) if len(a2) < len(b2) else (b2, a2)
    return any(long_[:i] + long_[i + 1 :] == short for i in range(len(long_)))


def read_measurements(path: str | Path, robot: Robot) -> MeasurementData:
    """Read and validate a measurement CSV.

    Raises:
        InputError: naming the file, row (header = row 1) and column: missing file, empty file,
            duplicated or missing (misspelled) column, text/NaN/infinity in a number field, joint
            angles that look like radians or lie outside the robot's limits, negative payload,
            fewer than 9 poses (27 parameters need 27 coordinates).
    """
    path = Path(path)
    header, data = read_csv_table(path, REQUIRED_COLUMNS)
    for h in header:
        if h in REQUIRED_COLUMNS or h in OPTIONAL_COLUMNS:
            continue
        for known in OPTIONAL_COLUMNS:
            if _near_name(h, known):
                raise InputError(
                    f"{path}: row 1 (header): unknown column {h!r}; did you mean {known!r}? "
                    f"(optional columns: {', '.join(OPTIONAL_COLUMNS)})"
                )
    if not data:
        raise InputError(f"{path}: no data rows (the file has only a header)")
    q_deg = np.stack([parse_float_column(path, header, data, c) for c in Q_COLUMNS], axis=1)
    eta = np.stack([parse_float_column(path, header, data, c) for c in XYZ_COLUMNS], axis=1)
    opt = {c: parse_float_column(path, header, data, c) if c in header else None for c in OPTIONAL_COLUMNS}
    if opt["payload_kg"] is not None and np.any(opt["payload_kg"] < 0):
        k = int(np.flatnonzero(opt["payload_kg"] < 0)[0])
        row = row_numbers(data)[k]
        raise InputError(f"{path}: row {row}, column 'payload_kg': a payload cannot be negative")
    check_joint_angles(path, q_deg, robot, rows=row_numbers(data))
    n_free = 27
    need = int(np.ceil(n_free / 3))
    if len(data) < need:
        raise InputError(
            f"{path}: {len(data)} poses (data rows 2..{len(data) + 1}) are too few: the {n_free} estimated "
            f"parameters need at least {need} poses (3 coordinates each), and more than {need} for a "
            "goodness-of-fit test; about 60 are usual"
        )
    return MeasurementData(
        path=str(path), q=np.deg2rad(q_deg), eta=eta, rows=np.asarray(row_numbers(data)), **opt
    )


# ----------------------------------------------------------------------------------------------
# Calibration
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class CalibrationReport:
    """Outcome of :func:`calibrate` (internal units) plus :meth:`to_dict` in file units.

    Attributes:
        robot: the nominal robot; nominal: the nominal model; result: the final estimation.
        data: the measurements; q_work: (6,) [rad].
        outliers: indices (0-based into the data) of the removed poses, in removal order.
        normalized: (n,) studentised residual statistics of the final fit (chi^2(3) under H0).
        outlier_threshold: the chi^2(3) threshold of the last test (or None if not tested).
        kpi: (3,) TCP at q_work in W [mm]; kpi_cov: (3, 3) [mm^2]; kpi_nominal: (3,) [mm].
        warnings: human-readable remarks (non-convergence, poor fit, outlier cap).
    """

    robot: Robot
    nominal: TrackerModel
    result: estimation.EstimationResult
    data: MeasurementData
    q_work: np.ndarray
    outliers: list[int]
    normalized: np.ndarray
    outlier_threshold: float | None
    outlier_alpha: float | None
    kpi: np.ndarray
    kpi_cov: np.ndarray
    kpi_nominal: np.ndarray
    warnings: list[str]

    # --- derived numbers ---------------------------------------------------------------------
    @property
    def model(self) -> TrackerModel:
        return self.result.model

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
        return [int(self.data.rows[i]) for i in sorted(self.outliers)]

    def parameter_table(self) -> list[dict]:
        """All 33 parameters: name, value, nominal, std (mm/deg), unit, estimated."""
        lay = self.model.layout
        free = list(lay.free)
        std = self.result.std
        out = []
        for i, name in enumerate(lay.names):
            ang = bool(lay.is_angle[i])
            conv = np.rad2deg if ang else (lambda x: x)
            est = i in free
            value = float(conv(self.model.p[i]))
            nominal = float(conv(self.nominal.p[i]))
            if 27 <= i < 30:  # small rotations about the estimated tracker axes: zero after rebasing
                nominal = None
            row = {
                "name": name,
                "value": value,
                "nominal": nominal,
                "deviation": None if nominal is None else value - nominal,
                "std": float(conv(std[free.index(i)])) if est else 0.0,
                "unit": "deg" if ang else "mm",
                "estimated": est,
            }
            out.append(row)
        return out

    def correlations(self, k: int = N_CORRELATIONS) -> list[dict]:
        """The ``k`` strongest correlations between estimated parameters."""
        Cp = self.result.Cp
        s = np.sqrt(np.diag(Cp))
        R = Cp / np.outer(s, s)
        names = self.result.free_names
        iu = np.triu_indices_from(R, 1)
        order = np.argsort(-np.abs(R[iu]))[:k]
        return [{"a": names[iu[0][j]], "b": names[iu[1][j]], "correlation": float(R[iu][j])} for j in order]

    def tracker(self) -> dict:
        from pydrake.math import RollPitchYaw, RotationMatrix

        R = self.model.R_WT
        rpy = RollPitchYaw(RotationMatrix(R)).vector()
        std = self.result.std
        return {
            "R_WT": R.tolist(),
            "rpy_deg": np.rad2deg(rpy).tolist(),
            "p_WT_mm": self.model.p_WT.tolist(),
            "p_WT_std_mm": std[18:21].tolist(),
            "rotation_std_deg": np.rad2deg(std[21:24]).tolist(),
            "note": "tracker frame T in W as estimated (p_W = R_WT p_T + p_WT); rotation_std_deg: small "
            "rotations about the tracker axes",
        }

    def to_dict(self) -> dict:
        """The JSON report (millimetres and degrees)."""
        std = self.result.std
        res = self.result
        poses = []
        for i in range(self.data.n):
            r = res.residuals[i]
            poses.append(
                {
                    "row": int(self.data.rows[i]),
                    "used": bool(res.mask[i]),
                    "residual_mm": r.tolist(),
                    "residual_norm_mm": float(np.linalg.norm(r)),
                    "normalized_chi2": float(self.normalized[i]),
                    "p_value": float(chi2_dist.sf(self.normalized[i], 3)),
                }
            )
        return {
            "robot": self.robot.name,
            "data": self.data.path,
            "n_poses": self.data.n,
            "n_used": int(np.count_nonzero(self.used)),
            "sigma_mm": res.sigma,
            "q_work_deg": np.rad2deg(self.q_work).tolist(),
            "converged": bool(res.converged),
            "iterations": int(res.iterations),
            "stop_reason": res.message,
            "rms_residual_mm": self.rms_residual_mm,
            "rms_residual_note": "root mean square over the coordinates of the used poses",
            "max_residual_mm": self.max_residual_mm,
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_per_dof": self.chi2_per_dof,
            "p_value": self.p_value,
            "n_outliers": len(self.outliers),
            "outlier_rows": self.outlier_rows,
            "row_convention": ROW_CONVENTION,
            "outlier_test": {
                "statistic": "studentised residual r^T (sigma^2 (I - H_ii))^-1 r ~ chi2(3)",
                "alpha_familywise": self.outlier_alpha,
                "threshold": self.outlier_threshold,
            },
            "kpi_mm": self.kpi.tolist(),
            "kpi_cov_mm2": self.kpi_cov.tolist(),
            "kpi_std_mm": np.sqrt(np.diag(self.kpi_cov)).tolist(),
            "kpi_avg_var_mm2": float(np.trace(self.kpi_cov) / 3.0),
            "kpi_cov_mm2_aposteriori": (self.kpi_cov * self.chi2_per_dof).tolist()
            if self.chi2_per_dof is not None
            else None,
            "kpi_nominal_mm": self.kpi_nominal.tolist(),
            "kpi_note": "TCP (reflector point) at q_work in W; covariance Js Cp Js^T with Cp = (F1^T F1)^-1 "
            "from the given sigma; the a-posteriori version is scaled by chi2/dof",
            "parameters": self.parameter_table(),
            "parameter_std_note": "a-priori standard deviations from the given sigma",
            "correlations": self.correlations(),
            "tracker": self.tracker(),
            "reflector": {
                "p_FQ_mm": self.model.p_FQ.tolist(),
                "std_mm": std[24:27].tolist(),
                "note": "estimated reflector offset in the flange frame; the cell file is not changed",
            },
            "poses": poses,
            "warnings": list(self.warnings),
        }

    def summary(self) -> str:
        """A human-readable summary."""
        d = self
        lines = [
            f"{d.robot.name}: calibrated from {d.data.path}: {d.data.n} poses, "
            f"{int(np.count_nonzero(d.used))} used, 27 parameters, sigma {d.result.sigma:g} mm",
            f"  converged: {d.result.converged} ({d.result.iterations} iterations; {d.result.message})",
            f"  residuals: RMS {d.rms_residual_mm:.4f} mm per coordinate, max {d.max_residual_mm:.4f} mm",
        ]
        if d.dof > 0:
            lines.append(f"  chi2/dof = {d.chi2_per_dof:.3f} (dof {d.dof}), p-value {d.p_value:.3g}")
        if d.outliers:
            lines.append(
                f"  outliers removed: {len(d.outliers)} (rows {', '.join(map(str, d.outlier_rows))})"
            )
        else:
            lines.append("  outliers removed: none")
        sd = np.sqrt(np.diag(d.kpi_cov))
        lines.append(
            "  KPI (TCP at q_work in W): "
            + ", ".join(f"{v:.4f} +- {s:.4f}" for v, s in zip(d.kpi, sd, strict=True))
            + f" mm; tr(Cs)/3 = {np.trace(d.kpi_cov) / 3:.3e} mm^2"
        )
        dev = d.kpi - d.kpi_nominal
        lines.append(f"  KPI shift from nominal: {np.linalg.norm(dev):.4f} mm")
        table = [p for p in d.parameter_table() if p["estimated"] and not p["name"].startswith("tracker")]
        table.sort(key=lambda p: -abs(p["deviation"]) / max(p["std"], 1e-300))
        lines.append("  largest deviations from nominal (in standard deviations):")
        for p in table[:6]:
            lines.append(f"    {p['name']:<12} {p['deviation']:+.5f} +- {p['std']:.5f} {p['unit']}")
        for w in d.warnings:
            lines.append(f"  warning: {w}")
        return "\n".join(lines)


def calibrate(
    robot: str | Robot,
    data: MeasurementData,
    *,
    sigma_mm: float = 0.02,
    q_work=None,
    outlier_threshold: float | None = 0.01,
    max_outlier_fraction: float = 0.1,
    cell_path=None,
    max_iter: int = 100,
) -> CalibrationReport:
    """Calibrate the 27 parameters from measured data.

    Args:
        robot: model name, YAML path or :class:`Robot` (the nominal model to start from).
        data: :class:`MeasurementData` (from :func:`read_measurements`).
        sigma_mm: noise standard deviation per coordinate [mm].
        q_work: (6,) working pose [rad] for the KPI; default: the model file's.
        outlier_threshold: family-wise false-alarm probability alpha of the outlier test
            (Bonferroni: each pose is tested at alpha / n); None or 0 disables the test.
        max_outlier_fraction: remove at most this fraction of the poses.
        cell_path: cell file (default models/cell.yaml): nominal tracker position, reflector offset.

    Returns:
        :class:`CalibrationReport`.

    Raises:
        InputError: bad sigma or q_work, too few poses, or poses that do not determine the
            parameters.
    """
    rob = load_robot(robot) if isinstance(robot, str) else robot
    if not (np.isfinite(sigma_mm) and sigma_mm > 0):
        raise InputError(f"--sigma-mm must be a positive number of millimetres, got {sigma_mm!r}")
    if q_work is None:
        if rob.q_work is None:
            raise InputError(f"{rob.name}: the model file has no q_work_deg; pass --q-work")
        q_work = rob.q_work
    q_work = np.asarray(q_work, dtype=float)
    if q_work.shape != (N_JOINTS,) or np.any(q_work < rob.lower - 1e-9) or np.any(q_work > rob.upper + 1e-9):
        raise InputError(f"{rob.name}: q_work must be 6 angles within the joint limits")
    alpha = float(outlier_threshold) if outlier_threshold else None
    if alpha is not None and not 0 < alpha < 1:
        raise InputError(
            f"outlier threshold (family-wise level) must be in (0, 1), got {outlier_threshold!r}"
        )
    cell = load_cell(cell_path, robot=rob)
    nominal = nominal_model(rob, cell)
    n = data.n
    need = int(np.ceil(nominal.layout.n_free / 3))
    if n < need:
        raise InputError(
            f"{data.path}: {n} poses are too few for {nominal.layout.n_free} parameters (need {need})"
        )

    warnings: list[str] = []
    mask = np.ones(n, dtype=bool)
    outliers: list[int] = []
    max_out = int(np.floor(max_outlier_fraction * n))
    res = estimation.estimate(nominal, data.q, data.eta, sigma=sigma_mm, mask=mask, max_iter=max_iter)
    threshold = None
    while True:
        t = estimation.normalized_residuals(res)
        n_used = int(np.count_nonzero(mask))
        if alpha is None or n_used - 1 < MIN_POSES_FOR_OUTLIER_TEST:
            break
        threshold = float(chi2_dist.isf(alpha / n_used, 3))
        used = np.flatnonzero(mask)
        worst = int(used[np.argmax(t[used])])
        if t[worst] <= threshold:
            break
        if len(outliers) >= max_out:
            warnings.append(
                f"outlier removal stopped after {len(outliers)} poses "
                f"(cap {max_outlier_fraction:.0%} of the data); "
                f"row {int(data.rows[worst])} still fails the test: the residuals suggest model discrepancy "
                "or a wrong --sigma-mm rather than single bad points"
            )
            break
        mask[worst] = False
        outliers.append(worst)
        res = estimation.estimate(
            res.model, data.q, data.eta, sigma=sigma_mm, mask=mask, register=False, max_iter=max_iter
        )
    normalized = estimation.normalized_residuals(res)
    if not res.converged:
        warnings.append(f"the least-squares iteration did not converge ({res.message})")

    s, Js = kpi_jacobian(res.model, q_work)
    Jf = Js[:, res.free]
    kpi_cov = Jf @ res.Cp @ Jf.T
    kpi_nom = kpi_jacobian(nominal, q_work)[0]
    report = CalibrationReport(
        robot=rob,
        nominal=nominal,
        result=res,
        data=data,
        q_work=q_work,
        outliers=outliers,
        normalized=normalized,
        outlier_threshold=threshold,
        outlier_alpha=alpha,
        kpi=s,
        kpi_cov=kpi_cov,
        kpi_nominal=kpi_nom,
        warnings=warnings,
    )
    p = report.p_value
    if p is not None and p < 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g} (p = {p:.2g}): the residuals are larger than a noise of "
            f"{sigma_mm:g} mm explains; the noise is larger than given or the geometric model misses an "
            "effect (see `kpioed diagnose`); the a-posteriori covariance scales by chi2/dof"
        )
    elif p is not None and p > 1 - 1e-3:
        warnings.append(
            f"chi2/dof = {report.chi2_per_dof:.3g}: the residuals are smaller than a noise of "
            f"{sigma_mm:g} mm "
            "predicts; --sigma-mm is probably too large (the reported uncertainties are then pessimistic)"
        )
    return report


# ----------------------------------------------------------------------------------------------
# Calibrated model file
# ----------------------------------------------------------------------------------------------
def _spec_from_robot(robot: Robot) -> RobotSpec:
    """A RobotSpec rebuilt from a loaded robot (used when its source file is not available)."""
    joints = []
    for i, conv in enumerate(robot.conventions):
        joints.append(
            JointSpec(
                name=robot.joint_names[i],
                convention=conv,
                lower_deg=float(np.rad2deg(robot.lower[i])),
                upper_deg=float(np.rad2deg(robot.upper[i])),
            )
        )
    links = []
    for k in range(N_JOINTS + 1):
        caps = [
            CapsuleSpec(name=c.name, radius_mm=c.radius, a_mm=c.a.tolist(), b_mm=c.b.tolist())
            for c in robot.capsules
            if c.frame == k
        ]
        links.append(
            LinkSpec(index=k, mass_kg=float(robot.masses[k]), com_mm=robot.coms[k].tolist(), capsules=caps)
        )
    return RobotSpec(
        name=robot.name,
        joints=joints,
        links=links,
        self_collision_pairs=[list(p) for p in robot.self_pairs],
        beam_links=list(robot.beam_links),
        q_work_deg=[] if robot.q_work is None else np.rad2deg(robot.q_work).tolist(),
        car_shift_x_mm=robot.car_shift_x,
    )


def _robot_spec(robot: Robot) -> RobotSpec:
    from pydrake.common.yaml import yaml_load_typed

    src = Path(robot.source) if robot.source else None
    if src is not None and src.is_file():
        try:
            return yaml_load_typed(filename=str(src), schema=RobotSpec)
        except Exception:  # fall back to the loaded object
            pass
    return _spec_from_robot(robot)


def calibrated_robot_yaml(report: CalibrationReport) -> str:
    """The calibrated robot as model-file text (RobotSpec schema, mm/deg).

    Joint rows hold the estimated values (the gauge parameters theta1, d1, theta6, d6, a6, alpha6
    keep their nominal values); capsules, masses, limits and q_work are the nominal model's. The
    reflector offset and the tracker pose are not robot properties: they are reported in the note.
    """
    from pydrake.common.yaml import yaml_dump_typed

    rob = report.robot
    spec = _robot_spec(rob)
    g = report.model.geometry
    for i, j in enumerate(spec.joints):
        conv = rob.conventions[i]
        j.convention = conv
        if conv == "dh":
            th, d, a, al = g[i]
            j.theta_deg, j.d_mm, j.a_mm, j.alpha_deg = (
                float(np.rad2deg(th)),
                float(d),
                float(a),
                float(np.rad2deg(al)),
            )
            j.beta_deg = 0.0
        else:
            th, a, al, be = g[i]
            j.theta_deg, j.a_mm, j.alpha_deg = float(np.rad2deg(th)), float(a), float(np.rad2deg(al))
            j.beta_deg, j.d_mm = float(np.rad2deg(be)), 0.0
    spec.name = f"{rob.name}-calibrated"
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    pf = report.model.p_FQ
    pt = report.model.p_WT
    cal_note = (
        f"Calibrated by kpioed calibrate from {report.data.path} ({stamp}): "
        f"{int(np.count_nonzero(report.used))} of {report.data.n} poses, sigma {report.result.sigma:g} mm, "
        f"RMS residual {report.rms_residual_mm:.4g} mm"
        + (f", chi2/dof {report.chi2_per_dof:.3g}" if report.chi2_per_dof is not None else "")
        + f". Joint rows hold the estimates (theta1, d1, theta6, d6, a6, alpha6 nominal: the gauge). "
        f"Estimated reflector offset (not stored here; the cell file is unchanged): "
        f"({pf[0]:.4f}, {pf[1]:.4f}, {pf[2]:.4f}) mm; tracker position in W ({pt[0]:.3f}, {pt[1]:.3f}, "
        f"{pt[2]:.3f}) mm."
    )
    spec.notes = (spec.notes + " " if spec.notes else "") + cal_note
    header = "# Calibrated robot model file (kpioed-drake). Units: mm, deg, kg. Format: models/README.md.\n"
    return header + yaml_dump_typed(spec)


# ----------------------------------------------------------------------------------------------
# The whole workflow
# ----------------------------------------------------------------------------------------------
def calibrate_file(
    robot: str,
    data_path: str,
    *,
    sigma_mm: float = 0.02,
    q_work_deg: str | None = None,
    out: str | None = None,
    json_path: str | None = None,
    plots_dir: str | None = None,
    outlier_threshold: float | None = 0.01,
    cell_path=None,
) -> CalibrationReport:
    """Read, calibrate, and write the requested outputs (only after everything succeeded).

    Args:
        robot: model name or YAML path; data_path: the measurement CSV.
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        out: calibrated robot model file (YAML) to write.
        json_path: JSON report to write.
        plots_dir: folder for the residual plots (PNG).
    """
    rob = load_robot(robot)
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    data = read_measurements(data_path, rob)
    report = calibrate(
        rob, data, sigma_mm=sigma_mm, q_work=qw, outlier_threshold=outlier_threshold, cell_path=cell_path
    )
    yaml_text = calibrated_robot_yaml(report) if out else None
    json_data = report.to_dict() if json_path else None
    staged = None
    try:
        if plots_dir:
            from kpioed_drake.calibration_plots import plot_calibration

            parent = Path(plots_dir).resolve().parent
            parent.mkdir(parents=True, exist_ok=True)
            staged = Path(tempfile.mkdtemp(prefix=".kpioed-plots.", dir=parent))
            files = plot_calibration(report, staged)
        # everything computed: write
        if out:
            atomic_write_text(out, yaml_text)
        if json_path:
            atomic_write_json(json_path, json_data)
        if plots_dir:
            dest = Path(plots_dir)
            dest.mkdir(parents=True, exist_ok=True)
            for f in files:
                os.replace(f, dest / f.name)
    finally:
        if staged is not None:
            shutil.rmtree(staged, ignore_errors=True)
    return report
