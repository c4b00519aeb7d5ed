"""``kpioed compensate``: joint values with which a calibrated model is where the nominal one promised."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli
from kpioed_drake.compensation.workflow import ANGLES


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(
        sub,
        "compensate",
        help="compensate a program (nominal joint values) or reach target points with a calibrated model",
    )
    cli.add_optional(p, "--program", metavar="P.csv", help="nominal joint values (q1_deg, ...)")
    cli.add_optional(p, "--targets", metavar="T.csv", help="points in W (x_mm, y_mm, z_mm)")
    p.add_argument("--out", required=True, metavar="Q.csv", help="compensated joint values to write")
    nominal = "the controller's nominal model (default: the name before '-calibrated' of --robot)"
    cli.add_optional(p, "--nominal", metavar="ROBOT", help=nominal)
    p.add_argument("--target", type=int, default=1, metavar="K", help="target (1-based) to compensate")
    p.add_argument(
        "--angles",
        choices=ANGLES,
        default="model",
        help="the joint columns hold model angles or controller angles (through the joint_map)",
    )
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="EFFECT=VALUE",
        help="an estimated effect with its value, e.g. joint_elasticity:2=7.7e-7 (repeatable)",
    )
    p.add_argument(
        "--allow-unreachable",
        action="store_true",
        help="write rows that cannot be reached (reachable=0) instead of failing",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    names = ("program", "targets", "out", "nominal", "target", "angles", "allow_unreachable")
    report = api.compensate(args.robot, effects=args.effect, **cli.passed(args, *names))
    print(report.summary())
    return 0
