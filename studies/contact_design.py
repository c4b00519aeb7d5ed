"""The KPI designs of contact systems against heuristic designs (plane touches, a pivot ballbar).

For one robot and system, the design of ``kpioed design --measure plane|ballbar`` (its defaults: the
robot's default planes, models/planes/ROBOT.yaml, or the pivot at the working TCP with a 150 mm bar;
sigma 0.01 mm; the search of :data:`kpioed_drake.design.contact.workflow.SEARCH`, seed 0) with its
certificate, against 10 heuristic designs of as many random feasible poses (seeds 100..109; planes:
an equal share per plane). Prints tr(Cs)/3 [mm^2], the bound, the efficiency and the heuristics'
median, best and worst; writes studies/results/contact_design-SYSTEM-ROBOT.json and the design CSV.

    python studies/contact_design.py --system plane --robot kr16 [--n 40] [--rounds 40]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from kpioed_drake.design.contact.poses import contact_poses
from kpioed_drake.design.contact.problem import ContactProblem
from kpioed_drake.design.contact.workflow import contact_design_file

RESULTS = Path(__file__).parent / "results"


def heuristic(problem: ContactProblem, n: int, seed: int) -> float:
    """tr(Cs)/3 [mm^2] of ``n`` random feasible poses (planes: n / K on each, the draws of each plane
    seeded ``seed + k``)."""
    S = problem.surfaces
    if S.kind == "plane":
        q = [contact_poses(problem, S.subset([k]), n=n // len(S), seed=seed + k)[0] for k in range(len(S))]
        q = np.concatenate(q)
    else:
        q = contact_poses(problem, S, n=n, seed=seed)[0]
    return float(problem.criteria(q)["kpi_avg_var_mm2"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--system", choices=("plane", "ballbar"), required=True)
    ap.add_argument("--robot", default="kr16")
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument(
        "--rounds",
        type=int,
        default=None,
        help="most column-generation rounds (default: the command's, 40 for planes, 120 for a ballbar)",
    )
    args = ap.parse_args()
    stem = RESULTS / f"contact_design-{args.system}-{args.robot}"
    t0 = time.perf_counter()
    rep = contact_design_file(
        args.robot, args.system, n=args.n, rounds=args.rounds, out=stem.with_suffix(".csv")
    )
    seconds = time.perf_counter() - t0
    des, problem = rep.design, rep.problem
    # the plane study's seeds (100 + 10 s + k per plane); the ballbar's 100 + s
    h = np.array(
        [heuristic(problem, args.n, 100 + (10 if args.system == "plane" else 1) * s) for s in range(10)]
    )
    out = {
        **{k: v for k, v in rep.record().items() if k != "poses"},
        "design_seconds": seconds,
        "poses_per_surface": np.bincount(des.surface, minlength=len(problem.surfaces)).tolist(),
        "min_clearance_mm": float(rep.clearance.min()),
        "heuristic_kpi_mm2": h.tolist(),
        "heuristic_median_mm2": float(np.median(h)),
    }
    print(
        f"{args.robot} {args.system}: design {des.value:.3e} mm^2, bound {des.bound:.3e}, efficiency "
        f"{des.efficiency:.3f}, poses per {problem.surfaces.kind} {out['poses_per_surface']}, "
        f"{seconds:.0f} s; "
        f"heuristic median {np.median(h):.3e}, best {h.min():.3e}, worst {h.max():.3e}"
    )
    stem.with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
