"""Pictures of a diagnosis (matplotlib, Agg backend): residuals against the variables that reveal causes.

- :func:`plot_residual_structure`: the geometric model's residuals projected on each candidate's
  signature, against the candidate's variable: per joint the *apparent joint-angle error*
  ``a = g . r / |g|^2`` (``g = dh/dq_i``, the direction a joint-angle error moves the reflector)
  against ``q_i`` and against the gravity torque ``tau_i``; the *apparent scale error*
  ``u . r / |u|^2`` (``u`` = the reflector position) against the temperature; the residual in W
  against time; and the residual norms against the noise.
- :func:`plot_before_after`: for each named cause, the same projection before (geometric model) and
  after (extended model), against the variable that revealed the cause, with the fitted effect.
- :func:`write_plots`: both into a folder; returns the paths.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.report import DiagnosisReport
from kpioed_drake.outputs import pyplot
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.kinematics import subtree_links
from kpioed_drake.tracker.measurement import reflector_world

_BEFORE, _AFTER, _FIT = "tab:orange", "tab:blue", "black"


def _save(plt, fig, path) -> Path:
    """Write ``fig`` to ``path`` (folders created) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _signatures(prob, fit):
    """Per pose: joint directions g (n, 6, 3) [mm/rad], scale direction u (n, 3) [mm], R_TW."""
    idx = np.arange(prob.data.n)
    _, H, _ = prob.response(fit.model, fit.effects, idx)
    g = H[:, :, fit.model.layout.joint_angles].transpose(0, 2, 1)  # dh/dtheta_j = dh/dq_j
    u = reflector_world(fit.model, prob.data.q, prob.data.target) @ fit.model.R_WT
    return g, u, fit.model.R_WT.T


def _apparent(r: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(n,) least-squares coefficient of r_k on g_k per pose."""
    return np.einsum("ni,ni->n", r, g) / np.maximum(np.einsum("ni,ni->n", g, g), 1e-300)


def _score_title(report, name: str) -> str:
    for s in report.residual_structure:
        if s["candidate"] == name:
            return f"score {s['score']:.0f} (p {s['p_value']:.1g})"
    return ""


def _labels(ax, title: str, xlabel: str, ylabel: str) -> None:
    """A panel's title (the pictures' size) and axis labels."""
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)


def _no_data(ax, text: str) -> None:
    """A panel without data: ``text`` in its middle, no axes."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_axis_off()


def _joint_panels(grid, report: DiagnosisReport, prob, r, g, cols: int) -> None:
    """Per joint j, in row pair ``j // cols``: the apparent joint-angle error against q_j and
    against its gravity torque (or why there is none: no masses in the file, or a vertical axis)."""
    d, nj = prob.data, prob.data.q.shape[1]
    size = np.max(np.abs(prob.tau), axis=0)
    loaded = size > 1e-9 * max(1.0, float(np.max(size)))  # as the candidates: gravity loads the joint
    massless = [not np.any(prob.robot.masses[subtree_links(prob.robot, j + 1)] > 0) for j in range(nj)]
    for j in range(nj):
        a = np.rad2deg(_apparent(r, g[:, j]))
        axes = grid[2 * (j // cols) :]
        ax = axes[0, j % cols]
        ax.scatter(q_to_file(prob.robot, d.q)[:, j], a, s=8, color=_BEFORE)
        best = min((_score_title(report, f"gear_cyclic:{j + 1}:{n}"), n) for n in (1, 2))[0]
        ax.set_title(f"joint {j + 1} vs q{j + 1}\n{best}", fontsize=9)
        ax.set_xlabel(f"q{j + 1} [{'mm' if prob.robot.prismatic[j] else 'deg'}]")
        ax.axhline(0, color="0.7", lw=0.8)
        ax = axes[1, j % cols]
        if not loaded[j]:
            why = "no link masses in the file" if massless[j] else "vertical axis,\nno gravity torque"
            _no_data(ax, f"joint {j + 1}: {why}")
        else:
            ax.scatter(prob.tau[:, j], a, s=8, color=_BEFORE)
            ax.set_title(
                f"joint {j + 1} vs gravity torque\n{_score_title(report, f'joint_elasticity:{j + 1}')}",
                fontsize=9,
            )
            ax.set_xlabel(f"tau{j + 1} [N m]")
            ax.axhline(0, color="0.7", lw=0.8)


def plot_residual_structure(report: DiagnosisReport, path: Path | str) -> Path:
    """Baseline residuals against every candidate variable: per joint its angle and its gravity
    torque (six joints a row pair, 3 x 6 panels for six joints), then the conditions."""
    plt = pyplot()
    prob, base = report.details["prob"], report.details["base"]
    d = prob.data
    r = base.residuals
    g, u, R_TW = _signatures(prob, base)
    nj = d.q.shape[1]
    cols, blocks = max(4, min(nj, 6)), -(-nj // 6)
    fig, grid = plt.subplots(
        2 * blocks + 1, cols, figsize=(20 * cols / 6, 10 * (2 * blocks + 1) / 3), constrained_layout=True
    )
    for ax in grid[-3:-1, nj - cols * (blocks - 1) :].ravel():  # the last row pair's empty panels
        ax.set_axis_off()
    _joint_panels(grid, report, prob, r, g, cols)
    for ax in grid[:-1, 0]:
        ax.set_ylabel("apparent joint-angle error [deg]")
    axes = grid[-3:]
    ax = axes[2, 0]
    if d.temperature_C is not None:
        ax.scatter(d.temperature_C, 1e6 * _apparent(r, u), s=8, color=_BEFORE)
        title = f"scale vs temperature\n{_score_title(report, 'thermal_expansion')}"
        _labels(ax, title, "temperature [C]", "apparent scale error [ppm]")
    else:
        _no_data(ax, "no temperature_C")
    ax = axes[2, 1]
    if d.time_s is not None:
        rW = r @ R_TW
        for c, lab in enumerate("xyz"):
            ax.plot(d.time_s / 60.0, rW[:, c], ".", ms=3, label=f"{lab} (W)")
        ax.legend(fontsize=7)
        _labels(
            ax, f"residual vs time\n{_score_title(report, 'tracker_drift')}", "time [min]", "residual [mm]"
        )
    else:
        _no_data(ax, "no time_s")
    _norm_hist(axes[2, 2], report, which=("base",))
    ax = axes[2, 3]
    top = report.residual_structure[:8]
    ax.barh([s["candidate"] for s in top][::-1], [s["score"] for s in top][::-1], color=_BEFORE)
    ax.set_xscale("log")
    ax.set_title("largest score statistics", fontsize=9)
    ax.set_xlabel("score (chi2, dof = parameters)")
    for ax in axes[2, 4:]:
        ax.set_axis_off()
    t = report.test
    fig.suptitle(
        f"{report.robot}: residuals of the geometric model (chi2/dof {t['chi2_per_dof']:.2f}, "
        f"p = {t['p_value']:.2g}, sigma {report.sigma_mm:g} mm)"
    )
    return _save(plt, fig, path)


def _norm_hist(ax, report, which=("base", "ext")):
    prob = report.details["prob"]
    x = np.linspace(0, 5, 200)
    for w, col, lab in (("base", _BEFORE, "geometric model"), ("ext", _AFTER, "extended model")):
        if w not in which:
            continue
        fit = report.details[w]
        nr = np.linalg.norm(fit.residuals, axis=1) / prob.sigma
        ax.hist(
            nr,
            bins=30,
            range=(0, max(5.0, float(np.percentile(nr, 99)))),
            density=True,
            alpha=0.5,
            color=col,
            label=lab,
        )
    ax.plot(x, scipy.stats.chi.pdf(x, 3), color=_FIT, lw=1, label="noise only (chi, 3 dof)")
    ax.set_xlabel("|residual| / sigma per pose")
    ax.set_title("residual norms", fontsize=9)
    ax.legend(fontsize=7)


def _cause_view(prob, fit, effect, residual, g, u, R_TW, partial: bool):
    """x, y (n,) and the fitted curve (x, y) for one effect; y in display units."""
    d = prob.data
    i = next(k for k, e in enumerate(fit.effects) if e.name == effect.name)
    sig = prob.effect_signal(fit, i)  # (n,3)
    r = residual + sig if partial else residual
    if effect.family in fx.JOINT_FAMILIES:
        j = effect.joint - 1
        y = np.rad2deg(_apparent(r, g[:, j]))
        ys = np.rad2deg(_apparent(sig, g[:, j]))
        if effect.family in ("joint_elasticity", "backlash", "joint_elasticity_basis"):
            x, xl = prob.tau[:, j], f"gravity torque tau{j + 1} [N m]"
        else:
            jx = effect.coupled - 1 if effect.coupled is not None else j
            unit = "mm" if prob.robot.prismatic[jx] else "deg"
            x, xl = q_to_file(prob.robot, d.q)[:, jx], f"q{jx + 1} [{unit}]"
        return x, y, ys, xl, "apparent joint-angle error [deg]"
    if effect.family in ("thermal_expansion", "tracker_scale"):
        w = u if effect.family == "thermal_expansion" else d.eta  # scaled about the base / the tracker
        return (
            d.temperature_C,
            1e6 * _apparent(r, w),
            1e6 * _apparent(sig, w),
            "temperature [C]",
            "apparent scale error [ppm]",
        )
    if effect.family in fx.ROTATION_FAMILIES:  # a bend under the weight: along its own displacement
        size = np.linalg.norm(sig, axis=1)
        along = sig / np.maximum(size, 1e-300)[:, None]
        x, xl = size, f"fitted {effect.name} displacement at the reflector [mm]"
        return x, np.sum(r * along, axis=1), size, xl, "residual along that displacement [mm]"
    v = fit.effects[i].value_array()
    vdir = v / max(np.linalg.norm(v), 1e-300)
    y = (r @ R_TW) @ vdir  # residual in W along the drift direction
    ys = (sig @ R_TW) @ vdir
    return d.time_s / 60.0, y, ys, "time [min]", "residual along the drift direction [mm]"


def plot_before_after(report: DiagnosisReport, path: Path | str) -> Path:
    """Residuals before and after the extension against the variable that revealed each cause."""
    plt = pyplot()
    prob, base, ext = report.details["prob"], report.details["base"], report.details["ext"]
    causes = ext.effects
    rows = max(len(causes), 1)
    fig, axes = plt.subplots(rows, 3, figsize=(15, 3.8 * rows), constrained_layout=True, squeeze=False)
    g_b, u_b, R_b = _signatures(prob, base)
    g_e, u_e, R_e = _signatures(prob, ext)
    if not causes:
        axes[0, 0].text(
            0.5,
            0.5,
            "no cause named:\nthe geometric model is kept",
            ha="center",
            va="center",
            transform=axes[0, 0].transAxes,
        )
        axes[0, 0].set_axis_off()
        axes[0, 1].set_axis_off()
    for k, e in enumerate(causes):
        x, y, _, xl, yl = _cause_view(prob, ext, e, base.residuals, g_b, u_b, R_b, partial=False)
        ax = axes[k, 0]
        ax.scatter(x, y, s=9, color=_BEFORE)
        ax.axhline(0, color="0.7", lw=0.8)
        _labels(ax, f"before: geometric model, projected on {e.name}", xl, yl)
        x, yp, ys, _, _ = _cause_view(prob, ext, e, ext.residuals, g_e, u_e, R_e, partial=True)
        _, ya, _, _, _ = _cause_view(prob, ext, e, ext.residuals, g_e, u_e, R_e, partial=False)
        ax = axes[k, 1]
        ax.scatter(x, yp, s=9, color="tab:gray", alpha=0.6, label="extended residual + fitted effect")
        o = np.argsort(x)
        ax.plot(
            x[o],
            ys[o],
            ".-" if e.family == "gear_cyclic" else "-",
            color=_FIT,
            lw=1.2,
            ms=3,
            label=f"fitted {e.name}",
        )
        ax.scatter(x, ya, s=9, color=_AFTER, label="after: extended model residual")
        ax.axhline(0, color="0.7", lw=0.8)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.legend(fontsize=7)
        cause = next((c for c in report.causes if c["name"] == e.name), None)
        ttl = f"after: {e.name}"
        if cause:
            v = cause["value"]
            vs = ", ".join(f"{a:.3g}" for a in v) if isinstance(v, list) else f"{v:.3g}"
            ttl += f" = {vs} {cause['unit']}"
        ax.set_title(ttl, fontsize=9)
        axes[k, 2].set_axis_off()
    _norm_hist(axes[0, 2], report)
    axes[0, 2].set_axis_on()
    b, x_ = report.baseline, report.extended
    fig.suptitle(
        f"{report.robot}: held-out RMS {b['holdout_rms_mm']:.4f} -> {x_['holdout_rms_mm']:.4f} mm, "
        f"chi2/dof {b['chi2_per_dof']:.2f} -> {x_['chi2_per_dof']:.2f} (sigma {report.sigma_mm:g} mm)"
    )
    return _save(plt, fig, path)


def write_plots(report: DiagnosisReport, folder: Path | str) -> list[Path]:
    """``residual_structure.png`` and ``before_after.png`` in ``folder``."""
    folder = Path(folder)
    return [
        plot_residual_structure(report, folder / "residual_structure.png"),
        plot_before_after(report, folder / "before_after.png"),
    ]
