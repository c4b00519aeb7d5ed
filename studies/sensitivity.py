"""The sensitivity study of docs/studies.md ("Why our numbers differ from the paper's").

For each problem variant (kpioed_drake.study.variants.SENSITIVITY_VARIANTS) and the three KUKA
robots: 10 heuristic draws, phi_A(Cp) and phi_A(Cs) designs with collision avoidance, 60 poses.
Every finished task is written at once and atomically to OUT/run/tasks/ (a new run resumes); after
each variant the table is rewritten (OUT/sensitivity.csv, OUT/sensitivity.md, atomically).

    .venv/bin/python studies/sensitivity.py [--out studies/sensitivity] [--variants a,b] [--jobs 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from kpioed_drake.outputs import atomic_write_text
from kpioed_drake.study import run_tasks
from kpioed_drake.study.sensitivity import sensitivity_markdown, sensitivity_table, sensitivity_tasks
from kpioed_drake.study.variants import SENSITIVITY_VARIANTS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).parent / "sensitivity"))
    ap.add_argument(
        "--variants", default=",".join(SENSITIVITY_VARIANTS), help="comma-separated variant names"
    )
    ap.add_argument("--heuristic-draws", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    out = Path(args.out)
    rows = []
    for name in [v.strip() for v in args.variants.split(",") if v.strip()]:
        t0 = time.perf_counter()
        tasks = sensitivity_tasks(name, heuristic_draws=args.heuristic_draws)
        done, n_run, n_skip = run_tasks(tasks, out / "run", jobs=args.jobs, progress=False)
        rows += done
        table = sensitivity_table(rows)
        atomic_write_text(out / "sensitivity.csv", table.to_csv(index=False, float_format="%.6g"))
        atomic_write_text(out / "sensitivity.md", sensitivity_markdown(table))
        print(f"{name}: {n_run} run, {n_skip} resumed, {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
