"""``kpioed design``: optimum experimental design (paper eq. 24) or the heuristic design.

Exit status: 0 success; 2 bad input; 3 the solver failed or the design is infeasible (nothing is
written to ``--out``; ``--json`` still records the failure). ``--allow-infeasible`` writes the
design anyway and exits 0 with a warning.

Several KPIs (paper, Outlook): ``--q-work`` repeated, or ``--q-work-file`` (a CSV of working poses,
e.g. a working path sampled at K points), with ``--kpi-weights`` and ``--kpi-aggregate mean|max``.
Sequential re-identification (paper 3.1): ``--given D.csv`` adds ``--n`` new poses to poses
already measured. Fewest poses for a precision (paper, Conclusion): ``--target-var V``.
``--start`` picks the KPI optimisation's start (default: the rounded approximate design); the
optimality certificate (a lower bound on tr(Cs)/3 of any design of as many poses, and the design's
efficiency) is in the summary and the JSON record unless ``--no-certify``.
"""

from __future__ import annotations

import argparse
import sys

from kpioed_drake import api, cli
from kpioed_drake.design import DesignError, discrimination_lines, format_summary
from kpioed_drake.design.contact.workflow import CONTACT_PROBLEMS, contact_design_file
from kpioed_drake.design.discriminate.plan import payload_lines, plan_lines
from kpioed_drake.design.settings import DEFAULT_START, DESIGN_METHODS, SOLVERS, START_METHODS
from kpioed_drake.errors import EXIT_SOLVER, InputError, name_fields
from kpioed_drake.estimation.criteria import TABLE
from kpioed_drake.tracker.kpi import KPI_AGGREGATES, MEASURES, SIGMA_ROT_DEG


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(
        sub,
        "design",
        help="compute measurement poses (KPI, standard, D, O1 optimal or heuristic)",
        description="Compute a design of measurement poses and write it as a CSV (a column per joint: "
        "q1_deg, q2_deg, ...).",
    )
    _add_solve_options(p)
    cli.add_sigma(p)
    _add_measure_options(p)
    _add_kpi_options(p)
    p.add_argument(
        "--given",
        default=None,
        metavar="D.csv",
        help="design CSV of poses already measured: their information is held fixed and --n new poses "
        "are optimised (--out gets the new poses; the values are those of the combined design)",
    )
    cli.add_optional(
        p,
        "--target-var",
        type=float,
        metavar="V",
        help="find the fewest poses whose design reaches tr(Cs)/3 <= V [mm^2] (warm-started search; "
        "--n is not used)",
    )
    p.add_argument("--out", required=True, metavar="FILE", help="design CSV to write")
    p.add_argument("--json", default=None, metavar="FILE", help="JSON record of the run")
    p.add_argument("--allow-infeasible", action="store_true", help="write the design even if it fails")
    p.add_argument("--plot", default=None, metavar="FILE.png", help="picture of the poses (.png, .pdf, .svg)")
    cli.add_html(p)
    cli.add_extend(p)
    _add_discriminate_options(p)
    _add_contact_options(p)
    p.set_defaults(func=run)


def _add_solve_options(p: argparse.ArgumentParser) -> None:
    """What to optimise and how: ``--criterion``, ``--n``, ``--no-collision``, ``--solver``,
    ``--seed``, ``--start``, ``--certify``, ``--starts``."""
    p.add_argument(
        "--criterion",
        default=None,
        choices=DESIGN_METHODS,
        help="required unless --discriminate; "
        + "; ".join(
            ["heuristic = random feasible poses (paper 3.2)"]
            + [f"{c.name} = {c.description}" for c in TABLE.values()]
        ),
    )
    p.add_argument("--n", type=int, default=60, help="number of poses (default 60)")
    p.add_argument("--no-collision", action="store_true", help="no collision or laser-beam constraints")
    p.add_argument("--solver", choices=SOLVERS, default="snopt", help="NLP solver (default snopt)")
    cli.add_seed(p, of="the start")
    p.add_argument(
        "--start",
        choices=START_METHODS,
        default=None,
        help="the optimiser's start: heuristic = random feasible poses; approximate = the approximate KPI "
        f"design rounded to --n poses (criterion kpi only) (default {DEFAULT_START} for kpi, else heuristic)",
    )
    p.add_argument(
        "--certify",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the optimality certificate: a lower bound on tr(Cs)/3 of any design of --n poses and the "
        "design's efficiency (bound/value), on by default (not with --discriminate); it costs 4-13 s once "
        "per robot and setup (then cached on disk, $KPIOED_CACHE or ~/.cache/kpioed) and 1-4 s per design",
    )
    p.add_argument("--starts", type=int, default=1, help="number of starts, the best is kept (default 1)")


MEASURE_HELP = (
    "what a pose measures: point = the reflector's position (3 rows); pose = a 6-DoF probe's position and "
    "orientation (6 rows, the probe's rotation on the flange estimated) (default point); plane = touches "
    "of planes by a touch probe (1 row, no tracker; --planes), ballbar = the tool ball of a pivot ballbar "
    "at its length from the pivot (1 row, no tracker; --pivot, --bar-length-mm): the KPI design with its "
    "certificate, docs/contacts.md"
)
"""The help of ``--measure``: every measurement system a design is made for."""


def _add_measure_options(p: argparse.ArgumentParser) -> None:
    """``--measure point|pose|plane|ballbar``, ``--sigma-deg`` and ``--kpi-orientation-mm``."""
    measures = (*MEASURES, *CONTACT_PROBLEMS)
    p.add_argument("--measure", choices=measures, default="point", help=MEASURE_HELP)
    cli.add_sigma_deg(p, default=None, use=f"with --measure pose (default {SIGMA_ROT_DEG:g})")
    cli.add_kpi_orientation(p, default=None, use="with --measure pose")


def _add_discriminate_options(p: argparse.ArgumentParser) -> None:
    """``--discriminate A|B`` and its ``--condition-span``."""
    p.add_argument(
        "--discriminate",
        default=None,
        metavar="A|B",
        help="poses that tell two explanations apart (e.g. 'joint_scale:2=300|gear_cyclic:2:1'; values "
        "optional, default: the smallest realistic size), instead of --criterion; --given: the first data "
        "set; a pair with thermal_expansion, tracker_scale or tracker_drift gets a measurement plan (each "
        "pose in two blocks, the CSV's block and temperature_offset_K / time_offset_s columns), and so does "
        "a pair with a gravity-torque effect given a payload span (payload_offset_kg)",
    )
    p.add_argument(
        "--condition-span",
        default=None,
        metavar="SPAN",
        help="with --discriminate and a temperature or time effect: the change of temperature or time "
        "between the plan's two blocks, e.g. 3K, 600s, 10min, 3K,600s (default: the span for power 0.8, "
        "rounded up; 0 forbids it); with joint_elasticity, backlash or a compliance: the payload at the "
        "reflector in block 2, e.g. 10kg (opt-in; default: the poses alone)",
    )


def _add_kpi_options(p: argparse.ArgumentParser) -> None:
    """The working poses of the KPI: ``--q-work`` (repeatable), ``--q-work-file``, weights, aggregate."""
    cli.add_q_work(p, several=True)
    p.add_argument(
        "--q-work-file",
        default=None,
        metavar="FILE.csv",
        help="CSV of working poses (a column per joint: q1_deg, ...; optional weight column) instead of "
        "--q-work",
    )
    p.add_argument(
        "--kpi-weights",
        default=None,
        metavar="w1,...,wK",
        help="weights of the working poses in the mean KPI (normalised to sum 1; default equal)",
    )
    p.add_argument(
        "--kpi-aggregate",
        choices=KPI_AGGREGATES,
        default="mean",
        help="KPI of several working poses: the weighted mean of their tr(Cs)/3 or the worst (default mean)",
    )


def _weights(text: str | None) -> list[float] | None:
    """``--kpi-weights w1,...,wK`` as numbers (checked by
    :func:`~kpioed_drake.estimation.problem.make_problem`)."""
    if text is None:
        return None
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"--kpi-weights: expected comma-separated numbers, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    if (status := _contact_run(args)) is not None:
        return status
    if args.criterion is None and args.discriminate is None:
        raise InputError("--criterion is required (or --discriminate A|B)")
    q_work = args.q_work[0] if args.q_work and len(args.q_work) == 1 else args.q_work
    try:
        res = api.design(
            args.robot,
            criterion=args.criterion or "kpi",
            collision=not args.no_collision,
            q_work_deg=q_work,
            kpi_weights=_weights(args.kpi_weights),
            target_var_mm2=args.target_var,
            json_path=args.json,
            **cli.passed(args, "discriminate", "condition_span", "n", "solver", "seed", "starts", "sigma_mm"),
            **cli.passed(args, "q_work_file", "kpi_aggregate", "given", "extend", "out", "plot", "html"),
            **cli.passed(args, "allow_infeasible", "start", "certify", "measure", "sigma_deg"),
            **({} if args.kpi_orientation_mm is None else {"kpi_orientation_mm": args.kpi_orientation_mm}),
        )
    except DesignError as exc:
        if exc.result is not None:
            print(format_summary(exc.result), file=sys.stderr)
        print(
            f"kpioed: design failed: {name_fields(str(exc), exc.fields, args.option_names)}", file=sys.stderr
        )
        return EXIT_SOLVER
    print(format_summary(res))
    if getattr(res, "discrimination", None) is not None:
        rec = res.discrimination
        print("\n".join(discrimination_lines(rec) + plan_lines(rec) + payload_lines(rec)))
    if not (res.success and res.feasible):
        print(
            "kpioed: warning: the design failed or is infeasible (written because of --allow-infeasible)",
            file=sys.stderr,
        )
    written = [str(x) for x in (args.out, args.json, args.plot, args.html) if x]
    print(f"  wrote {', '.join(written)}")
    return 0


# Contact designs (``--measure plane|ballbar``): their own options, refusals and run.

CONTACT_OPTIONS = {
    "planes": "--planes",
    "pivot_mm": "--pivot",
    "bar_length_mm": "--bar-length-mm",
    "rounds": "--rounds",
}
"""The options of contact designs alone (dest -> option)."""
TRACKER_ONLY = {
    "given": "--given",
    "target_var": "--target-var",
    "discriminate": "--discriminate",
    "condition_span": "--condition-span",
    "plot": "--plot",
    "html": "--html",
    "extend": "--extend",
    "q_work_file": "--q-work-file",
    "kpi_weights": "--kpi-weights",
    "kpi_aggregate": "--kpi-aggregate",
    "sigma_deg": "--sigma-deg",
    "kpi_orientation_mm": "--kpi-orientation-mm",
    "start": "--start",
    "certify": "--certify",
    "starts": "--starts",
    "solver": "--solver",
    "allow_infeasible": "--allow-infeasible",
}
"""The options of tracker designs a contact design does not take (dest -> option)."""


def _add_contact_options(p: argparse.ArgumentParser) -> None:
    """The options of ``--measure plane|ballbar``: ``--planes``, ``--pivot``, ``--bar-length-mm`` and
    ``--rounds``; records the tracker options' defaults (a contact design refuses them when changed)."""
    p.add_argument(
        "--planes",
        default=None,
        metavar="PLANES.yaml|csv",
        help="with --measure plane: the planes (YAML 'planes: [{normal: [x, y, z], offset_mm: d}, ...]' or "
        "CSV nx,ny,nz,offset_mm; normal . x = d in the base frame, the normal towards the flange's side) "
        "(default models/planes/ROBOT.yaml)",
    )
    p.add_argument(
        "--pivot",
        dest="pivot_mm",
        default=None,
        metavar="x,y,z",
        help="with --measure ballbar: the pivot in the base frame [mm] (default the TCP at the working pose)",
    )
    cli.add_optional(
        p,
        "--bar-length-mm",
        type=float,
        metavar="L",
        help="with --measure ballbar: the bar's nominal length [mm] (default 150)",
    )
    cli.add_optional(
        p,
        "--rounds",
        type=int,
        metavar="R",
        help="with --measure plane|ballbar: most column-generation rounds of the search (default 40 for "
        "planes, 120 for a ballbar)",
    )
    p.set_defaults(tracker_defaults={a.dest: a.default for a in p._actions if a.dest in TRACKER_ONLY})


def _contact_run(args: argparse.Namespace) -> int | None:
    """A contact design's run (None for the other measures, which refuse the contact options)."""
    if args.measure not in CONTACT_PROBLEMS:
        if given := [o for d, o in CONTACT_OPTIONS.items() if getattr(args, d) is not None]:
            raise InputError(f"{', '.join(given)}: only with --measure plane or ballbar")
        return None
    changed = [o for d, o in TRACKER_ONLY.items() if getattr(args, d) != args.tracker_defaults[d]]
    if args.criterion not in (None, "kpi"):
        changed.insert(0, f"--criterion {args.criterion}")
    if changed:
        raise InputError(
            f"--measure {args.measure}: a KPI design without a tracker; not with {', '.join(changed)}"
        )
    if args.q_work is not None and len(args.q_work) > 1:
        raise InputError(f"--measure {args.measure}: one --q-work (a contact design has one working pose)")
    report = contact_design_file(
        args.robot,
        args.measure,
        q_work_deg=None if args.q_work is None else args.q_work[0],
        collision=not args.no_collision,
        json_path=args.json,
        **cli.passed(args, "planes", "pivot_mm", "bar_length_mm", "n", "sigma_mm", "seed", "rounds", "out"),
    )
    print(report.summary())
    print(f"  wrote {', '.join(str(x) for x in (args.out, args.json) if x)}")
    return 0
