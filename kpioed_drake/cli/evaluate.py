"""``kpioed evaluate``: KPI variance, standard criterion and feasibility of a design file; with
its optimality certificate (:func:`kpioed_drake.design.certify`; ``--no-certify``: none)."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli
from kpioed_drake.design import certificate_line


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(sub, "evaluate", help="evaluate a design CSV (a column per joint: q1_deg, ...)")
    p.add_argument("--design", required=True, help=cli.DESIGN_HELP)
    p.add_argument(
        "--certify",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the optimality certificate: a lower bound on tr(Cs)/3 of any feasible design of as many poses "
        "(collision avoidance) and the design's efficiency (bound/value), on by default; 4-13 s once per "
        "robot and setup (then cached on disk, $KPIOED_CACHE or ~/.cache/kpioed) and 1-4 s per design",
    )
    cli.add_sigma(p)
    cli.add_q_work(p)
    cli.add_extend(p)
    cli.add_json_out(p)
    cli.add_html(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    options = dict(sigma_mm=args.sigma_mm, q_work_deg=args.q_work, extend=args.extend, html=args.html)
    d = api.evaluate(
        args.robot, args.design, json_path=cli.json_file(args.json), certify=args.certify, **options
    )
    if args.json == "-":
        cli.print_json(d)
        return 0
    s = d["feasibility"]
    print(f"{d['robot']}: {d['n_poses']} poses, {d['n_params']} parameters, sigma {d['sigma_mm']} mm")
    print(f"  KPI average variance tr(Cs)/3 = {d['kpi_avg_var_mm2']:.4g} mm^2")
    print(f"  standard criterion tr(P^T Cp P) = {d['param_crit']:.4g} mm^2")
    print(
        f"  feasible: {d['feasible']} ({s['n_infeasible']} infeasible poses: "
        f"{s['n_joint_limit']} joint limit, {s['n_incidence']} incidence, "
        f"{s['n_collision']} collision, {s['n_beam']} beam)"
    )
    if args.certify and d["certificate"] is not None:  # none with several targets
        print(f"  {certificate_line(d['certificate'])}")
    return 0
