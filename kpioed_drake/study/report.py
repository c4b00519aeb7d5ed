"""The study's report: :class:`StudyReport`, what a run of :func:`~kpioed_drake.study.workflow.run_study`
wrote, and ``report.md`` (:func:`make_report`): Tables 6-8 and the ratios beside the paper's numbers,
the share of colliding poses of designs made without collision avoidance (paper section 3.3.2), the
feasibility of the designs made with it, failed tasks and the optimiser's status counts and solve
times.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake.paper import COLLIDING_SHARE_NOCA
from kpioed_drake.study.tables import ratios


@dataclasses.dataclass
class StudyReport:
    """Outputs of :func:`~kpioed_drake.study.workflow.run_study` (all also written to ``out_dir``)."""

    out_dir: Path
    """The study folder."""
    results: pd.DataFrame
    """One row per task (``results.csv``, :data:`~kpioed_drake.study.tables.RESULT_COLUMNS`)."""
    table6: pd.DataFrame
    """Table 6: KUKA robots, ours and the paper's [mm^2]."""
    table7: pd.DataFrame
    """Table 7: min and max over the notional robots [mm^2]."""
    table8: pd.DataFrame
    """Table 8: means over the notional robots [mm^2]."""
    report: str
    """The markdown of ``report.md``."""
    figures: list[Path]
    """The figure files written (Figures 7 and 8 when their data exist)."""
    n_tasks: int
    """Number of tasks of the study."""
    n_run: int
    """Tasks run by this call."""
    n_skipped: int
    """Tasks resumed from their result files."""
    n_errors: int
    """Tasks that recorded an error."""
    wall_s: float
    """Wall time of this call [s]."""


def _fmt(v, f: str = "{:.3f}") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f.format(v)


def _md_table(df: pd.DataFrame, f: str = "{:.3f}") -> str:
    """A markdown table: booleans as words, counts (``n_*``, ``*_draws``) as integers, else ``f``."""
    cols = [str(df.index.name or "")] + [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for idx, r in df.iterrows():
        vals = []
        for col, v in zip(df.columns, r.values, strict=True):
            if isinstance(v, bool | np.bool_):
                vals.append(str(bool(v)))
            elif (
                isinstance(v, int | np.integer)
                or (str(col).startswith("n_") or str(col).endswith("_draws"))
                and isinstance(v, float)
                and np.isfinite(v)
            ):
                vals.append(str(int(v)))
            else:
                vals.append(_fmt(v, f))
        lines.append("| " + " | ".join([str(idx)] + vals) + " |")
    return "\n".join(lines)


def _colliding_section(pr: pd.DataFrame) -> list[str]:
    share = pr[[c for c in pr.columns if c.endswith("_colliding_share")]]
    if not len(share):
        return []
    allv = share.to_numpy(dtype=float).ravel()
    allv = allv[np.isfinite(allv)]
    lines = ["## Colliding poses of designs made without collision avoidance", ""]
    if allv.size:
        lo, hi = COLLIDING_SHARE_NOCA
        lines.append(
            f"Share of the poses that fail the Drake checker's collision or beam test: mean "
            f"{100 * allv.mean():.0f} %, range {100 * allv.min():.0f}-{100 * allv.max():.0f} % over "
            f"{allv.size} designs (paper: {100 * lo:.0f}-{100 * hi:.0f} %)."
        )
    return lines + [
        "",
        _md_table(share.rename(columns=lambda c: c.replace("_colliding_share", "")), "{:.2f}"),
        "",
    ]


def _feasibility_section(df: pd.DataFrame) -> list[str]:
    ca = df[(df["collision_avoidance"] == True) & df["error"].isna()]  # noqa: E712
    bad = ca[~ca["feasible"].astype(bool)]
    failing = ", ".join(
        f"{a} {b} {c} ({d} poses)"
        for a, b, c, d in zip(
            bad["robot"], bad["criterion"], bad["seed"], bad["n_infeasible_poses"], strict=True
        )
    )
    return [
        "## Feasibility of the designs made with collision avoidance",
        "",
        f"{len(ca) - len(bad)} of {len(ca)} designs pass the independent Drake checker at every pose."
        + ("" if bad.empty else " Failing: " + failing),
    ]


def _efficiency_section(pr: pd.DataFrame) -> list[str]:
    """The bound per robot and the designs' efficiencies (bound / value), summarised."""
    if "bound_mm2" not in pr or not np.isfinite(pr["bound_mm2"].astype(float)).any():
        return []
    cols = {"heuristic_efficiency": "heuristic", "param_ca_efficiency": "param", "kpi_ca_efficiency": "kpi"}
    parts = []
    for col, name in cols.items():
        v = pr[col].astype(float).dropna()
        if len(v):
            parts.append(f"{name} median {v.median():.3f} (range {v.min():.3f}-{v.max():.3f})")
    return [
        "## Efficiency (designs with collision avoidance)",
        "",
        "Efficiency = a lower bound on tr(Cs)/3 of any design of as many poses with collision avoidance "
        "(per robot, the optimality certificate's search, `bounds.csv`; lowered where a design's own poses "
        "go beyond the search) / the design's tr(Cs)/3; at most 1 (docs/certificate.md). Conservative: "
        "unlike `kpioed evaluate`, no search continues from the design's poses, so a design that went "
        "beyond the search only lowers its own bound. Over the "
        f"{int(pr['bound_mm2'].notna().sum())} robots: " + "; ".join(parts) + ". Per robot: `per_robot.csv`; "
        "Table 6 and Tables 7-8 (`ca_efficiency_*`) above.",
        "",
    ]


def _failed_section(df: pd.DataFrame) -> list[str]:
    err = df[df["error"].notna()]
    if not len(err):
        return []
    cols = ("robot", "criterion", "collision_avoidance", "seed", "error")
    return ["", "## Failed tasks", ""] + [
        f"- {a} {b} {'ca' if c else 'noca'} seed {d}: {e}"
        for a, b, c, d, e in zip(*(err[k] for k in cols), strict=True)
    ]


def _optimiser_section(df: pd.DataFrame) -> list[str]:
    st = df[df["criterion"] != "heuristic"]
    if not len(st):
        return []
    return [
        "",
        "## Optimiser",
        "",
        "Status counts: "
        + ", ".join(f"{k}: {v}" for k, v in st["status"].value_counts().items())
        + f". Solve time per design: median {st['solve_s'].median():.1f} s, "
        f"max {st['solve_s'].max():.1f} s.",
    ]


def make_report(
    df: pd.DataFrame,
    t6: pd.DataFrame,
    t7: pd.DataFrame,
    t8: pd.DataFrame,
    pr: pd.DataFrame,
    *,
    wall_s: float | None = None,
    title: str = "Study",
) -> str:
    """The markdown report of a study.

    Args:
        df: the results frame (:func:`~kpioed_drake.study.tables.results_frame`).
        t6, t7, t8, pr: Tables 6, 7, 8 and the per-robot table (:func:`~.tables.make_tables`).
        wall_s: wall time of the run [s], reported if given.
        title: first words of the heading.
    """
    lines = [f"# {title}: KPI-based OED, paper Tables 6-8", ""]
    n_rob = df["robot"].nunique()
    lines.append(
        f"{n_rob} robots, {len(df)} designs ({int(df['error'].notna().sum())} failed). Values: average KPI "
        "variance tr(Cs)/3 [mm^2], noise 1 mm per coordinate. `paper_*`: Jost, Kudruss, Körkel and "
        "Walter 2017 (kpioed_drake.study.PAPER). Heuristic: mean over the seeded draws (feasible poses only)."
    )
    if wall_s is not None:
        lines.append(f"Wall time of this run: {wall_s:.0f} s.")
    lines += ["", "## Table 6: KUKA robots (with collision avoidance)", "", _md_table(t6), ""]
    lines += ["## Table 7: notional robots, min and max", "", _md_table(t7), ""]
    lines += ["## Table 8: notional robots, mean", "", _md_table(t8), ""]
    lines += ["## Ratios (ours next to the paper's)", "", _md_table(ratios(t6, t8)), ""]
    lines += _efficiency_section(pr)
    lines += _colliding_section(pr)
    lines += _feasibility_section(df)
    lines += _failed_section(df)
    lines += _optimiser_section(df)
    lines.append("")
    return "\n".join(lines)
