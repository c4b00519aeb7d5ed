"""``kpioed design``: optimum experimental design (paper eq. 24) or the heuristic design.

Exit status: 0 success; 2 bad input; 3 the solver failed or the design is infeasible (nothing is
written to ``--out``; ``--json`` still records the failure). ``--allow-infeasible`` writes the
design anyway and exits 0 with a warning.
"""

from __future__ import annotations

import sys

from kpioed_drake.cli.common import add_extend, add_q_work, add_robot, add_sigma

EXIT_DESIGN_FAILED = 3


def register(sub) -> None:
    from kpioed_drake.design import DESIGN_CRITERIA, SOLVERS

    p = sub.add_parser(
        "design",
        help="compute measurement poses (KPI, standard, D, O1 optimal or heuristic)",
        description="Compute a design of measurement poses and write it as a CSV (q1_deg..q6_deg).",
    )
    add_robot(p)
    p.add_argument(
        "--criterion",
        required=True,
        choices=DESIGN_CRITERIA,
        help="kpi = tr(Cs)/3 (paper), param = scaled tr(Cp) (standard), d, o1, heuristic = random feasible",
    )
    p.add_argument("--n", type=int, default=60, help="number of poses (default 60)")
    p.add_argument("--no-collision", action="store_true", help="no collision or laser-beam constraints")
    p.add_argument("--solver", choices=SOLVERS, default="snopt", help="NLP solver (default snopt)")
    p.add_argument("--seed", type=int, default=0, help="seed of the heuristic start (default 0)")
    p.add_argument("--starts", type=int, default=1, help="number of starts, the best is kept (default 1)")
    add_sigma(p)
    add_q_work(p)
    p.add_argument("--out", required=True, metavar="FILE", help="design CSV to write")
    p.add_argument("--json", default=None, metavar="FILE", help="JSON record of the run")
    p.add_argument("--allow-infeasible", action="store_true", help="write the design even if it fails")
    p.add_argument("--plot", default=None, metavar="FILE.png", help="PNG picture of the poses")
    add_extend(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from kpioed_drake.design import DesignError, format_summary, run_design

    try:
        res = run_design(
            args.robot,
            criterion=args.criterion,
            n=args.n,
            collision=not args.no_collision,
            solver=args.solver,
            seed=args.seed,
            starts=args.starts,
            sigma_mm=args.sigma_mm,
            q_work_deg=args.q_work,
            out=args.out,
            json_path=args.json,
            allow_infeasible=args.allow_infeasible,
            plot=args.plot,
            extend=args.extend,
        )
    except DesignError as exc:
        if exc.result is not None:
            print(format_summary(exc.result), file=sys.stderr)
        print(f"kpioed: design failed: {exc}", file=sys.stderr)
        return EXIT_DESIGN_FAILED
    print(format_summary(res))
    if not (res.success and res.feasible):
        print(
            "kpioed: warning: the design failed or is infeasible (written because of --allow-infeasible)",
            file=sys.stderr,
        )
    written = [str(x) for x in (args.out, args.json, args.plot) if x]
    print(f"  wrote {', '.join(written)}")
    return 0
