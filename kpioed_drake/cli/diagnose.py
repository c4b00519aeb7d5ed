"""``kpioed diagnose``: does the geometric model explain measured data, and if not, what is missing?"""

from __future__ import annotations

from kpioed_drake.cli.common import add_json_out, add_robot, add_sigma, emit_json


def register(sub) -> None:
    p = sub.add_parser(
        "diagnose",
        help="test measured data against the geometric model and name the missing effect",
        description="Geometric calibration, goodness-of-fit test against the known noise, and a stepwise "
        "search over joint_elasticity, gear_cyclic, thermal_expansion and tracker_drift "
        "(docs/diagnosis.md).",
    )
    add_robot(p)
    p.add_argument(
        "data",
        metavar="DATA.csv",
        help="measurements: q1_deg..q6_deg, x_mm, y_mm, z_mm [, temperature_C, time_s, payload_kg]",
    )
    add_sigma(p, default=0.02)
    add_json_out(p)
    p.add_argument("--plots", default=None, metavar="DIR", help="write residual plots (PNG) into DIR")
    p.set_defaults(func=run)


def run(args) -> int:
    from kpioed_drake.diagnosis import diagnose

    report = diagnose(args.robot, args.data, sigma_mm=args.sigma_mm)
    if args.json:
        emit_json(report.to_json(), args.json)
        if args.json == "-":
            return 0
    print(report.summary())
    if args.plots:
        from kpioed_drake.diagnosis_plots import write_plots

        for path in write_plots(report, args.plots):
            print(f"  plot: {path}")
    return 0
