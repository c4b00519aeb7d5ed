"""``kpioed diagnose``: does the geometric model explain measured data, and if not, what is missing?"""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli

DESCRIPTION = (
    "Geometric calibration, goodness-of-fit test against the known noise, and a stepwise search over "
    "joint_elasticity, gear_cyclic, joint_scale, joint_coupling, backlash, thermal_expansion, "
    "tracker_scale and tracker_drift; each cause with its competing explanations and plausibility, and "
    "the structure of what stays unexplained (docs/diagnosis.md)."
)
"""The command's description in its ``--help``."""


def register(sub: argparse._SubParsersAction) -> None:
    help = "test measured data against the geometric model and name the missing effect"
    p = cli.command(sub, "diagnose", help=help, description=DESCRIPTION, data="required")
    cli.add_sigma(p)  # None: measured on repeated poses or checked against the residuals
    cli.add_model_out(
        p,
        help="write the extended model of the named causes (the geometric one if none is named): YAML, or "
        "for a URDF robot NAME.urdf with its sidecar",
    )
    cli.add_data_outputs(p, plots_help="write residual plots (PNG) into DIR")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    report = api.diagnose(
        args.robot, args.data, **cli.passed(args, "sigma_mm", "out"), **cli.data_outputs(args)
    )
    written = (
        (args.out, "extended model (use it as --robot FILE)"),
        (args.plots, "plots"),
        (args.html, "3-D page"),
    )
    return cli.print_result(args, report.to_json, report.summary, written)
