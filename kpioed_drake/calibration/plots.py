"""Residual plots of a calibration (matplotlib, Agg backend).

- ``residuals_per_pose.png``: x, y, z residuals (in W, mm) against the file row, with the +-3 sigma
  band and the removed outliers marked;
- ``residuals_vs_joints.png``: residual components against each joint angle (deg), which shows
  effects that depend on one joint (gear errors, elasticity);
- ``validation_errors.png`` (:func:`plot_validation`): a validation's 3-D error per row and their
  histogram.

Residuals are ``measured - model`` rotated from the tracker frame into W (``R_WT r``), so that z is
up and the components mean the same for every tracker orientation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.outputs import pyplot
from kpioed_drake.robot.jointmap import q_to_file


def _figure(*args, **kwargs):
    """``pyplot`` (:func:`~kpioed_drake.outputs.pyplot`) and a new figure with axes."""
    plt = pyplot()
    return plt, plt.subplots(*args, **kwargs)


def plot_calibration(report: CalibrationReport, outdir: str | Path) -> list[Path]:
    """Write the residual plots of a :class:`~kpioed_drake.calibration.CalibrationReport`.

    Returns:
        the written files.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    res = report.result
    r_W = res.residuals @ report.model.R_WT.T  # (n, 3) in W
    rows = np.asarray(report.data.rows)
    used = res.mask
    sigma = res.sigma
    q_deg = q_to_file(report.robot, report.data.q)  # deg (prismatic joints: mm)
    nj = q_deg.shape[1]
    labels = ("x", "y", "z")
    colors = ("tab:red", "tab:green", "tab:blue")
    files = []

    plt, (fig, axes) = _figure(3, 1, figsize=(9, 7), sharex=True)
    for k, ax in enumerate(axes):
        ax.axhspan(-3 * sigma, 3 * sigma, color="0.9", label="+-3 sigma")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.plot(rows[used], r_W[used, k], "o", ms=3.5, color=colors[k], label="used")
        if np.any(~used):
            ax.plot(rows[~used], r_W[~used, k], "x", ms=8, mew=2, color="k", label="outlier (removed)")
        ax.set_ylabel(f"{labels[k]} residual [mm]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("file row (header = 1)")
    title = f"{report.robot.name}: residuals in W, RMS {report.rms_residual_mm:.4f} mm" + (
        f", chi2/dof {report.chi2_per_dof:.2f}" if report.chi2_per_dof is not None else ""
    )
    fig.suptitle(title)
    fig.tight_layout()
    path = outdir / "residuals_per_pose.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    files.append(path)

    ncol = -(-nj // 2)
    plt, (fig, axes) = _figure(2, ncol, figsize=(13 * ncol / 3, 7), sharey=True)
    for ax in axes.ravel()[nj:]:
        ax.set_visible(False)
    for j, ax in enumerate(axes.ravel()[:nj]):
        for k in range(3):
            ax.plot(q_deg[used, j], r_W[used, k], "o", ms=3, color=colors[k], alpha=0.8, label=labels[k])
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel(f"q{j + 1} [{'mm' if report.robot.prismatic[j] else 'deg'}]")
        ax.grid(alpha=0.3)
        if j % ncol == 0:
            ax.set_ylabel("residual [mm]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{report.robot.name}: residuals (used poses, in W) against the joint angles")
    fig.tight_layout()
    path = outdir / "residuals_vs_joints.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    files.append(path)
    return files


def plot_validation(errors_mm: np.ndarray, rows: np.ndarray, title: str, folder: Path) -> list[Path]:
    """``validation_errors.png``: the 3-D errors ``errors_mm`` (n,) [mm] per file row ``rows`` (n,)
    and their histogram, under ``title``."""
    plt, (fig, (ax1, ax2)) = _figure(1, 2, figsize=(10, 3.6))
    e = np.asarray(errors_mm, dtype=float)
    ax1.plot(rows, e, ".", ms=4)
    ax1.axhline(np.mean(e), color="k", lw=0.8, label=f"mean {np.mean(e):.3f} mm")
    ax1.set(xlabel="row in the data file", ylabel="3-D error [mm]", title=title)
    ax1.legend()
    ax2.hist(e, bins=min(30, max(5, len(e) // 5)))
    ax2.set(xlabel="3-D error [mm]", ylabel="rows")
    fig.tight_layout()
    path = Path(folder) / "validation_errors.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
