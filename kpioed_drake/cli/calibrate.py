"""``kpioed calibrate``: estimate the robot's parameters from measured laser-tracker data."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli


def register(sub: argparse._SubParsersAction) -> None:
    help = "calibrate from a measurement CSV (q1_deg, ... per joint, x_mm, y_mm, z_mm: the tracker frame)"
    p = cli.command(sub, "calibrate", help=help, data="optional")
    cli.add_sigma(p, default=0.02)
    use = "for data with orientations whose rows give none (0.01: about a T-Mac's stated accuracy)"
    cli.add_sigma_deg(p, default=0.01, use=use)
    cli.add_q_work(p)
    cli.add_model_out(
        p,
        help="write the calibrated robot model file: YAML, or for a URDF robot NAME.urdf (its sidecar "
        "NAME.kpioed.yaml beside it)",
    )
    cli.add_data_outputs(p, plots_help="write residual plots (PNG) to DIR")
    p.add_argument(
        "--outlier-alpha",
        type=float,
        default=0.01,
        help="family-wise false-alarm level of the outlier test (Bonferroni; at max(sigma, the residuals' "
        "robust scale)); 0 disables (0.01)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse poses that do not determine every parameter (default: hold those at nominal, warn)",
    )
    cli.add_extend(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    same = cli.passed(
        args, "sigma_mm", "sigma_deg", "extend", "outlier_alpha", "out", "strict", "planes", "distances"
    )
    report = api.calibrate(args.robot, args.data, q_work_deg=args.q_work, **same, **cli.data_outputs(args))
    written = ((args.out, "calibrated model (use it as --robot FILE)"), (args.html, "3-D page"))
    return cli.print_result(args, report.to_dict, report.summary, written)
