"""Pictures of measurement designs (matplotlib, Agg backend, written as PNG files).

:func:`plot_design_poses` draws each pose of a design as a 3D stick figure of the robot (the link
frame origins joined by lines, ending at the reflector), the car and mount capsules, the laser
tracker, and optionally the working pose ``q_work`` and the lines of sight.

Units: millimetres in W (robot base frame, z up); angles in radians.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from kpioed_drake.outputs import pyplot
from kpioed_drake.robot.kinematics import flange_point, forward_kinematics
from kpioed_drake.robot.models import Cell, Robot

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D


def _capsule_mesh(a: np.ndarray, b: np.ndarray, radius: float, n_around: int = 20, n_cap: int = 6):
    """Surface (X, Y, Z), each (m, n_around + 1), of a capsule with axis a-b [mm]."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, helper)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    phi = np.linspace(0.0, 2.0 * np.pi, n_around + 1)
    # profile along the axis: hemisphere at a, cylinder, hemisphere at b
    th0 = np.linspace(-np.pi / 2, 0.0, n_cap)
    th1 = np.linspace(0.0, np.pi / 2, n_cap)
    t = np.concatenate([radius * np.sin(th0), length + radius * np.sin(th1)])  # along z
    rad = np.concatenate([radius * np.cos(th0), radius * np.cos(th1)])
    ring = np.cos(phi)[None, :, None] * x + np.sin(phi)[None, :, None] * y  # (1, k, 3)
    P = a + t[:, None, None] * z + rad[:, None, None] * ring  # (m, k, 3)
    return P[..., 0], P[..., 1], P[..., 2]


def plot_design_poses(
    robot: Robot,
    cell: Cell,
    q: np.ndarray,
    path: str | Path,
    *,
    q_work: np.ndarray | None = None,
    infeasible: np.ndarray | None = None,
    title: str | None = None,
    show_beams: bool = True,
    elev: float = 25.0,
    azim: float = -60.0,
    dpi: int = 120,
) -> Path:
    """Save a 3D picture of a design's poses in the cell as a PNG file.

    Args:
        robot, cell: the models (the cell as loaded for this robot).
        q: (n, 6) measurement poses [rad].
        path: output PNG file (folders are created).
        q_work: (6,) working pose [rad], drawn in black with its TCP marked (and its capsules);
            several: (K, 6), each drawn as a thinner black line with its TCP.
        infeasible: (n,) bool, poses drawn in red (e.g. those failing the feasibility check).
        title: figure title.
        show_beams: draw the line of sight from each reflector to the tracker.
        elev, azim: view angles [deg].

    Returns:
        the path written.
    """
    plt = pyplot()

    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    bad = np.zeros(n, dtype=bool) if infeasible is None else np.asarray(infeasible, dtype=bool)
    fr = forward_kinematics(robot, q)
    refl = flange_point(fr, cell.p_FQ)  # (n, 3)
    chain = np.concatenate([fr.o, refl[:, None, :]], axis=1)  # (n, 8, 3)

    fig = plt.figure(figsize=(9, 7.5))
    ax = fig.add_subplot(projection="3d")
    cmap = plt.get_cmap("viridis")
    for k in range(n):
        color = "red" if bad[k] else cmap(k / max(n - 1, 1))
        ax.plot(*chain[k].T, color=color, lw=1.0, alpha=0.55)
        if show_beams:
            ax.plot(*np.stack([refl[k], cell.p_WT]).T, color="orange", lw=0.4, alpha=0.25)
    ax.scatter(*refl[~bad].T, s=10, color="tab:blue", depthshade=False, label="reflector (measurement)")
    if bad.any():
        ax.scatter(*refl[bad].T, s=16, color="red", depthshade=False, label="infeasible pose")
    if q_work is not None:
        _draw_working_poses(ax, robot, cell, q_work)
    _draw_cell(ax, cell, chain)
    ax.view_init(elev=elev, azim=azim)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title or f"{robot.name}: {n} measurement poses")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def _draw_working_poses(ax: Axes3D, robot: Robot, cell: Cell, q_work: np.ndarray) -> None:
    """The working pose(s) ``q_work`` [rad] in black with their TCP (one pose: with its capsules)."""
    fw = forward_kinematics(robot, np.atleast_2d(np.asarray(q_work, dtype=float)))
    pw = flange_point(fw, cell.p_FQ)
    cw = np.concatenate([fw.o, pw[:, None, :]], axis=1)
    for i in range(len(cw)):
        label = None if i else "working pose q_work"
        ax.plot(*cw[i].T, color="black", lw=2.5 if len(cw) == 1 else 1.5, label=label)
    ax.scatter(*pw.T, s=40, color="black", marker="x", depthshade=False, label="TCP (KPI)")
    for c in robot.capsules if len(cw) == 1 else ():
        A = fw.o[0, c.frame] + fw.R[0, c.frame] @ c.a
        B = fw.o[0, c.frame] + fw.R[0, c.frame] @ c.b
        ax.plot_surface(*_capsule_mesh(A, B, c.radius, 12, 4), color="gray", alpha=0.08, linewidth=0)


def _draw_cell(ax: Axes3D, cell: Cell, chain: np.ndarray) -> None:
    """The obstacles, the tracker and the floor, and the axes around them and the poses' ``chain``
    (n, 8, 3) [mm]."""
    for ob in cell.obstacles:
        color = "tab:red" if ob.moves_with_car else "tab:brown"
        ax.plot_surface(*_capsule_mesh(ob.a, ob.b, ob.radius), color=color, alpha=0.15, linewidth=0)
    ax.scatter(
        *cell.p_WT, s=120, marker="*", color="orange", edgecolor="k", depthshade=False, label="laser tracker"
    )
    pts = np.concatenate(
        [chain.reshape(-1, 3), cell.p_WT[None, :]]
        + [np.stack([ob.a - ob.radius, ob.b + ob.radius]) for ob in cell.obstacles],
        axis=0,
    )
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    lo[2] = min(lo[2], cell.floor_z)
    # floor outline
    fx, fy = np.meshgrid([lo[0], hi[0]], [lo[1], hi[1]])
    ax.plot_surface(fx, fy, np.full_like(fx, cell.floor_z), color="gray", alpha=0.06, linewidth=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
