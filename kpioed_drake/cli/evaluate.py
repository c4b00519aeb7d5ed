"""``kpioed evaluate``: KPI variance, standard criterion and feasibility of a design file."""

from __future__ import annotations

from kpioed_drake import api
from kpioed_drake.cli.common import add_extend, add_json_out, add_q_work, add_robot, add_sigma, emit_json


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="evaluate a design CSV (q1_deg..q6_deg)")
    add_robot(p)
    p.add_argument("--design", required=True, help="design CSV with columns q1_deg..q6_deg")
    add_sigma(p)
    add_q_work(p)
    add_extend(p)
    add_json_out(p)
    p.set_defaults(func=run)


def run(args) -> int:
    d = api.evaluate(
        args.robot, args.design, sigma_mm=args.sigma_mm, q_work_deg=args.q_work, extend=args.extend
    )
    if args.json:
        emit_json(d, args.json)
        if args.json == "-":
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
    return 0
