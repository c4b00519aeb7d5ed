"""The unexplained rest: what the extended model's residuals still follow when they exceed the noise.

When the goodness-of-fit test of the extended model rejects (``chi2 ~ chi2(dof)`` against the known
sigma, p < alpha), the residuals hold an error outside the candidate library. Its structure: the
residuals in W (n, 3) are regressed, coordinate by coordinate, on each variable of the data:

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

import numpy as np
import scipy.stats

from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.tracker.measurement import reflector_world

MAX_FOLLOWS = 6
"""Most variables listed in ``follows``."""


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


def unexplained_rest(prob: FitProblem, fit: Fit, *, alpha: float) -> dict | None:
    """None when ``fit`` explains the data to the noise level, else the rest and what it follows.

    Returns:
        ``{chi2_per_dof, p_value, alpha, excess_rms_mm, follows: [{variable, strength, p_value}],
        variables: [all of them]}`` or None.
    """
    p = float(scipy.stats.chi2.sf(fit.cost, fit.dof))
    if p >= alpha:
        return None
    allv = structure(prob, fit)
    return {
        "chi2_per_dof": fit.chi2_per_dof,
        "p_value": p,
        "alpha": alpha,
        "excess_rms_mm": prob.sigma * float(np.sqrt(max(fit.chi2_per_dof - 1.0, 0.0))),
        "follows": [x for x in allv if x["p_value"] < alpha][:MAX_FOLLOWS],
        "variables": allv,
    }
