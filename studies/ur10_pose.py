"""Calibrate the public UR10 6-DoF data (positions and orientations) and validate on its test set.

``train_6dof.csv`` (150 poses) and ``test_6dof.csv`` (500 other poses of the same session) of
``../shared/data/ur10-laser-tracker`` (README there): the probe origin in the tracker frame and the
probe frame's orientation as intrinsic XYZ Euler angles, ``R = Rotation.from_euler('XYZ', (rx, ry,
rz), degrees=True)``. Until the file readers take orientation columns, this script builds the
:class:`~kpioed_drake.tracker.data.Measurements` with pandas and scipy.

Three fits on the same train poses, each validated on the test poses with the tracker frame kept
(the fit's own: same session), position and orientation errors (mean / 95 % / max):

- ``points``: positions only (the model file's gauge holds theta5, alpha5: the probe origin is on
  joint 6's axis);
- ``pose``: positions and orientations, the orientation rows weighted with ``sigma_deg`` (default
  0.01 deg) and the positions with ``sigma_mm`` (0.02 mm);
- ``points`` again, its probe orientation on the flange registered afterwards on the train rows
  (closed form): the orientation errors of a positions-only fit;
- ``pose-row-sigmas``: the same with each row's own orientation std (``std_r*_deg`` read as the
  std of the small rotation about the tracker axes, an approximation: they are the Euler angles').

Usage::

    .venv/bin/python studies/ur10_pose.py [--json out/ur10_pose.json] [--data DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from kpioed_drake.calibration.fit import calibrate
from kpioed_drake.calibration.modelfile import calibrated_robot_yaml
from kpioed_drake.calibration.options import CalibrationOptions
from kpioed_drake.calibration.validate import validate
from kpioed_drake.estimation.accuracy import orientation_accuracy
from kpioed_drake.outputs import atomic_write_json
from kpioed_drake.robot.jointmap import q_columns, q_from_file
from kpioed_drake.robot.models import load_robot
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.orientation import registered_probe, with_probe, world_orientation_errors

REPO = Path(__file__).resolve().parents[1]
EULER = ["rx_deg", "ry_deg", "rz_deg"]
STD_ROT = ["std_rx_deg", "std_ry_deg", "std_rz_deg"]
WRIST = ("theta5", "a5", "alpha5", "d5")


def read_pose_csv(path: Path, robot, *, row_sigmas: bool = False, orientations: bool = True) -> Measurements:
    """The 6-DoF file as Measurements (angles as the README says: intrinsic XYZ Euler degrees)."""
    t = pd.read_csv(path)
    q = q_from_file(robot, t[list(q_columns(robot))].to_numpy(dtype=float))
    eta = t[["x_mm", "y_mm", "z_mm"]].to_numpy(dtype=float)
    if not orientations:
        return Measurements.from_arrays(q, eta, source=str(path))
    R_TP = Rotation.from_euler("XYZ", t[EULER].to_numpy(dtype=float), degrees=True).as_matrix()
    sigma = np.deg2rad(t[STD_ROT].to_numpy(dtype=float)) if row_sigmas else None
    return Measurements.from_arrays(q, eta, source=str(path), R_TP=R_TP, sigma_rot_rad=sigma)


def run_fit(name: str, robot, train: Measurements, test: Measurements, folder: Path) -> dict:
    """Calibrate on ``train``, write the model, validate it on ``test`` with the tracker kept."""
    report = calibrate(robot, train, CalibrationOptions(sigma_mm=0.02, sigma_deg=0.01))
    path = folder / f"ur10-{name}.yaml"
    path.write_text(calibrated_robot_yaml(report))
    val = validate(load_robot(str(path)), test, tracker_frame="kept")
    fit_o, val_o = report.orientation_figures(), val.orientation_figures()
    out = {
        "fit": name,
        "n_free": report.model.layout.n_free,
        "held_at_nominal": report.held_at_nominal,
        "gauge": [n for n in report.model.layout.names if n not in report.model.layout.free_names],
        "chi2_per_dof": report.chi2_per_dof,
        "fit_position": report.figures().to_dict(),
        "fit_orientation": None if fit_o is None else fit_o.to_dict(),
        "test_position": val.figures().to_dict(),
        "test_orientation": None if val_o is None else val_o.to_dict(),
        "probe": report.probe(),
        "wrist": [p for p in report.parameter_table() if p["name"] in WRIST],
        "warnings": list(report.warnings) + list(val.warnings),
        "notes": list(val.notes),
        "report": report,
    }
    print(f"{name}: {out['n_free']} parameters estimated; held {out['held_at_nominal']}")
    for p in out["wrist"]:
        est = f"{p['deviation']:+.5f} +- {p['std']:.5f}" if p["estimated"] else "held at nominal"
        print(f"  {p['name']}: {est} {p['unit']}")
    if out["probe"]:
        print(f"  probe rpy on the flange: {np.round(out['probe']['rpy_deg'], 4).tolist()} deg")
    print("\n".join(report.figures().lines() + (fit_o.lines() if fit_o else [])))
    print("\n".join(val.figures().lines() + (val_o.lines() if val_o else [])))
    return out


def points_model_orientation(report, train: Measurements, test: Measurements) -> dict:
    """The points fit's orientation errors on ``test`` once the probe's orientation on the flange is
    registered (closed form, the chordal mean) on the train rows: what its held wrist parameters cost."""
    model = registered_probe(with_probe(report.model), train.q, train.R_TP)
    e_fit = world_orientation_errors(model, train.q, train.R_TP, model.R_WT)
    e_test = world_orientation_errors(model, test.q, test.R_TP, model.R_WT)
    fit = orientation_accuracy(e_fit, kind="fit", tracker="fitted", model="points fit + registered probe")
    held_out = orientation_accuracy(
        e_test, kind="held-out", tracker="kept", model="points fit + registered probe"
    )
    print("\n".join(fit.lines() + held_out.lines()))
    return {"fit_orientation": fit.to_dict(), "test_orientation": held_out.to_dict()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "ur10-laser-tracker"))
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    folder = Path(args.data)
    if not (folder / "train_6dof.csv").is_file():
        print(f"{folder}: no train_6dof.csv", file=sys.stderr)
        return 2
    robot = load_robot("ur10")
    train, test = folder / "train_6dof.csv", folder / "test_6dof.csv"
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [
            ("points", dict(orientations=False)),
            ("pose", dict()),
            ("pose-row-sigmas", dict(row_sigmas=True)),
        ]
        for name, kw in cases:
            tr = read_pose_csv(train, robot, **kw)
            te = read_pose_csv(test, robot, orientations=name != "points")
            results.append(run_fit(name, robot, tr, te, Path(tmp)))
            if name == "points":
                report = results[-1].pop("report")
                both = read_pose_csv(train, robot), read_pose_csv(test, robot)
                results[-1]["registered_probe"] = points_model_orientation(report, *both)
            else:
                results[-1].pop("report")
    if args.json:
        atomic_write_json(args.json, {"data": str(folder), "fits": results})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
