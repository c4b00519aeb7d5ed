"""Author the robot model files under models/robots (run once; the YAML files are then the truth).

Usage: python studies/make_models.py [--only kr16,notional-850-800] [--skip-existing]

KUKA geometry: SPEC's datasheet table. Notional robots: paper Table 2 with SPEC's changes, our
sign conventions (models/README.md). q_work is solved by Drake inverse kinematics; where the
working point cannot be reached in the default cell, the car is moved away from or towards the
robot along x in 50 mm steps and the shift is stored in the file (SPEC).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import yaml

from kpioed_drake.robot.models import MODELS_DIR, RobotSpec, load_cell, robot_from_spec
from kpioed_drake.study.authoring import EnvelopeSize, envelope_links, kinematic_rows, solve_q_work

KUKA = {
    "kr16": dict(
        description="KUKA KR 15 of the paper, with KR 16-2 geometry (no public KR 15 data).",
        geo=dict(d1=675, a1=260, a2=680, a3=35, d4=670, d6=158),
        limits=[(-185, 185), (-155, 35), (-130, 154), (-350, 350), (-130, 130), (-350, 350)],
        size=EnvelopeSize(220, 180, 120, 110, 90, 40, (60, 70, 45, 35, 8, 6, 2)),
        rated_payload_kg=16.0,
    ),
    "kr300": dict(
        description="KUKA KR 300 R2500 ultra.",
        geo=dict(d1=675, a1=350, a2=1150, a3=41, d4=1000, d6=240),
        limits=[(-185, 185), (-140, -5), (-120, 155), (-350, 350), (-122.5, 122.5), (-350, 350)],
        size=EnvelopeSize(380, 320, 200, 180, 140, 40, (250, 330, 230, 200, 50, 35, 10)),
        rated_payload_kg=300.0,
    ),
    "kr500": dict(
        description="KUKA KR 500 R2830.",
        geo=dict(d1=1045, a1=500, a2=1300, a3=55, d4=1025, d6=290),
        limits=[(-185, 185), (-130, 20), (-100, 144), (-350, 350), (-120, 120), (-350, 350)],
        size=EnvelopeSize(420, 360, 230, 200, 160, 40, (550, 700, 500, 420, 100, 70, 20)),
        rated_payload_kg=500.0,
    ),
}
NOTIONAL_LIMITS = [(-82, 82), (-77, 31), (-13, 154), (-347, 347), (-87, 87), (-347, 347)]
SELF_PAIRS = [[0, 3], [0, 5], [0, 6], [1, 3], [1, 5], [1, 6], [2, 5], [2, 6], [3, 6]]
BEAM_LINKS = [0, 1, 2, 3, 5]
SOURCES = (
    "Geometry: SPEC.md (public datasheet numbers converted to our DH/Hayati rows). Capsules: "
    "kpioed_drake.study.authoring.envelope_links, radii chosen to nearly surround the links (paper 3.2). "
    "Masses: estimates that add up to the datasheet's total robot mass, split base 25 %, shoulder "
    "30 %, upper arm 20 %, forearm 15 %, wrist and flange the rest; centres of mass at the middle of "
    "each link's capsule."
)


def notional_entries():
    for lam in range(650, 1101, 50):
        for mu in range(600, 1001, 50):
            s = (lam + mu) / 1350.0
            yield (
                f"notional-{lam}-{mu}",
                dict(
                    description=f"Notional robot of paper Table 2 with lambda = {lam} mm, mu = {mu} mm.",
                    geo=dict(d1=675, a1=350, a2=lam, a3=145, d4=mu, d6=170),
                    limits=NOTIONAL_LIMITS,
                    size=EnvelopeSize(
                        220,
                        180,
                        120,
                        110,
                        90,
                        40,
                        (60, 70, round(45 * lam / 680, 1), round(35 * mu / 670, 1), 8, 6, 2),
                    ),
                    mass_note=f"scale {s:.2f}",
                ),
            )


def author(name: str, entry: dict, out: Path) -> None:
    cell = load_cell()
    rows = kinematic_rows(**entry["geo"], limits_deg=entry["limits"])
    links = envelope_links(rows, entry["size"], cell.p_FQ)
    spec = RobotSpec(
        name=name,
        description=entry["description"],
        sources=SOURCES,
        joints=rows,
        links=links,
        self_collision_pairs=SELF_PAIRS,
        beam_links=BEAM_LINKS,
        rated_payload_kg=entry.get("rated_payload_kg", 0.0),
    )
    shift, q = 0.0, None
    for shift in [0.0, -50.0, -100.0, -150.0, -200.0, -250.0, -300.0, 50.0, 100.0, 150.0, 200.0]:
        spec.car_shift_x_mm = shift
        robot = robot_from_spec(spec, where=name)
        try:
            q, ang, err = solve_q_work(robot, load_cell(robot=robot))
            break
        except RuntimeError:
            continue
    if q is None:
        raise SystemExit(f"{name}: no working pose found for any car shift")
    spec.q_work_deg = np.rad2deg(q).round(4).tolist()
    spec.notes = (
        f"q_work by Drake IK (kpioed_drake.study.authoring.solve_q_work): reflector 100 mm above the cabin, "
        f"reflector axis {np.rad2deg(ang):.1f} deg from the line of sight, position error {err:.2e} mm."
        + (f" Car moved {shift:+.0f} mm along x so that the working point is reachable." if shift else "")
    )
    data = dataclasses.asdict(spec)
    out.parent.mkdir(parents=True, exist_ok=True)
    header = "# Robot model file (kpioed-drake). Units: mm, deg, kg. Format: models/README.md.\n"
    out.write_text(header + yaml.safe_dump(data, sort_keys=False, width=100))
    print(f"{name}: q_work = {spec.q_work_deg}, incidence {np.rad2deg(ang):.1f} deg, car shift {shift}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--only", default="", help="comma-separated names")
    ap.add_argument("--skip-existing", action="store_true")
    args = ap.parse_args()
    entries = dict(KUKA)
    entries.update(dict(notional_entries()))
    only = set(filter(None, args.only.split(",")))
    for name, entry in entries.items():
        if only and name not in only:
            continue
        sub = "notional/" if name.startswith("notional-") else ""
        out = MODELS_DIR / "robots" / f"{sub}{name}.yaml"
        if args.skip_existing and out.exists():
            continue
        author(name, entry, out)


if __name__ == "__main__":
    main()
