"""The KPI design of plane touches against heuristic touches (kr16, four planes; issue 44).

The 40-touch design of :func:`kpioed_drake.design.contact.design.plane_design` (pool 1000, 48
searches a round, at most 40 rounds, 2000 fresh touches verified, seed 0) with its certificate,
against heuristic designs of 10 feasible touches per plane (10 seeds). Prints tr(Cs)/3 [mm^2], the
bound and the efficiency; writes studies/results/plane_design.json.

    python studies/plane_design.py [--n 40] [--sigma-mm 0.01]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kpioed_drake.design.contact.design import plane_design
from kpioed_drake.design.contact.poses import plane_poses
from kpioed_drake.design.contact.problem import make_plane_problem

NORMALS = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0], [1, 1, 1]]) / np.array([[1], [1], [1], [3**0.5]])
"""A table, two walls and a tilted plate (docs/contacts.md), normals towards the free side."""
OFFSETS = np.array([400.0, -900.0, -700.0, 1300.0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--sigma-mm", type=float, default=0.01)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "plane_design.json"))
    args = ap.parse_args()
    problem = make_plane_problem("kr16", NORMALS, OFFSETS, sigma_mm=args.sigma_mm)
    des = plane_design(problem, args.n, pool=1000, starts=48, rounds=40, verify=2000, seed=0)
    per_plane = args.n // len(OFFSETS)
    heuristic = []
    for s in range(10):
        q = [
            plane_poses(problem, NORMALS[k : k + 1], OFFSETS[k : k + 1], n=per_plane, seed=100 + 10 * s + k)[
                0
            ]
            for k in range(len(OFFSETS))
        ]
        heuristic.append(problem.criteria(np.concatenate(q))["kpi_avg_var_mm2"])
    h = np.array(heuristic)
    out = {
        "n": args.n,
        "sigma_mm": args.sigma_mm,
        "design_kpi_mm2": des.value,
        "bound_mm2": des.bound,
        "efficiency": des.efficiency,
        "touches_per_plane": np.bincount(des.plane, minlength=len(OFFSETS)).tolist(),
        "g_max": des.g_max,
        "rounds": des.rounds,
        "converged": des.converged,
        "heuristic_kpi_mm2": h.tolist(),
    }
    print(
        f"design {des.value:.3e} mm^2, bound {des.bound:.3e}, efficiency {des.efficiency:.3f}, "
        f"touches per plane {out['touches_per_plane']}; heuristic median {np.median(h):.3e}, "
        f"best {h.min():.3e}, worst {h.max():.3e}"
    )
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
