"""The study's tables: the results frame, paper Tables 6, 7, 8 (ours beside the paper's numbers), the
per-robot table and the ratios between design methods.

Values are the KPI average variance tr(Cs)/3 [mm^2] (paper eq. 24a on the projection Cs of eq. 25);
the paper's numbers come from :mod:`kpioed_drake.paper`.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from kpioed_drake.paper import TABLE6, TABLE7, TABLE8
from kpioed_drake.study.tasks import KUKA, METHODS, is_notional, notional_lambda_mu

EFFICIENCY_COLUMNS = ["bound_mm2", "heuristic_efficiency", "param_ca_efficiency", "kpi_ca_efficiency"]
"""Per robot: the bound on tr(Cs)/3 of any design with collision avoidance [mm^2] and the mean
efficiency (bound / value) of its heuristic draws and of its param and kpi designs with collision
avoidance."""

RESULT_COLUMNS = [
    "robot",
    "lambda_mm",
    "mu_mm",
    "criterion",
    "collision_avoidance",
    "seed",
    "n",
    "kpi_avg_var_mm2",
    "param_crit",
    "n_colliding_poses",
    "n_infeasible_poses",
    "n_limit_or_incidence_poses",
    "feasible",
    "design_feasible",
    "solve_s",
    "solver",
    "status",
    "success",
    "n_evals",
    "all_rows_retry",
    "q_work_deg",
    "error",
    "variant",
    "bound_mm2",
    "efficiency",
]
"""Columns of ``results.csv`` (``criterion`` holds the design method, ``variant`` the problem
variant of :mod:`.variants`; ``bound_mm2`` the lower bound on tr(Cs)/3 of any design of as many
poses with collision avoidance that covers this design's poses and ``efficiency`` = bound / value,
:mod:`.bounds`; NaN without collision avoidance)."""


def results_frame(rows: list[dict]) -> pd.DataFrame:
    """One row per task (the :func:`~kpioed_drake.study.tasks.run_task` rows without the poses), with
    the notional robots' lambda and mu [mm], in :data:`RESULT_COLUMNS`."""
    df = pd.DataFrame([{k: v for k, v in r.items() if k not in ("q_deg", "traceback")} for r in rows])
    lm = [notional_lambda_mu(r) for r in df["robot"]]
    df["lambda_mm"] = [a for a, _ in lm]
    df["mu_mm"] = [b for _, b in lm]
    for c in RESULT_COLUMNS:
        if c not in df:
            df[c] = None
    return df[RESULT_COLUMNS]


def per_robot(df: pd.DataFrame) -> pd.DataFrame:
    """One row per robot: heuristic (mean, std and count over draws), param/kpi with and without CA,
    the share of colliding poses of the no-CA designs."""
    ok = df[df["error"].isna()]
    out = {}
    for robot, g in ok.groupby("robot", sort=False):
        h = g[g["criterion"] == "heuristic"]["kpi_avg_var_mm2"]
        d = {
            "heuristic": h.mean(),
            "heuristic_std": h.std(ddof=1) if len(h) > 1 else math.nan,
            "heuristic_draws": len(h),
            "bound_mm2": g["bound_mm2"].astype(float).max() if "bound_mm2" in g else math.nan,
            "heuristic_efficiency": _mean_efficiency(g[g["criterion"] == "heuristic"]),
        }
        for method in ("param", "kpi"):
            for ca in (True, False):
                s = g[(g["criterion"] == method) & (g["collision_avoidance"] == ca)]
                key = f"{method}_{'ca' if ca else 'noca'}"
                d[key] = s["kpi_avg_var_mm2"].iloc[0] if len(s) else math.nan
                if not ca:
                    d[f"{key}_colliding_share"] = (
                        s["n_colliding_poses"].iloc[0] / s["n"].iloc[0] if len(s) else math.nan
                    )
                else:
                    d[f"{key}_feasible"] = bool(s["feasible"].iloc[0]) if len(s) else False
                    d[f"{key}_efficiency"] = _mean_efficiency(s)
        d["lambda_mm"], d["mu_mm"] = notional_lambda_mu(robot)
        out[robot] = d
    pr = pd.DataFrame.from_dict(out, orient="index")
    pr.index.name = "robot"
    return pr


def _mean_efficiency(rows: pd.DataFrame) -> float:
    """Mean ``efficiency`` of the rows (NaN without any)."""
    if "efficiency" not in rows or not len(rows):
        return math.nan
    return float(rows["efficiency"].astype(float).mean())


def _paper(v: float | None) -> float:
    return math.nan if v is None else v


def make_tables(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Tables 6, 7, 8 (with the paper's numbers beside ours) and the per-robot table; with the bound
    [mm^2] and the designs' efficiencies (Table 6, per robot: :data:`EFFICIENCY_COLUMNS`; Tables 7
    and 8: ``ca_efficiency_min``, ``_max``, ``_mean`` over the notional robots; NaN without
    bounds)."""
    pr = per_robot(df)
    kuka = [r for r in KUKA if r in pr.index]
    t6 = pr.loc[kuka, ["heuristic", "heuristic_std", "param_ca", "kpi_ca"]].copy()
    for c in ("heuristic", "param_ca", "kpi_ca"):
        t6[f"paper_{c}"] = [TABLE6[r][c] for r in kuka]
    for c in EFFICIENCY_COLUMNS:
        t6[c] = pr.loc[kuka, c]
    t6.index.name = "robot"

    nt = pr[[is_notional(r) for r in pr.index]]
    t7 = {}
    t8 = {}
    for method in METHODS:
        if method == "heuristic":
            noca, ca = pd.Series(dtype=float), nt["heuristic"] if len(nt) else pd.Series(dtype=float)
        else:
            noca, ca = nt[f"{method}_noca"], nt[f"{method}_ca"]
        t7[method] = {"noca_min": noca.min(), "noca_max": noca.max(), "ca_min": ca.min(), "ca_max": ca.max()}
        t8[method] = {"noca_mean": noca.mean(), "ca_mean": ca.mean(), "n_robots": len(ca.dropna())}
        eff = nt[f"{method}_efficiency" if method == "heuristic" else f"{method}_ca_efficiency"]
        t7[method].update(ca_efficiency_min=eff.min(), ca_efficiency_max=eff.max())
        t8[method]["ca_efficiency_mean"] = eff.mean()
        for k, v in TABLE7[method].items():
            t7[method][f"paper_{k}"] = _paper(v)
        for k, v in TABLE8[method].items():
            t8[method][f"paper_{k}"] = _paper(v)
    t7 = pd.DataFrame.from_dict(t7, orient="index")
    t8 = pd.DataFrame.from_dict(t8, orient="index")
    t7.index.name = t8.index.name = "cost"
    return t6, t7, t8, pr


def _ours_and_paper(ratios: dict) -> dict[str, float]:
    """Each ratio ``name: ((row, column), (row, column))``: ours and, as ``paper name``, the paper's
    (the columns with ``paper_``)."""
    out = {}
    for name, ((ra, a), (rb, b)) in ratios.items():
        out[name] = ra[a] / rb[b]
        out[f"paper {name}"] = ra[f"paper_{a}"] / rb[f"paper_{b}"]
    return out


def ratios(t6: pd.DataFrame, t8: pd.DataFrame) -> pd.DataFrame:
    """kpi/heuristic, kpi/param, param/heuristic and ca/noca: ours and the paper's."""
    rows = {}
    for robot, r in t6.iterrows():
        kpi, param, heur = (r, "kpi_ca"), (r, "param_ca"), (r, "heuristic")
        rows[robot] = _ours_and_paper(
            {"kpi/heuristic": (kpi, heur), "kpi/param": (kpi, param), "param/heuristic": (param, heur)}
        )
    if "kpi" in t8.index and np.isfinite(t8.loc["kpi", "ca_mean"]):
        h, p, k = ((t8.loc[c], "ca_mean") for c in ("heuristic", "param", "kpi"))
        rows["notional (means)"] = _ours_and_paper(
            {
                "kpi/heuristic": (k, h),
                "kpi/param": (k, p),
                "param/heuristic": (p, h),
                "kpi ca/noca": (k, (k[0], "noca_mean")),
                "param ca/noca": (p, (p[0], "noca_mean")),
            }
        )
    out = pd.DataFrame.from_dict(rows, orient="index")
    out.index.name = "case"
    return out
