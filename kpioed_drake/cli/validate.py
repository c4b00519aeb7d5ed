"""``kpioed validate``: how well does a (calibrated) model predict fresh measurements?"""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(
        sub,
        "validate",
        help="predict fresh measurements with a model (nothing fitted; tracker kept or cross-registered)",
        data="optional",
    )
    cli.add_format(p)
    p.add_argument(
        "--tracker-frame",
        choices=("kept", "cross", "in-sample"),
        default=None,
        help="kept: the model's tracker frame (default for a calibrated model file); cross: the tracker "
        "moved (another session): registered on one half of the poses, scored on the other, both ways "
        "(default for a model without an estimated tracker pose); in-sample: registered on the poses "
        "scored (optimistic)",
    )
    p.add_argument("--keep-tracker", action="store_true", help="the same as --tracker-frame kept")
    p.add_argument(
        "--force", action="store_true", help="go on with implausible data (a warning instead of a refusal)"
    )
    cli.add_json_out(p)
    cli.add_optional(p, "--plots", metavar="DIR", help="write the error plot (PNG) to DIR")
    cli.add_html(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    outputs = {"json_path": cli.json_file(args.json), "plots_dir": args.plots, "data_format": args.format}
    keep = args.keep_tracker or None
    result = api.validate(
        args.robot,
        args.data,
        keep_tracker=keep,
        **cli.passed(args, "tracker_frame", "force", "planes", "distances", "html"),
        **outputs,
    )
    return cli.print_result(args, result.to_dict, result.summary, ((args.html, "3-D page"),))
