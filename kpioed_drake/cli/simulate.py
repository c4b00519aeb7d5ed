"""``kpioed simulate``: simulated laser-tracker measurements of a design (a robot with random errors)."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli
from kpioed_drake.files.designs import OFFSET_COLUMNS


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(
        sub, "simulate", help="simulate measurements of a design CSV (writes the measurement CSV layout)"
    )
    p.add_argument("--design", required=True, help=cli.DESIGN_HELP)
    cli.add_sigma(p, default=0.02)
    cli.add_seed(p, of="the geometric errors, the tracker frame and the noise")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="SPEC",
        help="non-geometric effect, e.g. joint_elasticity:2, gear_cyclic:4:2=0.01,-0.005, thermal_expansion, "
        "tracker_drift, joint_scale:2=500, joint_coupling:5:4, tracker_scale, backlash:3, "
        "column_compliance:1 (a lift), base_compliance, lateral_compliance:2 (repeatable)",
    )
    p.add_argument("--payload-kg", type=float, default=0.0, help="payload at the reflector [kg] (0)")
    p.add_argument("--no-geometric-errors", action="store_true", help="the true robot is the nominal one")
    cli.add_optional(
        p,
        "--targets",
        type=int,
        metavar="N",
        help="targets (SMRs) measured at every pose: the first N of the model file's targets_mm "
        "(default: all); one row per pose and target, with a target column",
    )
    cli.add_optional(
        p,
        "--orientation-sigma-deg",
        type=float,
        metavar="S",
        help="also simulate a 6-DoF probe's orientations (columns qw, qx, qy, qz: the unit quaternion, "
        "scalar first, of the probe frame in the tracker frame) with noise S [deg] about each tracker "
        "axis (0: noise free); the truth's probe orientation on the flange is the model file's "
        "probe_rpy_deg, else random",
    )
    p.add_argument("--out", required=True, metavar="DATA.csv", help="measurement CSV to write")
    p.add_argument(
        "--truth", default=None, metavar="FILE.json", help="also write the true parameters as JSON"
    )
    p.set_defaults(func=run, api_names={"n_targets": "targets", "truth_path": "truth"})


def run(args: argparse.Namespace) -> int:
    table, truth = api.simulate(
        args.robot,
        args.design,
        args.out,
        sigma_mm=args.sigma_mm,
        seed=args.seed,
        effects=args.effect,
        geometric_errors=not args.no_geometric_errors,
        payload_kg=args.payload_kg,
        truth_path=args.truth,
        n_targets=args.targets,
        orientation_sigma_deg=args.orientation_sigma_deg,
    )
    eff = ", ".join(e.text() if hasattr(e, "text") else str(e) for e in truth["effects"]) or "none"
    print(
        f"{truth['robot']}: simulated {len(table)} "
        + ("poses" if truth["n_targets"] == 1 else f"rows ({truth['n_targets']} targets per pose)")
        + f", sigma {truth['sigma_mm']:g} mm, "
        f"seed {truth['seed']}, "
        f"geometric errors {'on' if truth['geometric_errors'] else 'off'}, effects: {eff}"
    )
    if truth.get("condition_offsets"):
        cols = " and ".join(OFFSET_COLUMNS[c] for c in truth["condition_offsets"])
        print(f"  measurement plan: the design's {cols} added to the simulated conditions")
    p = truth["p_WT_mm"]
    print(f"  true tracker position in W: ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) mm (random orientation)")
    print(f"  written to {args.out}" + (f"; truth to {args.truth}" if args.truth else ""))
    return 0
