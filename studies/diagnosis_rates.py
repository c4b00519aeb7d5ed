"""How often does :func:`kpioed_drake.diagnosis.diagnose` name a hidden effect correctly?

Seeded cases simulated by :func:`kpioed_drake.study.synthetic.run_synthetic_case` (true robot = nominal +
geometric errors of SPEC size + random tracker frame + effects + noise 0.02 mm, on random
collision-free poses). Kinds:

- ``single:FAMILY``: one hidden effect of that family (joint/harmonic uniform), for every family
  of :data:`FAMILIES`;
- ``pair``: two different hidden effects of any of those families (``--families``);
- ``clean``: no effect (false alarms);
- ``single:joint_elasticity:spec``: elasticity at SPEC's sizes (0.1-1 mm at the tool), not near
  the threshold: where masses unlike the file's matter (the gravity basis);
- ``single`` (old harness, ``--families``): one effect of any of the families;
- ``single:column_compliance``, ``single:base_compliance`` (not in the default kinds): a robot on
  a lift (``--robot lift7 --kinds single:column_compliance,clean``), the column's joint drawn among
  the robot's lifting columns.

The harder harness (default on; ``--easy`` switches it off, as in the first rates table): the true
link masses and centres of mass are +-30 % off the model file's (``--mass-spread``), every other
seed carries a payload that changes over the campaign (0 kg or 2-15 kg per pose), and each hidden
effect is rescaled near the detection threshold (its lambda log-uniform in 15-150).

Per case: named exactly; *explained* (every hidden effect named or among a cause's alternatives,
every cause standing for a hidden effect); a false alarm (clean data with a cause or a rejecting
test); the extended held-out RMS over sigma. ``lambda``: the non-centrality of the hidden signal
after projecting out the geometric parameters; below 25 no test at a corrected 1 % level finds it
reliably ("detectable" = lambda >= 25 for every hidden effect).

Every finished case is written at once (atomically) to ``OUT/cases/KIND-SEED.json``; a new run with
the same ``OUT`` skips the cases on disk (resume). Cases run seed-major over the kinds, so a
stopped run has about as many cases of every kind.

Usage::

    .venv/bin/python studies/diagnosis_rates.py --out out/rates --cases 100 [--poses 80] [--workers 2]
    .venv/bin/python studies/diagnosis_rates.py --out out/rates --summary-only   # table of what is on disk
    .venv/bin/python studies/diagnosis_rates.py --out /tmp/q --quick             # a handful of cases
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import scipy.stats

from kpioed_drake import diagnosis as D
from kpioed_drake import effects as fx
from kpioed_drake.effects.compliance import vertical_columns
from kpioed_drake.outputs import atomic_write_json
from kpioed_drake.robot.models import load_robot
from kpioed_drake.study import synthetic as syn
from kpioed_drake.study.synthetic import RATE_FAMILIES

DETECTABLE = 25.0
FAMILIES = RATE_FAMILIES
"""The families of the rate study (SPEC's four and the further four)."""
KINDS = tuple(f"single:{f}" for f in FAMILIES) + ("pair", "clean", "single:joint_elasticity:spec")
QUICK_KINDS = ("single:joint_scale", "pair", "clean")


def case_path(out: Path, kind: str, seed: int) -> Path:
    return out / "cases" / f"{kind.replace(':', '-')}-{seed}.json"


def run_case(job) -> dict:
    """Run one case (or read it back if it is on disk) and write it atomically."""
    out, kind, seed, opts = job
    path = case_path(Path(out), kind, seed)
    if path.exists():
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            pass  # unreadable: redo
    base, _, fam = kind.partition(":")
    fam, _, variant = fam.partition(":")
    families = (fam,) if fam else tuple(opts["families"])
    if fam == "column_compliance":  # the robot's lifting column(s)
        families = tuple(f"{fam}:{j}" for j in vertical_columns(load_robot(opts["robot"])))
    hard = not opts["easy"]
    rec = syn.run_synthetic_case(
        base,
        seed,
        opts["robot"],
        n_poses=opts["poses"],
        families=families,
        mass_spread=opts["mass_spread"] if hard else 0.0,
        payload="changes" if hard and seed % 2 else None,
        near_threshold=hard and variant != "spec",
    )
    rec["kind"] = kind
    rec["options"] = opts
    atomic_write_json(path, rec)
    return rec


POWER_TESTS = 35
"""Candidates of a KR 16 step on data with temperature and time (the Bonferroni factor of the power
reference, :func:`power_expected`)."""


def power_expected(rec: dict, *, alpha: float = D.ALPHA, tests: int = POWER_TESTS) -> float:
    """Probability that a test which knew the hidden effects' candidates would find all of them: the
    product over the hidden effects of the power of a chi2(k) test at ``alpha / tests`` (Bonferroni)
    against each effect's non-centrality beside the others (``lambda_given_others``). What a perfect
    search at the diagnosis' level could reach on this case; no spurious additions counted."""
    out = 1.0
    for text, lam in zip(rec["truth"], rec.get("lambda_given_others", rec["lambda"]), strict=True):
        k = fx.parse_effect(text).n_params
        out *= float(scipy.stats.ncx2.sf(scipy.stats.chi2.isf(alpha / tests, k), k, lam))
    return out


def _rate(flags) -> str:
    flags = list(flags)
    return f"{sum(flags)}/{len(flags)}" if flags else "-"


def summarise(records: list[dict]) -> dict:
    """Per kind: counts and rates (see the module docstring)."""
    out = {}
    for kind in sorted({r["kind"] for r in records}, key=lambda k: (KINDS + (k,)).index(k)):
        rs = [r for r in records if r["kind"] == kind]
        ho = np.array([r["holdout_ext_over_sigma"] for r in rs])
        s = {"cases": len(rs), "holdout_within_1.3": _rate(ho <= 1.3)}
        s["holdout_ext_over_sigma_median"] = float(np.median(ho))
        s["holdout_ext_over_sigma_max"] = float(np.max(ho))
        s["seconds_median"] = float(np.median([r["seconds"] for r in rs]))
        if kind == "clean":
            s["false_alarms"] = _rate(r["discrepancy"] for r in rs)
            s["causes_named"] = _rate(bool(r["named"]) for r in rs)
        else:
            det = [r for r in rs if min(r["lambda"]) >= DETECTABLE]
            s["detectable"] = len(det)
            s["exact"] = _rate(r["exact"] for r in rs)
            s["explained"] = _rate(r.get("explained", r["exact"]) for r in rs)
            s["exact_detectable"] = _rate(r["exact"] for r in det)
            s["explained_detectable"] = _rate(r.get("explained", r["exact"]) for r in det)
            s["named_with_gravity_basis"] = sum(any("basis" in x for x in r.get("named_raw", [])) for r in rs)
            s["power_expected_detectable"] = round(sum(power_expected(r) for r in det), 1)
            if kind == "pair":  # each effect detectable beside the other hidden one too
                both = [r for r in det if min(r.get("lambda_given_others", [0.0])) >= DETECTABLE]
                s["detectable_given_others"] = len(both)
                s["explained_detectable_given_others"] = _rate(r["explained"] for r in both)
        out[kind] = s
    return out


def markdown(summary: dict) -> str:
    """The rates table of docs/diagnosis.md."""
    lines = [
        "| kind | cases | detectable | named exactly (detectable) | named or alternative (detectable) "
        "| false alarms | held-out <= 1.3 sigma (median, max) |",
        "|---|---|---|---|---|---|---|",
    ]
    for kind, s in summary.items():
        med, mx = s["holdout_ext_over_sigma_median"], s["holdout_ext_over_sigma_max"]
        ho = f"{s['holdout_within_1.3']} ({med:.2f}, {mx:.2f})"
        if kind == "clean":
            lines.append(f"| clean | {s['cases']} | - | - | - | {s['false_alarms']} | {ho} |")
        else:
            lines.append(
                f"| {kind} | {s['cases']} | {s['detectable']} | {s['exact']} ({s['exact_detectable']}) | "
                f"{s['explained']} ({s['explained_detectable']}) | - | {ho} |"
            )
    return "\n".join(lines)


def misses(records: list[dict]) -> list[str]:
    out = []
    for r in sorted(records, key=lambda r: (r["kind"], r["seed"])):
        bad = r["discrepancy"] if r["kind"] == "clean" else not r.get("explained", r["exact"])
        if bad or r["holdout_ext_over_sigma"] > 1.3:
            out.append(
                f"{r['kind']} seed {r['seed']}: truth {[t.split('=')[0] for t in r['truth']]} (lambda "
                f"{[round(x, 1) for x in r['lambda']]}), named {r['named']}, alternatives "
                f"{r.get('alternatives')}, held-out/sigma {r['holdout_ext_over_sigma']:.2f}"
            )
    return out


def read_records(out: Path) -> list[dict]:
    recs = []
    for p in sorted((out / "cases").glob("*.json")):
        try:
            recs.append(json.loads(p.read_text()))
        except (OSError, ValueError):
            continue
    return recs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder of the per-case files (resumed if present)")
    ap.add_argument("--cases", type=int, default=100, help="cases per kind (default 100)")
    ap.add_argument("--robot", default="kr16")
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--families", default=",".join(FAMILIES), help="families of 'pair' and plain 'single'")
    ap.add_argument("--mass-spread", type=float, default=0.3)
    ap.add_argument(
        "--easy", action="store_true", help="the first harness: file masses, no payload, SPEC sizes"
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="1 case of 3 kinds on 60 poses (a CI-size check)")
    ap.add_argument("--summary-only", action="store_true", help="summarise the cases on disk, run nothing")
    a = ap.parse_args(argv)
    kinds = QUICK_KINDS if a.quick else tuple(k.strip() for k in a.kinds.split(","))
    for k in kinds:
        base, _, fam = k.partition(":")
        fam, _, variant = fam.partition(":")
        if (
            base not in syn.CASE_KINDS
            or (fam and fam not in FAMILIES + fx.COMPLIANCE_FAMILIES)
            or variant not in ("", "spec")
        ):
            ap.error(f"unknown kind {k!r}; expected one of {', '.join(KINDS)} or single/pair/clean")
    cases, poses = (1, 60) if a.quick else (a.cases, a.poses)
    out = Path(a.out)
    opts = {
        "robot": a.robot,
        "poses": poses,
        "mass_spread": a.mass_spread,
        "easy": a.easy,
        "families": [f.strip() for f in a.families.split(",")],
    }
    t0 = time.time()
    if not a.summary_only:
        jobs = [(str(out), k, a.seed0 + s, opts) for s in range(cases) for k in kinds]
        if a.workers > 1:
            with Pool(a.workers) as pool:
                for _ in pool.imap_unordered(run_case, jobs, chunksize=1):
                    pass
        else:
            for j in jobs:
                run_case(j)
    records = [r for r in read_records(out) if r["kind"] in kinds]
    summary = summarise(records)
    for line in misses(records):
        print("miss " + line, file=sys.stderr)
    print(markdown(summary))
    atomic_write_json(
        out / "summary.json", {"summary": summary, "wall_seconds": time.time() - t0, "options": opts}
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
