"""Model discrepancy: does the geometric model explain the data, and if not, which effect is missing?

:func:`diagnose` runs four steps on laser-tracker data (SPEC "Measured data and model discrepancy"):

1. **Geometric calibration and a goodness-of-fit test.** The 27 geometric parameters are fitted
   (rigid registration of the tracker, then Gauss-Newton/Levenberg-Marquardt). With a correct model
   and the known noise sigma, ``chi^2 = |r|^2 / sigma^2`` follows a chi-square law with
   ``3 n - 27`` degrees of freedom; a p-value below ``alpha`` is a discrepancy.
2. **Residual structure.** For every candidate extension the score statistic of its columns against
   the baseline residuals (``r^T P r / sigma^2`` with P the projector on the part of the columns the
   geometric parameters cannot absorb): the residual's correlation with gravity torque per joint,
   with ``sin/cos(n q_i)``, with the scale of the reflector position times the temperature, with
   time. Plots: :mod:`kpioed_drake.diagnosis_plots`.
3. **Naming the cause (forward selection).** Each candidate effect
   (:mod:`kpioed_drake.effects`) is fitted jointly with the geometric parameters. Before the fit its
   identifiability is checked: the fraction of its columns outside the span of the current model's
   columns (``remaining``; 1 = orthogonal, 0 = absorbed) and the largest canonical correlation with
   them; a candidate with ``remaining < MIN_REMAINING`` is reported as absorbed and not fitted (e.g. a
   first-harmonic gear error of a joint whose range in the data is small looks like a DH offset and
   axis tilt). A fitted candidate is tested with the likelihood ratio against the known noise,
   ``LR = (chi^2_before - chi^2_after)`` ~ chi^2(k) under "no effect", Bonferroni-corrected over the
   candidates tested in that step, and with BIC (``LR > k ln(3 n)``); its held-out error comes from
   K-fold cross-validation over poses (every fold refitted). Among the significant candidates the
   one with the largest penalised likelihood gain (``LR - k ln(3 n)``) is added provided it also
   lowers the held-out error; then every effect already chosen is re-tested for removal (stepwise),
   and the search repeats until no candidate is significant.
4. **The extended model and the gain**: RMS, chi^2/dof and held-out RMS before and after, and the
   KPI (TCP at ``q_work``): its shift between the two models and its variance tr(Cs)/3.

Candidates: ``joint_elasticity`` of joints 2..6 (joint 1 turns about the vertical axis, gravity has
no torque on it); ``gear_cyclic`` of joints 1..6 with n in {1, 2}; ``thermal_expansion`` if the data
has a temperature that varies; ``tracker_drift`` if it has a time that varies.

Units: mm, rad inside; reports in the display units of :data:`kpioed_drake.effects.UNITS`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.errors import InputError
from kpioed_drake.measurement import TrackerModel, kpi_jacobian, nominal_model, reflector_world
from kpioed_drake.models import N_JOINTS, Robot, load_cell, load_robot

ALPHA = 0.01
"""Level of the goodness-of-fit test and family-wise level of each selection step."""
MIN_REMAINING = 0.05
"""A candidate whose columns keep less than this fraction outside the model's span is 'absorbed'."""
K_FOLDS = 5
MAX_EFFECTS = 4
FOLD_SEED = 0


# ----------------------------------------------------------------------------------------------
# Data
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Measurements:
    """Measured data in internal units.

    Attributes:
        q: (n, 6) commanded joint angles [rad].
        eta: (n, 3) reflector positions in the tracker frame [mm].
        temperature_C, time_s, payload_kg: (n,) or None.
        source: where the data came from (for messages).
    """

    q: np.ndarray
    eta: np.ndarray
    temperature_C: np.ndarray | None = None
    time_s: np.ndarray | None = None
    payload_kg: np.ndarray | None = None
    source: str = "data"

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    def to_frame(self):
        """A pandas DataFrame in the SPEC file format (degrees, mm)."""
        import pandas as pd

        cols = {c: np.rad2deg(self.q[:, i]) for i, c in enumerate(_Q_COLS)}
        cols.update({c: self.eta[:, i] for i, c in enumerate(_XYZ)})
        for c in _OPTIONAL:
            if getattr(self, c) is not None:
                cols[c] = getattr(self, c)
        return pd.DataFrame(cols)

    def subset(self, idx) -> Measurements:
        def pick(x):
            return None if x is None else x[idx]

        return dataclasses.replace(
            self,
            q=self.q[idx],
            eta=self.eta[idx],
            temperature_C=pick(self.temperature_C),
            time_s=pick(self.time_s),
            payload_kg=pick(self.payload_kg),
        )


_Q_COLS = tuple(f"q{i}_deg" for i in range(1, N_JOINTS + 1))
_XYZ = ("x_mm", "y_mm", "z_mm")
_OPTIONAL = ("temperature_C", "time_s", "payload_kg")


def _from_frame(df, source: str) -> Measurements:
    missing = [c for c in _Q_COLS + _XYZ if c not in df.columns]
    if missing:
        raise InputError(f"{source}: missing column {missing[0]!r} (SPEC measurement format)")
    q = np.deg2rad(df[list(_Q_COLS)].to_numpy(dtype=float))
    eta = df[list(_XYZ)].to_numpy(dtype=float)
    opt = {c: (df[c].to_numpy(dtype=float) if c in df.columns else None) for c in _OPTIONAL}
    return Measurements(q, eta, source=source, **opt)


def read_data(path, robot: Robot) -> Measurements:
    """Read a SPEC measurement CSV (``calibration.read_measurements`` if available)."""
    try:
        from kpioed_drake.calibration import read_measurements
    except ImportError:
        read_measurements = None
    if read_measurements is not None:
        return as_measurements(read_measurements(path, robot), robot)
    from kpioed_drake.designio import check_joint_angles, parse_float_column, read_csv_table

    header, rows = read_csv_table(path, _Q_COLS + _XYZ)
    if len(rows) == 0:
        raise InputError(f"{path}: no measurements (the file has only a header)")
    cols = {c: parse_float_column(path, header, rows, c) for c in _Q_COLS + _XYZ}
    q_deg = np.stack([cols[c] for c in _Q_COLS], axis=1)
    check_joint_angles(path, q_deg, robot)
    opt = {c: (parse_float_column(path, header, rows, c) if c in header else None) for c in _OPTIONAL}
    eta = np.stack([cols[c] for c in _XYZ], axis=1)
    return Measurements(np.deg2rad(q_deg), eta, source=str(path), **opt)


def as_measurements(data, robot: Robot | None = None) -> Measurements:
    """Accept a :class:`Measurements`, a path, a pandas DataFrame in SPEC format, or an object with
    attributes ``q`` [rad] and ``eta`` (or ``xyz``/``p_T``) [mm] (e.g. the result of
    ``calibration.read_measurements``) and optional ``temperature_C``, ``time_s``, ``payload_kg``."""
    if isinstance(data, Measurements):
        return data
    if isinstance(data, str | Path):
        if robot is None:
            raise InputError("reading a data file needs the robot")
        return read_data(data, robot)
    try:
        import pandas as pd

        if isinstance(data, pd.DataFrame):
            return _from_frame(data, "data")
    except ImportError:  # pragma: no cover
        pass
    get = data.get if isinstance(data, dict) else (lambda k, d=None: getattr(data, k, d))
    q = get("q")
    eta = next((get(k) for k in ("eta", "xyz", "p_T", "xyz_mm") if get(k) is not None), None)
    if q is None or eta is None:
        frame = get("table") if get("table") is not None else get("frame")
        if frame is not None:
            return _from_frame(frame, str(get("source", "data")))
        raise InputError("data: expected a DataFrame in SPEC format or an object with q and eta")
    opt = {}
    for c in _OPTIONAL:
        v = get(c)
        opt[c] = None if v is None else np.asarray(v, dtype=float)
    return Measurements(
        np.asarray(q, float),
        np.asarray(eta, float),
        source=str(get("source", None) or get("path", "data")),
        **opt,
    )


def _check(data: Measurements) -> None:
    n = data.n
    if data.q.shape != (n, N_JOINTS) or data.eta.shape != (n, 3):
        raise InputError(f"{data.source}: expected q (n, 6) and positions (n, 3)")
    for name in ("eta",) + _OPTIONAL:
        v = getattr(data, name)
        if v is not None and not np.all(np.isfinite(v)):
            raise InputError(f"{data.source}: column {name} has a non-finite value")


# ----------------------------------------------------------------------------------------------
# Fitting the augmented model
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Fit:
    """A least-squares fit of the geometric parameters and some effects.

    Attributes:
        model: the fitted geometric model (tracker small rotations folded into the reference).
        effects: the effects with their fitted values.
        residuals: (n, 3) ``eta - h`` for every pose of the data given [mm].
        cost: chi^2 over the fitted poses (``|r|^2 / sigma^2``).
        n_used: number of fitted poses.
        J: (3 m, 27 + k) weighted Jacobian at the solution over the fitted poses.
        sigma: noise [mm].
    """

    model: TrackerModel
    effects: list
    residuals: np.ndarray
    cost: float
    n_used: int
    J: np.ndarray
    sigma: float
    iterations: int = 0

    @property
    def k(self) -> int:
        return sum(e.n_params for e in self.effects)

    @property
    def n_params(self) -> int:
        return self.model.layout.n_free + self.k

    @property
    def dof(self) -> int:
        return 3 * self.n_used - self.n_params

    @property
    def chi2_per_dof(self) -> float:
        return self.cost / self.dof if self.dof > 0 else float("nan")

    def covariance(self) -> np.ndarray:
        """(27 + k, 27 + k) a-priori covariance ``(J^T J)^-1`` (known sigma) [mm, rad, effect units]."""
        D = np.linalg.norm(self.J, axis=0)
        D[D == 0] = 1.0
        Js = self.J / D
        return np.linalg.pinv(Js.T @ Js) / np.outer(D, D)


class FitProblem:
    """Data + sigma + the cached gravity torques: fits of any set of effects on any subset of poses."""

    def __init__(self, robot: Robot, data: Measurements, sigma: float, *, cell=None):
        self.robot, self.data, self.sigma = robot, data, float(sigma)
        self.cell = load_cell(robot=robot) if cell is None else cell
        self.nominal = nominal_model(robot, self.cell)
        # Gravity torques at the commanded angles, payload at the nominal reflector point (fixed
        # during the fit, so that the residual function stays the same for every parameter value).
        self.tau = fx.gravity_torques(robot, data.q, payload_kg=data.payload_kg, p_FP=self.nominal.p_FQ)

    def response(self, model, effects, idx, *, jac: bool = True):
        d = self.data
        out = fx.augmented_jacobian(
            model,
            d.q[idx],
            effects,
            temperature_C=None if d.temperature_C is None else d.temperature_C[idx],
            time_s=None if d.time_s is None else d.time_s[idx],
            tau=self.tau[idx],
        )
        return out if jac else out[0]

    def weighted(self, model, effects, idx):
        h, H, E = self.response(model, effects, idx)
        r = (self.data.eta[idx] - h) / self.sigma
        J = np.concatenate([H[:, :, model.layout.free], E], axis=2) / self.sigma
        return r.reshape(-1), J.reshape(r.size, -1)

    def start(self, idx=None) -> TrackerModel:
        from kpioed_drake.estimation import registered_model

        idx = np.arange(self.data.n) if idx is None else idx
        return registered_model(self.nominal, self.data.q[idx], self.data.eta[idx])

    def fit(self, effects, *, start: Fit | None = None, idx=None, max_iter: int = 30) -> Fit:
        """Fit the geometric parameters and the effects' values on poses ``idx`` (default all).

        Starts from ``start`` (its model and the values of effects it shares) or from the
        registered nominal model with zero effect values.
        """
        n = self.data.n
        idx = np.arange(n) if idx is None else np.asarray(idx)
        known = {e.key: e for e in (start.effects if start is not None else [])}
        effs = [
            e.with_values(known[e.key].value_array())
            if e.key in known
            else e.with_values(np.zeros(e.n_params))
            for e in effects
        ]
        model = start.model if start is not None else self.start(idx)
        free = model.layout.free
        r, J = self.weighted(model, effs, idx)
        cost = float(r @ r)
        lam, it = 0.0, 0
        while it < max_iter:
            it += 1
            D = np.linalg.norm(J, axis=0)
            D[D == 0] = 1.0
            Js = J / D
            if lam > 0:
                A = np.vstack([Js, np.sqrt(lam) * np.eye(Js.shape[1])])
                b = np.concatenate([r, np.zeros(Js.shape[1])])
            else:
                A, b = Js, r
            dxs = np.linalg.lstsq(A, b, rcond=None)[0]
            dx = dxs / D
            p = model.p.copy()
            p[free] += dx[: free.size]
            trial = model.with_params(p)
            new_effs, c = [], free.size
            for e in effs:
                new_effs.append(e.with_values(e.value_array() + dx[c : c + e.n_params]))
                c += e.n_params
            r_new, J_new = self.weighted(trial, new_effs, idx)
            cost_new = float(r_new @ r_new)
            if cost_new <= cost:
                decrease = cost - cost_new
                model, effs, r, J, cost = trial.rebased(), new_effs, r_new, J_new, cost_new
                lam = lam / 10.0 if lam > 1e-6 else 0.0
                if decrease <= 1e-9 * max(cost, 1.0) or np.linalg.norm(dxs) < 1e-9:
                    break
            else:
                lam = max(lam * 10.0, 1e-4)
                if lam > 1e8:
                    break
        if np.any(np.asarray(model.p[27:30]) != 0):
            model = model.rebased()
        resid = self.data.eta - self.response(model, effs, np.arange(n), jac=False)
        _, J = self.weighted(model, effs, idx)
        return Fit(model, effs, resid, cost, int(idx.size), J, self.sigma, it)

    def folds(self, k: int = K_FOLDS) -> list[np.ndarray]:
        n = self.data.n
        k = int(min(k, n))
        perm = np.random.default_rng(FOLD_SEED).permutation(n)
        return [np.sort(perm[i::k]) for i in range(k)]

    def holdout(self, full: Fit, *, k: int = K_FOLDS) -> np.ndarray:
        """(n, 3) held-out residuals by K-fold cross-validation (each fold refitted from ``full``)."""
        n = self.data.n
        out = np.empty((n, 3))
        for test in self.folds(k):
            train = np.setdiff1d(np.arange(n), test)
            f = self.fit(full.effects, start=full, idx=train)
            out[test] = f.residuals[test]
        return out


def rms(r) -> float:
    """Root mean square over all coordinates [mm]."""
    r = np.asarray(r)
    return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


# ----------------------------------------------------------------------------------------------
# Candidates and identifiability
# ----------------------------------------------------------------------------------------------
def candidate_effects(data: Measurements, robot: Robot | None = None) -> tuple[list, list[str]]:
    """The candidate extensions for this data and notes on the ones left out."""
    notes = []
    cands = [fx.Effect("joint_elasticity", j) for j in range(2, N_JOINTS + 1)]
    notes.append(
        "joint_elasticity:1 is not a candidate: joint 1 turns about the vertical axis, gravity exerts no "
        "torque on it"
    )
    cands += [fx.Effect("gear_cyclic", j, n) for j in range(1, N_JOINTS + 1) for n in (1, 2)]
    if data.temperature_C is not None and np.ptp(data.temperature_C) > 0.5:
        cands.append(fx.Effect("thermal_expansion"))
    else:
        notes.append(
            "thermal_expansion is not a candidate: "
            + (
                "no temperature_C column"
                if data.temperature_C is None
                else "the temperature varies by < 0.5 K"
            )
            + " (a constant temperature only rescales lengths, which the geometric parameters absorb)"
        )
    if data.time_s is not None and np.ptp(data.time_s) > 0:
        cands.append(fx.Effect("tracker_drift"))
    else:
        notes.append("tracker_drift is not a candidate: no time_s column or a constant time")
    return cands, notes


def identifiability(J_model: np.ndarray, J_cand: np.ndarray) -> dict:
    """How well candidate columns separate from the model's columns (both weighted, (m, .)).

    Returns ``remaining`` (smallest singular value of the candidate's orthonormalised columns after
    projecting out the model's span: 1 = orthogonal, 0 = absorbed), ``max_corr`` (largest canonical
    correlation with the model's columns, ``sqrt(1 - remaining^2)``) and ``condition`` (of the
    column-scaled joint matrix).
    """
    Q, _ = np.linalg.qr(J_model)
    Dc = np.linalg.norm(J_cand, axis=0)
    if np.any(Dc == 0):
        return {"remaining": 0.0, "max_corr": 1.0, "condition": float("inf")}
    Qc, _ = np.linalg.qr(J_cand / Dc)
    R = Qc - Q @ (Q.T @ Qc)
    sv = np.linalg.svd(R, compute_uv=False)
    remaining = float(sv.min())
    A = np.concatenate([J_model, J_cand], axis=1)
    D = np.linalg.norm(A, axis=0)
    D[D == 0] = 1.0
    s = np.linalg.svd(A / D, compute_uv=False)
    return {
        "remaining": remaining,
        "max_corr": float(np.sqrt(max(0.0, 1.0 - remaining**2))),
        "condition": float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
    }


# ----------------------------------------------------------------------------------------------
# Report
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class DiagnosisReport:
    """Result of :func:`diagnose`; :meth:`to_json` gives the documented JSON contract.

    ``details`` holds arrays for plots (not part of the JSON).
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
        return _jsonable(
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


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, np.generic):
        return _jsonable(o.item())
    if isinstance(o, float) and not np.isfinite(o):
        return None
    return o


def _fit_summary(prob: FitProblem, fit: Fit, holdout: np.ndarray) -> dict:
    return {
        "rms_mm": rms(fit.residuals),
        "chi2": fit.cost,
        "dof": fit.dof,
        "chi2_per_dof": fit.chi2_per_dof,
        "p_value": float(scipy.stats.chi2.sf(fit.cost, fit.dof)),
        "holdout_rms_mm": rms(holdout),
        "n_params": fit.n_params,
    }


def _effect_signal(prob: FitProblem, fit: Fit, i: int) -> np.ndarray:
    """(n, 3) contribution of effect i of ``fit`` to the measurements (linearised) [mm]."""
    idx = np.arange(prob.data.n)
    _, _, E = prob.response(fit.model, fit.effects, idx)
    c = sum(e.n_params for e in fit.effects[:i])
    e = fit.effects[i]
    return E[:, :, c : c + e.n_params] @ e.value_array()


def _kpi(prob: FitProblem, base: Fit, ext: Fit) -> dict:
    robot = prob.robot
    if robot.q_work is None:
        return {}
    qw = robot.q_work
    out = {"q_work_deg": np.rad2deg(qw)}
    s_b, Js_b = kpi_jacobian(base.model, qw)
    s_e, Js_e = kpi_jacobian(ext.model, qw)
    s_e = s_e + fx.effect_tcp_shift(ext.model, qw, ext.effects)
    free = base.model.layout.free
    Jb = Js_b[:, free]
    Je = np.concatenate([Js_e[:, free], fx.effect_kpi_columns(ext.model, qw, ext.effects)], axis=1)
    Cb = Jb @ base.covariance() @ Jb.T
    Ce = Je @ ext.covariance() @ Je.T
    out.update(
        {
            "tcp_baseline_mm": s_b,
            "tcp_extended_mm": s_e,
            "tcp_shift_mm": float(np.linalg.norm(s_e - s_b)),
            "kpi_avg_var_mm2_baseline": float(np.trace(Cb) / 3.0),
            "kpi_avg_var_mm2_extended": float(np.trace(Ce) / 3.0),
            "conditions": f"no payload, temperature {fx.T_REF_C:g} C",
        }
    )
    return out


def _score_tests(prob: FitProblem, fit: Fit, cands) -> list:
    """Residual structure: score statistic of each candidate's columns against ``fit``'s residuals."""
    idx = np.arange(prob.data.n)
    r = (fit.residuals / prob.sigma).reshape(-1)
    _, H, E = prob.response(fit.model, fit.effects + list(cands), idx)
    free = fit.model.layout.free
    k0 = fit.k
    Jm = np.concatenate([H[:, :, free], E[:, :, :k0]], axis=2).reshape(r.size, -1) / prob.sigma
    Q, _ = np.linalg.qr(Jm)
    out, c = [], k0
    for e in cands:
        C = E[:, :, c : c + e.n_params].reshape(r.size, -1) / prob.sigma
        c += e.n_params
        Cp = C - Q @ (Q.T @ C)
        Qc, sv, _ = np.linalg.svd(Cp, full_matrices=False)
        keep = sv > 1e-9 * max(sv.max(), 1e-300)
        proj = Qc[:, keep].T @ r
        stat = float(proj @ proj)
        dof = int(keep.sum())
        variable = {
            "joint_elasticity": f"gravity torque tau_{e.joint}",
            "gear_cyclic": f"sin/cos({e.harmonic} q_{e.joint})",
            "thermal_expansion": "temperature x reflector position",
            "tracker_drift": "time",
        }[e.family]
        out.append(
            {
                "candidate": e.name,
                "variable": variable,
                "score": stat,
                "dof": dof,
                "p_value": float(scipy.stats.chi2.sf(stat, dof)) if dof else 1.0,
            }
        )
    return sorted(out, key=lambda d: d["p_value"])


def diagnose(
    robot,
    data,
    *,
    sigma_mm: float = 0.02,
    alpha: float = ALPHA,
    k_folds: int = K_FOLDS,
    max_effects: int = MAX_EFFECTS,
    candidates=None,
    cell=None,
) -> DiagnosisReport:
    """Diagnose the model discrepancy of a robot's laser-tracker data.

    Args:
        robot: model name, path or :class:`~kpioed_drake.models.Robot`.
        data: a path to a SPEC measurement CSV, a DataFrame in that format, the result of
            ``calibration.read_measurements`` or :class:`Measurements`.
        sigma_mm: the known noise standard deviation per coordinate [mm].
        alpha: level of the goodness-of-fit test and family-wise level of each selection step.
        k_folds: folds of the cross-validation over poses.
        max_effects: most effects to add.
        candidates: override the candidate list (effects or texts).

    Returns:
        :class:`DiagnosisReport`.
    """
    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    data = as_measurements(data, robot)
    _check(data)
    if not (np.isfinite(sigma_mm) and sigma_mm > 0):
        raise InputError(f"--sigma-mm must be a positive number of millimetres, got {sigma_mm!r}")
    prob = FitProblem(robot, data, sigma_mm, cell=cell)
    n = data.n
    n_free = prob.nominal.layout.n_free
    if 3 * (n - int(np.ceil(n / k_folds))) < n_free + 6:
        raise InputError(
            f"{data.source}: {n} poses are too few to calibrate {n_free} parameters with {k_folds}-fold "
            "cross-validation (use at least 15 poses; 60 or more to name causes)"
        )
    if candidates is None:
        cands, notes = candidate_effects(data, robot)
    else:
        cands = [
            fx.parse_effect(c) if isinstance(c, str) else dataclasses.replace(c, values=None)
            for c in candidates
        ]
        notes = []
    ln_n = np.log(3 * n)

    # 1. geometric calibration and the goodness-of-fit test
    base = prob.fit([])
    base_hold = prob.holdout(base, k=k_folds)
    p_gof = float(scipy.stats.chi2.sf(base.cost, base.dof))
    test = {
        "chi2": base.cost,
        "dof": base.dof,
        "chi2_per_dof": base.chi2_per_dof,
        "p_value": p_gof,
        "alpha": alpha,
        "rejects": bool(p_gof < alpha),
    }

    # 2. residual structure
    structure = _score_tests(prob, base, cands)

    # 3. forward (stepwise) selection
    current, cur_hold = base, base_hold
    steps, chosen_evidence = [], {}
    for step in range(1, max_effects + 1):
        pool = [c for c in cands if c.key not in {e.key for e in current.effects}]
        if not pool:
            break
        idx = np.arange(n)
        _, H, E = prob.response(current.model, current.effects + pool, idx)
        free = current.model.layout.free
        k0 = current.k
        Jm = np.concatenate([H[:, :, free], E[:, :, :k0]], axis=2).reshape(3 * n, -1) / prob.sigma
        rows, c = [], k0
        tested = []
        for e in pool:
            Jc = E[:, :, c : c + e.n_params].reshape(3 * n, -1) / prob.sigma
            c += e.n_params
            ident = identifiability(Jm, Jc)
            row = {"candidate": e.name, **ident}
            if ident["remaining"] < MIN_REMAINING:
                row["status"] = "absorbed by the model's parameters (not identifiable from these poses)"
                rows.append(row)
                continue
            tested.append((e, row))
            rows.append(row)
        m = max(len(tested), 1)
        best = None
        for e, row in tested:
            f = prob.fit(current.effects + [e], start=current)
            lr = max(current.cost - f.cost, 0.0)
            p = float(scipy.stats.chi2.sf(lr, e.n_params))
            row.update(
                {
                    "lr_stat": lr,
                    "dof": e.n_params,
                    "p_value": p,
                    "p_value_corrected": min(1.0, p * m),
                    "delta_bic": lr - e.n_params * ln_n,
                }
            )
            if row["p_value_corrected"] < alpha and row["delta_bic"] > 0:
                row["_fit"] = f
                if best is None or row["delta_bic"] > best[1]["delta_bic"]:
                    best = (e, row)
        # held-out error of the significant candidates (the expensive part)
        for _, row in tested:
            if "_fit" in row:
                hold = prob.holdout(row["_fit"], k=k_folds)
                row["holdout_rms_mm"] = rms(hold)
                row["_hold"] = hold
        accepted = None
        if best is not None:
            e, row = best
            if row["holdout_rms_mm"] < rms(cur_hold):
                accepted = (e, row)
            else:
                row["status"] = "significant but does not lower the held-out error"
        step_rec = {
            "step": step,
            "holdout_rms_mm_before": rms(cur_hold),
            "chi2_before": current.cost,
            "candidates": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows],
        }
        if accepted is None:
            step_rec["added"] = None
            steps.append(step_rec)
            break
        e, row = accepted
        step_rec["added"] = e.name
        chosen_evidence[e.key] = {k: v for k, v in row.items() if not k.startswith("_") and k != "candidate"}
        chosen_evidence[e.key]["holdout_rms_mm_with"] = chosen_evidence[e.key].pop("holdout_rms_mm")
        chosen_evidence[e.key]["step"] = step
        chosen_evidence[e.key]["holdout_rms_mm_without"] = rms(cur_hold)
        current, cur_hold = row["_fit"], row["_hold"]
        # backward check: does every chosen effect still earn its place?
        removed = []
        for old in list(current.effects):
            if old.key == e.key or len(current.effects) < 2:
                continue
            rest = [x for x in current.effects if x.key != old.key]
            f = prob.fit(rest, start=current)
            lr = max(f.cost - current.cost, 0.0)
            p = float(scipy.stats.chi2.sf(lr, old.n_params))
            if p >= alpha or lr - old.n_params * ln_n <= 0:
                current, cur_hold = f, prob.holdout(f, k=k_folds)
                removed.append(old.name)
                chosen_evidence.pop(old.key, None)
        if removed:
            step_rec["removed"] = removed
        steps.append(step_rec)

    ext, ext_hold = current, cur_hold
    # 4. the extended model and its gain
    cov = ext.covariance()
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    causes, c = [], n_free
    for i, e in enumerate(ext.effects):
        d = e.to_dict()
        s_int = std[c : c + e.n_params]
        c += e.n_params
        dv = e.display_values(s_int)
        d["std"] = dv[0] if len(dv) == 1 else dv
        d.pop("tool_mm", None)
        sig = _effect_signal(prob, ext, i)
        ev = dict(chosen_evidence.get(e.key, {}))
        # the final LR of this effect given all others (re-fitted without it)
        rest = [x for x in ext.effects if x.key != e.key]
        f0 = prob.fit(rest, start=ext)
        ev["lr_stat_final"] = max(f0.cost - ext.cost, 0.0)
        ev["tool_max_mm"] = float(np.max(np.linalg.norm(sig, axis=1)))
        ev["tool_rms_mm"] = float(np.sqrt(np.mean(np.sum(sig**2, axis=1))))
        d["evidence"] = ev
        causes.append(d)
    baseline = _fit_summary(prob, base, base_hold)
    extended = _fit_summary(prob, ext, ext_hold)
    kpi = _kpi(prob, base, ext)
    gain = {
        "holdout_rms_ratio": extended["holdout_rms_mm"] / baseline["holdout_rms_mm"],
        "rms_ratio": extended["rms_mm"] / baseline["rms_mm"],
        "chi2_per_dof_ratio": extended["chi2_per_dof"] / baseline["chi2_per_dof"],
        "holdout_rms_over_sigma": extended["holdout_rms_mm"] / prob.sigma,
    }
    if kpi:
        gain["kpi_tcp_shift_mm"] = kpi["tcp_shift_mm"]
        gain["kpi_avg_var_ratio"] = kpi["kpi_avg_var_mm2_extended"] / kpi["kpi_avg_var_mm2_baseline"]
    discrepancy = bool(test["rejects"] or causes)
    if test["rejects"] and not causes:
        notes.append(
            "the geometric model does not explain the data but no candidate effect is significant: an "
            "effect outside the candidate list, outliers, or a sigma that is too small"
        )
    if causes and extended["p_value"] < alpha:
        notes.append(
            f"the extended model still does not fit to the noise level (p = {extended['p_value']:.2g}): "
            "more effects or a larger sigma"
        )
    details = {
        "prob": prob,
        "base": base,
        "ext": ext,
        "base_holdout": base_hold,
        "ext_holdout": ext_hold,
        "candidates": cands,
    }
    return DiagnosisReport(
        robot=robot.name,
        n_poses=n,
        sigma_mm=prob.sigma,
        discrepancy=discrepancy,
        test=test,
        causes=causes,
        baseline=baseline,
        extended=extended,
        gain=gain,
        kpi=kpi,
        residual_structure=structure,
        steps=steps,
        notes=notes,
        details=details,
    )


# ----------------------------------------------------------------------------------------------
# Synthetic data (the self-test harness of tests/test_diagnosis.py and studies/diagnosis_rates.py)
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class SyntheticCase:
    """Simulated data with a known truth."""

    data: Measurements
    model_true: TrackerModel
    effects: list
    sigma: float

    @property
    def keys(self) -> set:
        return {e.key for e in self.effects}


def random_poses(robot: Robot, n: int, rng: np.random.Generator, *, cell=None) -> np.ndarray:
    """(n, 6) poses uniform within the joint limits whose capsules clear the floor, the wall and
    the cell's obstacles (:class:`~kpioed_drake.geometry.ClearanceModel`, no beam/incidence check)."""
    from kpioed_drake.geometry import ClearanceModel

    cell = load_cell(robot=robot) if cell is None else cell
    cm = ClearanceModel(robot, cell, collision=True, beam=False)
    out = []
    while sum(len(x) for x in out) < n:
        q = rng.uniform(robot.lower, robot.upper, size=(4 * n, N_JOINTS))
        vals = cm.values(q)
        kinds = np.array(cm.rows.kinds)
        keep = np.all(vals[:, kinds != "self"] >= 0.0, axis=1)
        out.append(q[keep])
    return np.concatenate(out)[:n]


def synthetic_case(
    robot: Robot,
    rng: np.random.Generator,
    effects=(),
    *,
    n_poses: int = 80,
    sigma: float = 0.02,
    seconds_per_pose: float = 20.0,
    payload_kg: float | None = None,
    cell=None,
    q=None,
) -> SyntheticCase:
    """Simulate a measurement campaign with hidden effects (texts or :class:`Effect`).

    True robot: nominal + N(0, 0.5 mm) on the free lengths and N(0, 0.05 deg) on the free angles of
    the joints and the reflector (gauge parameters stay nominal), a tracker frame with a random
    orientation and its origin within +-200 mm of the nominal one. Poses: ``q`` (n, 6) [rad] or
    :func:`random_poses`.
    ``time_s`` = ``seconds_per_pose`` per pose; ``temperature_C`` = 20 C plus a smooth swing of 3-10 K
    amplitude (SPEC: +-10 K) over the run; noise N(0, sigma^2) per coordinate.
    """
    cell = load_cell(robot=robot) if cell is None else cell
    nom = nominal_model(robot, cell)
    lay = nom.layout
    p = nom.p.copy()
    size = np.where(lay.is_angle, np.deg2rad(0.05), 0.5)
    geo = np.array([i for i in lay.free if not 24 <= i < 30])
    p[geo] += size[geo] * rng.standard_normal(geo.size)
    p[24:27] += rng.uniform(-200.0, 200.0, 3)
    from scipy.spatial.transform import Rotation

    R_ref = Rotation.random(random_state=rng).as_matrix()
    truth = dataclasses.replace(nom, p=p, R_WT_ref=R_ref)
    q = random_poses(robot, n_poses, rng, cell=cell) if q is None else np.asarray(q, dtype=float)
    n_poses = q.shape[0]
    t = np.arange(n_poses) * seconds_per_pose
    phase, cycles = rng.uniform(0, 2 * np.pi), rng.uniform(0.5, 1.5)
    temp = 20.0 + rng.uniform(3.0, 10.0) * np.sin(2 * np.pi * cycles * t / max(t[-1], 1.0) + phase)
    effs = [
        fx.parse_effect(e, rng, model=truth) if isinstance(e, str) else fx.resolve(e, truth) for e in effects
    ]
    pay = None if payload_kg is None else np.full(n_poses, float(payload_kg))
    h = fx.true_measurements(truth, q, effs, temperature_C=temp, time_s=t, payload_kg=pay)
    eta = h + sigma * rng.standard_normal(h.shape)
    data = Measurements(q, eta, np.round(temp, 3), t, pay, source="synthetic")
    return SyntheticCase(data, truth, effs, sigma)


def draw_effect_text(rng: np.random.Generator, exclude=(), families=fx.FAMILIES) -> str:
    """A random effect of SPEC's families (family, joint, harmonic uniform), without a value."""
    while True:
        fam = families[rng.integers(len(families))]
        if fam == "joint_elasticity":
            text = f"{fam}:{rng.integers(2, 7)}"
        elif fam == "gear_cyclic":
            text = f"{fam}:{rng.integers(1, 7)}:{rng.integers(1, 3)}"
        else:
            text = fam
        if fx.parse_effect(text).key not in {fx.parse_effect(x).key for x in exclude}:
            return text


def detectability(case: SyntheticCase) -> list[float]:
    """Non-centrality ``|P s|^2 / sigma^2`` of each hidden effect's signal s after projecting out the
    span of the 27 geometric columns (at the truth). Under 'no effect' the likelihood-ratio statistic
    is chi^2(k); with the effect its mean is about ``k + lambda``: below ~25 no test at a corrected
    1 % level finds the effect reliably."""
    prob = FitProblem(case.model_true.robot, case.data, case.sigma)
    idx = np.arange(case.data.n)
    _, H, E = prob.response(case.model_true, case.effects, idx)
    free = case.model_true.layout.free
    Q, _ = np.linalg.qr(H[:, :, free].reshape(-1, free.size))
    out, c = [], 0
    for e in case.effects:
        s = (E[:, :, c : c + e.n_params] @ e.value_array()).reshape(-1)
        c += e.n_params
        s = s - Q @ (Q.T @ s)
        out.append(float(s @ s) / case.sigma**2)
    return out


def kpi_error(case: SyntheticCase, fit: Fit) -> float | None:
    """|TCP(fit) - TCP(truth)| at q_work under KPI conditions (no payload, 20 C) [mm]."""
    qw = case.model_true.robot.q_work
    if qw is None:
        return None
    s_true = kpi_jacobian(case.model_true, qw)[0] + fx.effect_tcp_shift(case.model_true, qw, case.effects)
    s = kpi_jacobian(fit.model, qw)[0] + fx.effect_tcp_shift(fit.model, qw, fit.effects)
    return float(np.linalg.norm(s - s_true))


CASE_KINDS = ("single", "pair", "clean")


def run_synthetic_case(
    kind: str, seed: int, robot="kr16", *, n_poses: int = 80, sigma: float = 0.02, families=fx.FAMILIES
) -> dict:
    """One seeded case of the rate study: draw hidden effects (``single``: one, ``pair``: two
    different ones, ``clean``: none; family, joint and harmonic uniform, sizes in SPEC's ranges),
    simulate, diagnose, compare. Used by ``tests/test_diagnosis.py`` and
    ``studies/diagnosis_rates.py``. ``families`` restricts the draw (e.g. to ``("gear_cyclic",)``)."""
    import time

    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    rng = np.random.default_rng([seed, CASE_KINDS.index(kind) + 1])
    texts = []
    if kind != "clean":
        texts.append(draw_effect_text(rng, families=families))
    if kind == "pair":
        texts.append(draw_effect_text(rng, exclude=texts, families=families))
    case = synthetic_case(robot, rng, texts, n_poses=n_poses, sigma=sigma)
    t0 = time.perf_counter()
    rep = diagnose(robot, case.data, sigma_mm=sigma)
    seconds = time.perf_counter() - t0
    named = rep.cause_keys
    return {
        "kind": kind,
        "seed": seed,
        "truth": [e.text() for e in case.effects],
        "lambda": detectability(case),
        "named": sorted(":".join(str(x) for x in k if x is not None) for k in named),
        "exact": named == case.keys,
        "all_named": case.keys <= named,
        "discrepancy": rep.discrepancy,
        "p_gof": rep.test["p_value"],
        "holdout_base_over_sigma": rep.baseline["holdout_rms_mm"] / sigma,
        "holdout_ext_over_sigma": rep.extended["holdout_rms_mm"] / sigma,
        "chi2_per_dof_ext": rep.extended["chi2_per_dof"],
        "kpi_error_base_mm": kpi_error(case, rep.details["base"]),
        "kpi_error_ext_mm": kpi_error(case, rep.details["ext"]),
        "seconds": seconds,
    }


def reflector_points(model: TrackerModel, q) -> np.ndarray:
    """(n, 3) reflector positions in W [mm] (re-exported for plots)."""
    return reflector_world(model, q)


def calibrate_extended(robot, data, extend, *, sigma_mm: float = 0.02, q_work=None) -> dict:
    """Calibration with a model extension: the 27 geometric parameters and the effects' values.

    What ``kpioed calibrate --extend EFFECT`` runs. No outlier screening (run ``kpioed calibrate``
    without ``--extend`` first to find outliers).

    Args:
        robot: model name, path or :class:`~kpioed_drake.models.Robot`.
        data: measurement CSV path or data (see :func:`as_measurements`).
        extend: effect texts, e.g. ``["joint_elasticity:2"]``.
        q_work: (6,) working pose [rad] (default: the model's).

    Returns:
        JSON-ready report: ``rms_residual_mm``, ``chi2_per_dof``, ``p_value``, ``kpi_mm`` (TCP at
        q_work in W, no payload, reference temperature), ``kpi_cov_mm2``, ``parameters``
        (geometric, with std) and ``extensions`` (effect values with std, display units).
    """
    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    data = as_measurements(data, robot)
    _check(data)
    effs = fx.parse_effects(extend)
    prob = FitProblem(robot, data, sigma_mm)
    fit = prob.fit(effs)
    C = fit.covariance()
    std = np.sqrt(np.diag(C))
    free = fit.model.layout.free
    qw = robot.q_work if q_work is None else np.asarray(q_work, dtype=float)
    s, Js = kpi_jacobian(fit.model, qw)
    s = s + fx.effect_tcp_shift(fit.model, qw, fit.effects)
    Je = np.concatenate([Js[:, free], fx.effect_kpi_columns(fit.model, qw, fit.effects)], axis=1)
    Cs = Je @ C @ Je.T
    dof = 3 * fit.n_used - C.shape[0]
    chi2 = fit.cost
    names = fit.model.layout.names
    params = []
    for k, i in enumerate(free):
        ang = fit.model.layout.is_angle[i]
        f = np.rad2deg(1.0) if ang else 1.0
        params.append(
            {
                "name": names[i],
                "value": float(fit.model.p[i] * f),
                "std": float(std[k] * f),
                "unit": "deg" if ang else "mm",
            }
        )
    exts, c = [], free.size
    for e in fit.effects:
        d = e.to_dict()
        d["std"] = e.display_values(std[c : c + e.n_params])
        if len(d["std"]) == 1:
            d["std"] = d["std"][0]
        exts.append(d)
        c += e.n_params
    return {
        "robot": robot.name,
        "n_poses": int(data.n),
        "sigma_mm": float(sigma_mm),
        "rms_residual_mm": rms(fit.residuals),
        "max_residual_mm": float(np.max(np.linalg.norm(fit.residuals, axis=1))),
        "chi2_per_dof": float(chi2 / dof),
        "p_value": float(scipy.stats.chi2.sf(chi2, dof)),
        "kpi_mm": s.tolist(),
        "kpi_cov_mm2": Cs.tolist(),
        "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
        "parameters": params,
        "extensions": exts,
    }
