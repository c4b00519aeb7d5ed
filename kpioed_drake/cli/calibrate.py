"""``kpioed calibrate``: estimate the robot's parameters from measured laser-tracker data."""

from __future__ import annotations

from kpioed_drake import calibration
from kpioed_drake.cli.common import add_q_work, add_robot, emit_json


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate from a measurement CSV (q1_deg..q6_deg, x_mm, y_mm, z_mm in the tracker frame)",
    )
    add_robot(p)
    p.add_argument("data", metavar="DATA.csv", help="measurement CSV (SPEC format)")
    p.add_argument("--sigma-mm", type=float, default=0.02, help="noise std. dev. per coordinate [mm] (0.02)")
    add_q_work(p)
    p.add_argument("--out", default=None, metavar="PARAMS.yaml", help="write the calibrated robot model file")
    p.add_argument(
        "--json",
        nargs="?",
        const="-",
        default=None,
        metavar="FILE",
        help="write the report as JSON to FILE (or stdout)",
    )
    p.add_argument("--plots", default=None, metavar="DIR", help="write residual plots (PNG) to DIR")
    p.add_argument(
        "--outlier-alpha",
        type=float,
        default=0.01,
        help="family-wise false-alarm level of the outlier test (Bonferroni); 0 disables (0.01)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    to_stdout = args.json == "-"
    report = calibration.calibrate_file(
        args.robot,
        args.data,
        sigma_mm=args.sigma_mm,
        q_work_deg=args.q_work,
        out=args.out,
        json_path=None if to_stdout else args.json,
        plots_dir=args.plots,
        outlier_threshold=args.outlier_alpha,
    )
    if to_stdout:
        emit_json(report.to_dict(), "-")
        return 0
    print(report.summary())
    if args.out:
        print(f"  calibrated model written to {args.out} (use it as --robot {args.out})")
    return 0
