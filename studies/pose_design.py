"""KPI designs with a 6-DoF probe's pose measurements against designs with points (issue 44).

For each robot: the 40-pose KPI design (position KPI) measured with points and with poses (the
same sigma_mm; the orientation's sigma_deg per tracker axis), and with poses and the TCP's
orientation in the KPI (L = 100 mm). Prints tr(Cs)/3 [mm^2], the TCP's position and orientation
variances [mm^2, deg^2] and the certificate's efficiency; writes studies/results/pose_design.json.

    python studies/pose_design.py [--robots kr16 ur10] [--n 40] [--sigma-mm 0.02] [--sigma-deg 0.005]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from kpioed_drake import api

CASES = (("point", 0.0), ("pose", 0.0), ("pose", 100.0))
"""(measure, kpi_orientation_mm) of each design."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", nargs="+", default=["kr16", "ur10"])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--sigma-mm", type=float, default=0.02)
    ap.add_argument("--sigma-deg", type=float, default=0.005)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "pose_design.json"))
    args = ap.parse_args()
    rows = []
    for robot in args.robots:
        for measure, L in CASES:
            res = api.design(
                robot,
                criterion="kpi",
                n=args.n,
                sigma_mm=args.sigma_mm,
                measure=measure,
                sigma_deg=args.sigma_deg if measure == "pose" else None,
                kpi_orientation_mm=L,
            )
            row = {
                "robot": robot,
                "measure": measure,
                "kpi_orientation_mm": L,
                "n": args.n,
                "kpi_mm2": res.kpi_avg_var_mm2,
                **{
                    k: res.tcp[k] for k in ("position_var_mm2", "orientation_var_deg2", "orientation_rms_deg")
                },
                "bound_mm2": res.certificate["bound_mm2"],
                "efficiency": res.certificate["efficiency"],
                "feasible": res.feasible,
            }
            rows.append(row)
            print(
                f"{robot:5s} {measure:5s} L={L:5.0f} mm: tr(Cs)/3 {row['kpi_mm2']:.4g} mm^2, position "
                f"{row['position_var_mm2']:.4g} mm^2, orientation {row['orientation_var_deg2']:.4g} deg^2 "
                f"({row['orientation_rms_deg']:.3g} deg RMS), efficiency {row['efficiency']:.3f}",
                flush=True,
            )
    Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
