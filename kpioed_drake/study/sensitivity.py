"""The sensitivity study: paper Table 6 (three KUKA robots, 60 poses, collision avoidance) under each
problem variant of :mod:`.variants`, and the KPI design's gains beside the paper's.

Per variant and robot: heuristic designs (a few seeded draws), the standard design phi_A(Cp) and the
KPI design phi_A(Cs) (paper eq. 24a with the projections of eq. 25), each with collision avoidance,
evaluated as tr(Cs)/3 [mm^2]. The gains are the paper's "improvement of the TCP precision" (section
4.1): ``1 - kpi / heuristic`` and ``1 - kpi / param``.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from kpioed_drake.paper import TABLE6
from kpioed_drake.study.tables import results_frame
from kpioed_drake.study.tasks import KUKA, Task, make_tasks
from kpioed_drake.study.variants import get_variant

SENSITIVITY_COLUMNS = [
    "variant",
    "robot",
    "heuristic",
    "heuristic_std",
    "param",
    "kpi",
    "gain_vs_heuristic",
    "gain_vs_param",
    "paper_heuristic",
    "paper_param",
    "paper_kpi",
    "paper_gain_vs_heuristic",
    "paper_gain_vs_param",
    "n_infeasible_designs",
]
"""Columns of the sensitivity table (values tr(Cs)/3 [mm^2], gains as fractions)."""


def sensitivity_tasks(
    variant: str, *, robots: Iterable[str] = KUKA, heuristic_draws: int = 3, n: int = 60, seed: int = 0
) -> list[Task]:
    """The tasks of one variant: kpi and param designs with collision avoidance and the heuristic
    draws, per robot.

    Raises:
        InputError: an unknown variant.
    """
    name = get_variant(variant).name
    return make_tasks(robots, n=n, heuristic_draws=heuristic_draws, seed=seed, variant=name, no_ca=False)


def _gain(better: float, other: float) -> float:
    return 1.0 - better / other


def sensitivity_table(rows: list[dict]) -> pd.DataFrame:
    """One row per variant and robot (in the order of ``rows``): the mean of the heuristic draws and
    its standard deviation, the param and kpi designs, the gains, the paper's Table 6 numbers and the
    number of designs that fail the independent checker or recorded an error."""
    df = results_frame(rows)
    out = []
    for (variant, robot), g in df.groupby(["variant", "robot"], sort=False):
        heur = g[g["criterion"] == "heuristic"]["kpi_avg_var_mm2"].astype(float)
        by = {
            c: float(g[g["criterion"] == c]["kpi_avg_var_mm2"].astype(float).mean()) for c in ("param", "kpi")
        }
        paper = TABLE6.get(robot, {})
        ph, pp, pk = (paper.get(k, float("nan")) for k in ("heuristic", "param_ca", "kpi_ca"))
        out.append(
            {
                "variant": variant,
                "robot": robot,
                "heuristic": float(heur.mean()),
                "heuristic_std": float(heur.std(ddof=1)) if len(heur) > 1 else float("nan"),
                "param": by["param"],
                "kpi": by["kpi"],
                "gain_vs_heuristic": _gain(by["kpi"], float(heur.mean())),
                "gain_vs_param": _gain(by["kpi"], by["param"]),
                "paper_heuristic": ph,
                "paper_param": pp,
                "paper_kpi": pk,
                "paper_gain_vs_heuristic": _gain(pk, ph),
                "paper_gain_vs_param": _gain(pk, pp),
                "n_infeasible_designs": int((~g["feasible"].astype(bool) | g["error"].notna()).sum()),
            }
        )
    return pd.DataFrame(out, columns=SENSITIVITY_COLUMNS)


def _gains(r) -> str:
    """``ours % [paper's %]`` of both gains of a table row, as two markdown cells."""
    return " | ".join(
        f"{100 * r[f'gain_vs_{k}']:.0f} % [{100 * r[f'paper_gain_vs_{k}']:.0f} %]"
        for k in ("heuristic", "param")
    )


def sensitivity_markdown(table: pd.DataFrame) -> str:
    """The sensitivity table as markdown: values [mm^2] and gains [%], the paper's in brackets."""
    lines = [
        "| variant | robot | heuristic (std) | phi_A(Cp) | phi_A(Cs) | gain vs heuristic | gain vs param "
        "| failing designs |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        lines.append(
            f"| {r['variant']} | {r['robot']} | {r['heuristic']:.3f} ({r['heuristic_std']:.3f}) "
            f"[{r['paper_heuristic']:.2f}] | {r['param']:.3f} [{r['paper_param']:.2f}] "
            f"| {r['kpi']:.3f} [{r['paper_kpi']:.2f}] "
            f"| {_gains(r)} | {r['n_infeasible_designs']} |"
        )
    summary = sensitivity_summary(table)
    lines += [
        "",
        "| variant | gain vs heuristic | gain vs param | gap [pp] | scale (ours / paper) |",
        "|---|---|---|---|---|",
    ]
    for _, r in summary.iterrows():
        lines.append(f"| {r['variant']} | {_gains(r)} | {r['gap_pp']:.1f} | {r['scale']:.2f} |")
    return "\n".join(lines) + "\n"


def sensitivity_summary(table: pd.DataFrame) -> pd.DataFrame:
    """One row per variant (in table order): the gains averaged over the robots beside the paper's,
    ``gap_pp``, the mean absolute difference of the two gains from the paper's [percentage points],
    and ``scale``, the geometric mean of our values over the paper's (heuristic, param, kpi; 1 =
    the paper's absolute level)."""
    out = []
    for variant, g in table.groupby("variant", sort=False):
        gaps = [g[f"gain_vs_{k}"] - g[f"paper_gain_vs_{k}"] for k in ("heuristic", "param")]
        ratios = [g[k] / g[f"paper_{k}"] for k in ("heuristic", "param", "kpi")]
        out.append(
            {
                "variant": variant,
                "gain_vs_heuristic": float(g["gain_vs_heuristic"].mean()),
                "paper_gain_vs_heuristic": float(g["paper_gain_vs_heuristic"].mean()),
                "gain_vs_param": float(g["gain_vs_param"].mean()),
                "paper_gain_vs_param": float(g["paper_gain_vs_param"].mean()),
                "gap_pp": float(100 * np.mean(np.abs(np.concatenate(gaps)))),
                "scale": float(np.exp(np.mean(np.log(np.concatenate(ratios))))),
            }
        )
    return pd.DataFrame(out)
