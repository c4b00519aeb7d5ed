"""``kpioed next``: online calibration, calibrate on the data so far and either stop or give the
next poses to measure."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(
        sub,
        "next",
        help="online calibration: calibrate on the data so far; stop at the target TCP variance or "
        "write the next poses to measure",
        data="required",
        data_help=f"the measurements so far; {cli.DATA_HELP}",
    )
    p.add_argument(
        "--target-var", type=float, required=True, metavar="V", help="TCP precision to reach: tr(Cs)/3 [mm^2]"
    )
    p.add_argument("--n", type=int, default=5, help="poses to design when not done, at most --max-plan (5)")
    cli.add_sigma(p, default=0.02)
    cli.add_seed(p, of="the design's starts and the certificate")
    p.add_argument("--no-certify", dest="certify", action="store_false", help="skip the certificate")
    p.add_argument(
        "--max-plan", type=int, default=60, metavar="H", help="most poses planned ahead to the target (60)"
    )
    cli.add_optional(p, "--out", metavar="NEXT.csv", help="the next poses (not written when done)")
    plan = "the plan carried from step to step: read if it exists, then replaced (removed when done)"
    cli.add_optional(p, "--plan", metavar="PLAN.csv", help=plan)
    cli.add_json_out(p)
    cli.add_format(p)
    cli.add_force(p)
    _add_orientation(p)
    p.set_defaults(func=run)


def _add_orientation(p: argparse.ArgumentParser) -> None:
    """``--sigma-deg``, ``--kpi-orientation-mm``, ``--target-deg``: data with a probe's orientations."""
    use = "where the data's rows give none (0.01); the next poses are designed as pose measurements"
    cli.add_sigma_deg(p, default=0.01, use=use)
    cli.add_kpi_orientation(p, default=0.0, use="data with orientations")
    cli.add_optional(
        p,
        "--target-deg",
        type=float,
        metavar="D",
        help="data with orientations: also reach the TCP orientation's precision D [deg, RMS per axis]: "
        "done when position variance / target-var + (orientation / D)^2 <= 1 (not with --kpi-orientation-mm)",
    )


def run(args: argparse.Namespace) -> int:
    same = cli.passed(args, "n", "sigma_mm", "seed", "certify", "max_plan", "out", "plan", "force")
    same |= cli.passed(args, "sigma_deg", "kpi_orientation_mm", "target_deg")
    result = api.next(
        args.robot,
        args.data,
        target_var_mm2=args.target_var,
        json_path=cli.json_file(args.json),
        data_format=args.format,
        **same,
    )
    written = ((None if result["done"] else args.out, "next poses"),)
    return cli.print_result(args, lambda: result, lambda: result["summary"], written)
