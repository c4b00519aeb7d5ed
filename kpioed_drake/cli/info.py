"""``kpioed info``: parameters, identifiable count, reach and working pose of a robot."""

from __future__ import annotations

import argparse

from kpioed_drake import api, cli


def register(sub: argparse._SubParsersAction) -> None:
    p = cli.command(sub, "info", help="robot parameters, identifiable count, reach, q_work")
    p.add_argument("--json", dest="as_json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    d = api.info(args.robot)
    if args.as_json:
        cli.print_json(d)
        return 0
    print(f"robot        {d['robot']}")
    print(f"reach        {d['reach_mm']:.1f} mm")
    print(f"q_work       {d['q_work_deg']} deg")
    print(f"estimated    {len(d['estimated'])}: {', '.join(d['estimated'])}")
    print(f"fixed        {', '.join(d['fixed'])} (gauge: trade exactly against tracker pose / reflector)")
    ok = "all identifiable" if d["identifiable"] else f"NOT identifiable: {', '.join(d['unidentifiable'])}"
    print(f"n_params     {d['n_params']} ({ok})")
    pose = d["pose"]
    if pose is not None:
        print(
            f"6-DoF probe  {pose['n_params']} with orientations (kpioed calibrate of pose data): they add "
            f"{', '.join(pose['added']) or 'nothing'}"
        )
    names = [j["name"] for j in d["joints"]]
    branches = [
        f"{j['name']} ({k + 1}) on {names[j['parent'] - 1] if j['parent'] else 'the base'}"
        for k, j in enumerate(d["joints"])
        if j["parent"] != k  # not on the joint before it: a branch of a tree
    ]
    if branches:
        print(f"branches     {'; '.join(branches)}")
    for k, t in enumerate(d["targets"]):
        link = f"{names[t['link'] - 1]} ({t['link']})"
        print(f"target {k + 1}     on the link of {link}, offset {t['offset_mm']} mm")
    return 0
