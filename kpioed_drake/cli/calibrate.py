"""``kpioed calibrate``: estimate the robot's parameters from measured laser-tracker data."""

from __future__ import annotations

from kpioed_drake import calibration
from kpioed_drake.cli.common import add_extend, add_json_out, add_q_work, add_robot, emit_json


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
    add_json_out(p)
    p.add_argument("--plots", default=None, metavar="DIR", help="write residual plots (PNG) to DIR")
    p.add_argument(
        "--outlier-alpha",
        type=float,
        default=0.01,
        help="family-wise false-alarm level of the outlier test (Bonferroni); 0 disables (0.01)",
    )
    add_extend(p)
    p.set_defaults(func=run)


def run(args) -> int:
    to_stdout = args.json == "-"
    if args.extend:
        return _run_extended(args, to_stdout)
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


def _run_extended(args, to_stdout: bool) -> int:
    from kpioed_drake.designio import parse_q_work
    from kpioed_drake.diagnosis import calibrate_extended, read_data
    from kpioed_drake.models import load_robot

    if args.out or args.plots:
        from kpioed_drake.errors import InputError

        raise InputError("--out and --plots are not available with --extend (the report holds the fit)")
    robot = load_robot(args.robot)
    q_work = parse_q_work(args.q_work, robot) if args.q_work else None
    d = calibrate_extended(
        robot, read_data(args.data, robot), args.extend, sigma_mm=args.sigma_mm, q_work=q_work
    )
    if args.json:
        emit_json(d, args.json)
        if to_stdout:
            return 0
    print(f"{d['robot']}: {d['n_poses']} poses, geometric model + {', '.join(args.extend)}")
    rms, chi2, pv = d["rms_residual_mm"], d["chi2_per_dof"], d["p_value"]
    print(f"  rms residual {rms:.4f} mm, chi2/dof {chi2:.3f} (p {pv:.3g})")
    for e in d["extensions"]:
        print(f"  {e['effect']} {e.get('joint', '')}: {e['value']} +- {e['std']} {e['unit']}")
    kpi = ", ".join(f"{x:.4f}" for x in d["kpi_mm"])
    print(f"  KPI at q_work: ({kpi}) mm, tr(Cs)/3 = {d['kpi_avg_var_mm2']:.3g} mm^2")
    return 0
