"""Figures of the study (matplotlib, Agg): paper Figure 7 (95 % TCP confidence ellipses, KR 15 /
our kr16, heuristic vs KPI design, from the linearised covariance Cs of eq. 25) and Figure 8
(improvement of the KPI design over the heuristic and over the standard design for the notional
robots, with the paper's Table 8 means marked)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design
from kpioed_drake.outputs import pyplot
from kpioed_drake.paper import TABLE8
from kpioed_drake.study.tasks import Task

CHI2_2D_95 = 5.991  # chi-square quantile, 2 degrees of freedom, 95 %


def ellipse_points(C2: np.ndarray, k2: float = CHI2_2D_95, m: int = 200) -> np.ndarray:
    """Points of the ellipse x^T C2^-1 x = k2 (centre 0).

    Args:
        C2: (2, 2) covariance [mm^2].
        k2: squared radius (default: the 95 % quantile of chi2 with 2 degrees of freedom).
        m: number of points.

    Returns:
        (m, 2) points [mm].
    """
    w, V = np.linalg.eigh(np.asarray(C2, dtype=float))
    t = np.linspace(0.0, 2.0 * np.pi, m)
    circle = np.stack([np.cos(t), np.sin(t)])
    return (V @ (np.sqrt(np.maximum(w, 0.0) * k2)[:, None] * circle)).T


def figure7(out_path: Path, Cs_by_label: dict[str, np.ndarray], robot: str = "kr16") -> Path:
    """95 % confidence ellipses of the TCP in the xy, xz and yz planes (paper Figure 7).

    Args:
        out_path: PNG file to write.
        Cs_by_label: legend label -> Cs: (3, 3) [mm^2], the TCP covariance at q_work.
        robot: name in the title.
    """
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    planes = (("x", "y", 0, 1), ("x", "z", 0, 2), ("y", "z", 1, 2))
    styles = ("-", "--", ":", "-.")
    lim = 0.0
    for k, (label, Cs) in enumerate(Cs_by_label.items()):
        for ax, (_a, _b, i, j) in zip(axes, planes, strict=True):
            P = ellipse_points(Cs[np.ix_([i, j], [i, j])])
            ax.plot(P[:, 0], P[:, 1], styles[k % 4], lw=2, label=label)
            lim = max(lim, float(np.abs(P).max()))
    for ax, (a, b, _, _) in zip(axes, planes, strict=True):
        ax.set_xlabel(f"{a} [mm]")
        ax.set_ylabel(f"{b} [mm]")
        ax.set_title(f"{a}{b} projection")
        ax.set_aspect("equal")
        ax.set_xlim(-1.1 * lim, 1.1 * lim)
        ax.set_ylim(-1.1 * lim, 1.1 * lim)
        ax.grid(True, alpha=0.3)
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
    axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(
        f"Figure 7: 95 % confidence regions of the TCP at q_work, {robot} (linearised, chi2(2) = 5.991)"
    )
    fig.tight_layout()
    fig.savefig(out_path, dpi=120)
    plt.close(fig)
    return out_path


def figure8(out_path: Path, pr: pd.DataFrame) -> Path | None:
    """Improvement [%] of the KPI design (CA) over the heuristic (a) and over the standard design (b)
    per notional robot, on the lambda-mu grid, with the distribution of the improvement below."""
    nt = pr[np.isfinite(pr["lambda_mm"].astype(float))]
    nt = nt[np.isfinite(nt["kpi_ca"]) & np.isfinite(nt["param_ca"]) & np.isfinite(nt["heuristic"])]
    if nt.empty:
        return None
    plt = pyplot()
    imp_h = 100.0 * (1.0 - nt["kpi_ca"] / nt["heuristic"])
    imp_p = 100.0 * (1.0 - nt["kpi_ca"] / nt["param_ca"])
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), gridspec_kw={"height_ratios": [3, 2]})
    lam, mu = nt["lambda_mm"].to_numpy(float), nt["mu_mm"].to_numpy(float)
    annotate = len(nt) <= 30
    paper_h = 100.0 * (1.0 - TABLE8["kpi"]["ca_mean"] / TABLE8["heuristic"]["ca_mean"])
    paper_p = 100.0 * (1.0 - TABLE8["kpi"]["ca_mean"] / TABLE8["param"]["ca_mean"])
    for col, (imp, name, ref) in enumerate(
        ((imp_h, "heuristic", paper_h), (imp_p, "standard (phi_A(Cp)) design", paper_p))
    ):
        ax = axes[0, col]
        sc = ax.scatter(lam, mu, c=imp.to_numpy(float), s=420, marker="s", cmap="viridis", edgecolors="k")
        fig.colorbar(sc, ax=ax, label="improvement [%]")
        if annotate:
            for x, y, v in zip(lam, mu, imp, strict=True):
                ax.annotate(
                    f"{v:.0f}",
                    (x, y),
                    ha="center",
                    va="center",
                    fontsize=7,
                    bbox=dict(boxstyle="round,pad=0.1", fc="w", ec="none", alpha=0.7),
                )
        ax.set_xlabel("lambda (upper arm a2) [mm]")
        ax.set_ylabel("mu (forearm d4) [mm]")
        ax.set_title(f"({'ab'[col]}) KPI design vs {name}")
        ax.set_xlim(lam.min() - 60, lam.max() + 60)
        ax.set_ylim(mu.min() - 60, mu.max() + 60)
        ax2 = axes[1, col]
        ax2.hist(imp, bins=min(20, max(5, len(nt) // 3)), color="C0", edgecolor="k")
        ax2.axvline(float(imp.mean()), color="C3", lw=2, label=f"ours, mean {imp.mean():.0f} %")
        ax2.axvline(ref, color="C1", lw=2, ls="--", label=f"paper (Table 8 means) {ref:.0f} %")
        ax2.set_xlabel(f"improvement of the KPI design over the {name.split(' ')[0]} [%] (higher = better)")
        ax2.set_ylabel("robots")
        ax2.legend(fontsize=8)
    fig.suptitle(
        f"Figure 8: {len(nt)} notional robots, designs with collision avoidance, "
        "improvement = 1 - tr(Cs)_KPI / tr(Cs)_other"
    )
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path


def make_figures(out_dir: Path, df: pd.DataFrame, pr: pd.DataFrame, robot: str = "kr16") -> list[Path]:
    """Write ``figure7_<robot>.png`` (from the stored designs of the first heuristic draw and the KPI
    design with CA) and ``figure8_notional.png``; return the paths written."""
    out_dir = Path(out_dir)
    figs = []
    ok = df[(df["robot"] == robot) & df["error"].isna()]
    heur = ok[ok["criterion"] == "heuristic"].sort_values("seed")
    kpi = ok[(ok["criterion"] == "kpi") & (ok["collision_avoidance"] == True)]  # noqa: E712
    if len(heur) and len(kpi):
        p = make_problem(robot)
        task_h, task_k = Task.from_row(heur.iloc[0]), Task.from_row(kpi.iloc[0])
        qh = read_design(out_dir / "designs" / task_h.design_name, p.robot)
        qk = read_design(out_dir / "designs" / task_k.design_name, p.robot)
        Ch, Ck = p.covariances(qh)[1], p.covariances(qk)[1]
        figs.append(
            figure7(
                out_dir / f"figure7_{robot}.png",
                {
                    f"heuristic (seed {task_h.seed}), tr(Cs)/3 = {np.trace(Ch) / 3:.3f} mm2": Ch,
                    f"phi_A(Cs) design with CA, tr(Cs)/3 = {np.trace(Ck) / 3:.3f} mm2": Ck,
                },
                robot,
            )
        )
    f8 = figure8(out_dir / "figure8_notional.png", pr)
    if f8 is not None:
        figs.append(f8)
    return figs
