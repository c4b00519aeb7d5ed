"""Benchmark of the optimality certificate and the approximate-design start (issue 14, items 1-2).

For each robot (default: kr16, kr300, kr500 and the six notional robots of the quick study, among
them notional-850-800; default cell, q_work from the model file, sigma 1 mm, 60 poses, collision
avoidance) and each seed:

- the KPI design from the heuristic start (``optimize_design(start="heuristic")``): tr(Cs)/3, time;
- the KPI design from the approximate start (``optimize_design(start="approximate")``, the
  package's default for the KPI criterion: the cheaper column generation of ``approximate_start``,
  efficient rounding, the exchange pass, then SNOPT): tr(Cs)/3 and the time of all steps;
- the certificate (``certified_design``, computed once per robot, seed 0): the lower bound on
  tr(Cs)/3 of any 60-pose design, bound/N, and each design's efficiency = bound / value
  (``certify``, whose bound also covers the design's own poses).

Medians over the seeds; wall times depend on the load of the (shared) machine, so CPU time of this
process is given beside them. The certificate's search runs here without the disk cache
(``KPIOED_CACHE=off``), so its time is measured. Writes Markdown to ``bench/bound_results.md`` (and stdout).

Runs as the second step of ``make bench`` (about 4-6 min on 2 cores).

Usage: ``python bench/bound_bench.py [--robots kr16,kr300] [--seeds 3] [--out bench/bound_results.md]``
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ["KPIOED_CACHE"] = "off"  # measure the certificate's search, not a cache read

from kpioed_drake.design import DEFAULT_START, certified_design, certify, optimize_design  # noqa: E402
from kpioed_drake.estimation.problem import make_problem  # noqa: E402
from kpioed_drake.outputs import atomic_write_text  # noqa: E402
from kpioed_drake.study.tasks import KUKA, QUICK_NOTIONAL  # noqa: E402

N_POSES = 60


def _timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def bench_robot(robot: str, seeds: list[int]) -> dict:
    """Designs, times and the certificate of one robot."""
    problem = make_problem(robot, sigma_mm=1.0)
    cert, cert_wall, cert_cpu = _timed(lambda: certified_design(problem, seed=0))
    rows = []
    for seed in seeds:
        default, d_wall, d_cpu = _timed(
            lambda s=seed: optimize_design(problem, n=N_POSES, seed=s, start="heuristic")
        )
        started, a_wall, a_cpu = _timed(
            lambda s=seed: optimize_design(problem, n=N_POSES, seed=s, start="approximate")
        )
        rows.append(
            {
                "seed": seed,
                "default": default.kpi_avg_var_mm2,
                "default_cert": certify(problem, default.q, approx=cert),
                "default_wall": d_wall,
                "default_cpu": d_cpu,
                "default_ok": default.feasible and default.success,
                "approx_s": started.start_s,
                "started": started.kpi_avg_var_mm2,
                "started_cert": certify(problem, started.q, approx=cert),
                "started_wall": a_wall,
                "started_cpu": a_cpu,
                "started_ok": started.feasible and started.success,
            }
        )
    return {
        "robot": robot,
        "bound": cert.bound / N_POSES,
        "approx_best": cert.phi / N_POSES,
        "gap": 1.0 - cert.bound / cert.phi,
        "cert_rounds": cert.rounds,
        "cert_converged": cert.converged,
        "cert_candidates": len(cert.q) + cert.n_checked,
        "cert_searches": cert.n_searched,
        "cert_wall": cert_wall,
        "cert_cpu": cert_cpu,
        "rows": rows,
    }


def _med(rows, key):
    return statistics.median(r[key] for r in rows)


def _eff(rows, key):
    return statistics.median(x[key]["efficiency"] for x in rows)


def _targets(results: list[dict]) -> list[str]:
    """The issue's targets, checked on this run."""
    eff_ok, lines = True, []
    for r in results:
        need = 0.93 if r["robot"].startswith("notional") else 0.95
        eff = _eff(r["rows"], "started_cert")
        eff_ok &= eff >= need
        lines.append(f"{r['robot']} {eff:.3f} (target {need:.2f})")
    all_rows = [x for r in results for x in r["rows"]]
    dw, aw = _med(all_rows, "default_wall"), _med(all_rows, "started_wall")
    dc, ac = _med(all_rows, "default_cpu"), _med(all_rows, "started_cpu")
    return [
        "## Targets (issue 14, item 2)",
        "",
        f"- Median efficiency of the approximate start + SNOPT: {'; '.join(lines)}: "
        f"{'met' if eff_ok else 'NOT met'}.",
        f"- Median time per design over all robots and seeds: heuristic start {dw:.2f} s wall "
        f"({dc:.2f} s CPU), approximate start {aw:.2f} s wall ({ac:.2f} s CPU): ratio {aw / dw:.2f} wall, "
        f"{ac / dc:.2f} CPU (target <= 2): {'met' if aw <= 2 * dw else 'NOT met'}.",
        f"- The package's default start for the KPI criterion: {DEFAULT_START}.",
        "",
    ]


def report(results: list[dict], seeds: list[int], load: tuple, started_at: str) -> str:
    """The Markdown tables."""
    lines = [
        "# Certificate and approximate-design start (bench/bound_bench.py)",
        "",
        f"Run {started_at} UTC on a 2-core machine shared with other jobs (other helpers may have been "
        f"running; load average at start {load[0]:.2f}, at end {os.getloadavg()[0]:.2f}); {N_POSES} poses, "
        f"sigma 1 mm, collision avoidance, seeds {','.join(map(str, seeds))}; medians over the seeds. "
        "Wall times are inflated by the load; CPU time of this process beside them. One run.",
        "",
        "## Bound, designs and times per design",
        "",
        "bound/N: the certificate's search bound (``certified_design``, the same for every design); "
        "efficiency = the design's certified bound / value (``certify``: at most the search bound, raised "
        "by refinements with poses found near the design, lowered if it reached poses beyond the search). "
        "Times: wall (CPU) per design [s]; the approximate start's includes its column generation and "
        "rounding (column 'of which start').",
        "",
        "| robot | bound/N [mm^2] | heuristic start: value (eff.) | approximate start: value (eff.) "
        "| time heuristic start | time approximate start | of which start | ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        rows = r["rows"]
        dw, aw = _med(rows, "default_wall"), _med(rows, "started_wall")
        eff_d = _eff(rows, "default_cert")
        lines.append(
            f"| {r['robot']} | {r['bound']:.4f} | {_med(rows, 'default'):.4f} ({eff_d:.2f}) "
            f"| {_med(rows, 'started'):.4f} ({_eff(rows, 'started_cert'):.2f}) "
            f"| {dw:.2f} ({_med(rows, 'default_cpu'):.2f}) | {aw:.2f} ({_med(rows, 'started_cpu'):.2f}) "
            f"| {_med(rows, 'approx_s'):.2f} | {aw / dw:.2f} |"
        )
    lines += ["", *_targets(results)]
    lines += [
        "## Certificate (once per robot, seed 0)",
        "",
        "| robot | search bound/N | approx. design Phi/N | gap | wall (CPU) [s] | rounds | poses evaluated "
        "| local searches | converged | all designs feasible |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ok = all(x["default_ok"] and x["started_ok"] for x in r["rows"])
        lines.append(
            f"| {r['robot']} | {r['bound']:.4f} | {r['approx_best']:.4f} | {100 * r['gap']:.1f} % "
            f"| {r['cert_wall']:.1f} ({r['cert_cpu']:.1f}) | {r['cert_rounds']} | {r['cert_candidates']} "
            f"| {r['cert_searches']} | {r['cert_converged']} | {ok} |"
        )
    lines += [
        "",
        "## Per seed",
        "",
        "Column 'beyond': max g near the design's own poses over the search's maximum after 'ref.' "
        "refinements (> 1: the design reached feasible poses the search had missed, and its bound is "
        "lowered by that factor).",
        "",
        "| robot | seed | heuristic start | bound/N | eff. | beyond | ref. | approximate start | bound/N "
        "| eff. | beyond | ref. |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        for x in r["rows"]:
            d, a = x["default_cert"], x["started_cert"]
            cells = [r["robot"], x["seed"]]
            for value, c in ((x["default"], d), (x["started"], a)):
                cells += [f"{value:.4f}", f"{c['bound_mm2']:.4f}", f"{c['efficiency']:.3f}"]
                cells += [f"{c['design_beyond_search']:.3f}", c["refinements"]]
            lines.append("| " + " | ".join(map(str, cells)) + " |")
    lines += [
        "",
        "The bound is rigorous for designs whose poses are among those evaluated (candidates, fresh "
        "random and joint-limit poses, local maxima, and for a certified design its own poses and "
        "their local maxima); over the continuous feasible set it is as good as that search "
        "(docs/certificate.md).",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default=",".join(KUKA + QUICK_NOTIONAL))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", default=str(Path(__file__).with_name("bound_results.md")))
    args = ap.parse_args()
    started_at = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
    load = os.getloadavg()
    seeds = list(range(args.seeds))
    results = []
    for robot in args.robots.split(","):
        results.append(bench_robot(robot, seeds))
        print(report(results, seeds, load, started_at), flush=True)
    atomic_write_text(args.out, report(results, seeds, load, started_at))


if __name__ == "__main__":
    main()
