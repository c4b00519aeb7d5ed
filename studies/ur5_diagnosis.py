"""Diagnose the public UR5 laser-tracker data (1000 grid poses) and predict the 20 random poses.

``kpioed diagnose`` on ``../shared/data/ur5-laser-tracker/ur5_grid.csv`` (format file
``models/formats/ur5-laser-tracker.yaml``, measurement order as time, sigma = the data's own level
0.065 mm), then the mean 3-D error on ``ur5_random.csv`` (unseen) of the geometric fit and of the
extended fit (joint-angle effects at the random poses' commanded angles; an effect of time or
temperature is left out of the prediction: the random poses were taken at another time), with the
fitted tracker frame (the data are in the base frame) and after a rigid re-registration.

Usage::

    .venv/bin/python studies/ur5_diagnosis.py [--json out/ur5_diagnosis.json] [--data DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis import DiagnosisOptions, diagnose
from kpioed_drake.estimation.estimator import register_tracker
from kpioed_drake.outputs import atomic_write_json
from kpioed_drake.robot.models import load_robot
from kpioed_drake.tracker.data import read_data

REPO = Path(__file__).resolve().parents[1]
SIGMA_MM = 0.065


def predict_errors(fit, data) -> dict:
    """Mean and RMS 3-D error [mm] of ``fit`` (geometry + its joint effects) on ``data``."""
    joint = [e for e in fit.effects if e.family in fx.JOINT_FAMILIES]
    h = fx.augmented_response(fit.model, data.q, joint)
    err = np.linalg.norm(data.eta - h, axis=1)
    # re-registered: the predicted points in W against the data, a rigid fit of the frame
    p_W = h @ fit.model.R_WT.T + fit.model.p_WT
    R, p = register_tracker(p_W, data.eta)
    err_reg = np.linalg.norm(data.eta - (p_W - p) @ R, axis=1)
    return {
        "mean_mm": float(err.mean()),
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "mean_registered_mm": float(err_reg.mean()),
        "effects_used": [e.name for e in joint],
        "effects_left_out": [e.name for e in fit.effects if e not in joint],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "ur5-laser-tracker"))
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    robot = load_robot("ur5")
    fmt = REPO / "models" / "formats" / "ur5-laser-tracker.yaml"
    grid = read_data(Path(a.data) / "ur5_grid.csv", robot, fmt)
    rand = read_data(Path(a.data) / "ur5_random.csv", robot, fmt)
    t0 = time.perf_counter()
    rep = diagnose(robot, grid, DiagnosisOptions(sigma_mm=SIGMA_MM))
    seconds = time.perf_counter() - t0
    out = {
        "seconds": seconds,
        "causes": [
            {
                "name": c.get("name"),
                "value": c.get("value"),
                "std": c.get("std"),
                "unit": c.get("unit"),
                "plausible": c.get("plausible"),
                "alternatives": [x.get("name") for x in c.get("alternatives", [])],
                "lr_stat": c["evidence"].get("lr_stat"),
                "tool_max_mm": c["evidence"].get("tool_max_mm"),
            }
            for c in rep.causes
        ],
        "baseline": rep.baseline,
        "extended": rep.extended,
        "notes": rep.notes,
        "random_geometric": predict_errors(rep.details["base"], rand),
        "random_extended": predict_errors(rep.details["ext"], rand),
    }
    print(
        f"{seconds:.0f} s; causes {[c['name'] for c in out['causes']]}; held-out (grid, 5-fold) "
        f"{rep.baseline['holdout_rms_mm']:.4f} -> {rep.extended['holdout_rms_mm']:.4f} mm; "
        f"random 20 poses mean {out['random_geometric']['mean_mm']:.4f} -> "
        f"{out['random_extended']['mean_mm']:.4f} mm"
    )
    if a.json:
        atomic_write_json(a.json, {**out, "report": rep.to_json()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
