"""The simulated stand-in of an elastic humanoid upper body (issue 25): its model files and data.

An 11-joint serial chain: a torso of three actuated joints (yaw ``t1`` about the vertical, pitch
``t2`` and ``t3``) and a fourth pitch joint ``t4`` coupled to keep the chest upright,
``q_t4 = -(q_t2 + q_t3)``; on the chest a seven-joint right arm (shoulder pitch, roll, upper-arm
yaw, elbow, forearm yaw, wrist pitch, wrist roll) with a hand and its reflector.

- :func:`write_models` writes ``models/robots/humanoid11.urdf`` (no inertial data: the model the
  tool sees) and ``humanoid11_truth.urdf`` (link masses 2-15 kg, for the truth simulation only),
  each with its sidecar.
- :func:`poses` draws seeded poses in the joint box with the coupling.
- :func:`stand_in_data` simulates the elastic truth (joint compliance of the torso pitch joints,
  the shoulder and the elbow; 0.5 mm noise) on the truth file and returns fitted and held-out
  measurement tables for the mass-free file; of the two-arm twin too (``twin``, with ``lateral``
  the torso yaw's and the shoulders' bearings), and the two-arm diagnosis stand-in of issue 46
  (``spread``: the twin with 8 compliant bearings of the torso and both arms beside the elasticity
  of 9 joints, :data:`LATERAL_SPREAD`), whose diagnosis names about ten effects as the real robot's
  names thirteen.

Run ``python bench/humanoid.py`` to (re)write the model files.
"""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path

import numpy as np

ROBOTS = Path(__file__).resolve().parents[1] / "models" / "robots"
NAME = "humanoid11"
# (name, parent link, child link, origin xyz [m], axis, limits [deg], child mass [kg], child com [m])
JOINTS = [
    ("t1", "pelvis", "torso_yaw", (0, 0, 0.9), (0, 0, 1), (-40, 40), 8.0, (0, 0, 0.05)),
    ("t2", "torso_yaw", "torso_low", (0, 0, 0.1), (0, 1, 0), (-5, 25), 12.0, (0.01, 0, 0.18)),
    ("t3", "torso_low", "torso_mid", (0, 0, 0.35), (0, 1, 0), (-5, 25), 10.0, (0.01, 0, 0.17)),
    ("t4", "torso_mid", "chest", (0, 0, 0.35), (0, 1, 0), (-50, 10), 15.0, (0.03, 0.02, 0.2)),
    ("a1", "chest", "shoulder", (0, -0.22, 0.35), (0, 1, 0), (-120, 30), 4.0, (0, -0.05, 0)),
    ("a2", "shoulder", "upper_arm_1", (0, -0.1, 0), (1, 0, 0), (-90, 10), 3.0, (0, 0, -0.1)),
    ("a3", "upper_arm_1", "upper_arm_2", (0, 0, -0.15), (0, 0, 1), (-90, 90), 3.0, (0.01, 0, -0.1)),
    ("a4", "upper_arm_2", "forearm_1", (0, 0, -0.15), (0, 1, 0), (-130, 0), 2.5, (0, 0, -0.1)),
    ("a5", "forearm_1", "forearm_2", (0, 0, -0.14), (0, 0, 1), (-90, 90), 2.0, (0.01, 0, -0.08)),
    ("a6", "forearm_2", "wrist", (0, 0, -0.14), (0, 1, 0), (-60, 60), 2.0, (0, 0, -0.03)),
    ("a7", "wrist", "hand", (0, 0, -0.06), (1, 0, 0), (-90, 90), 2.0, (0.02, 0, -0.06)),
]


def _mirrored(joint):
    """The left arm's joint of a right-arm joint: y mirrored, the roll joints' limits mirrored."""
    name, parent, child, xyz, axis, (lo, up), m, com = joint
    side = lambda link: link if link == "chest" else f"{link}_left"  # noqa: E731
    lims = (-up, -lo) if axis == (1, 0, 0) or axis == (0, 0, 1) else (lo, up)
    return (
        "b" + name[1:],
        side(parent),
        side(child),
        (xyz[0], -xyz[1], xyz[2]),
        axis,
        lims,
        m,
        (com[0], -com[1], com[2]),
    )


TWIN = "humanoid18"
"""The two-arm twin: the same torso, the right arm and its mirror image on the chest (18 joints,
one hand marker each)."""
TWIN_JOINTS = JOINTS + [_mirrored(j) for j in JOINTS[4:]]
LEFT_REFLECTOR_MM = (30.0, -10.0, -130.0)
COUPLED = 4
"""The coupled torso joint (1-based): ``q_4 = -(q_2 + q_3)``."""
REFLECTOR_MM = (30.0, 10.0, -130.0)
TRACKER_MM = (2500.0, -600.0, 1400.0)
ELASTICITY = {2: 2.5e-5, 3: 3e-5, 4: 5e-5, 5: 1.5e-4, 6: 1.5e-4, 8: 2.5e-4}
"""The truth's joint compliance [rad/(N m)] (hand deflection 10-20 mm at most over the poses)."""


def _urdf(with_masses: bool, twin: bool = False) -> str:
    lines = [f'<?xml version="1.0"?>\n<robot name="{TWIN if twin else NAME}">', '  <link name="pelvis"/>']
    for name, parent, child, xyz, axis, (lo, up), m, com in TWIN_JOINTS if twin else JOINTS:
        inert = ""
        if with_masses:
            i = 0.4 * m * 0.05**2
            inert = (
                f'<inertial><mass value="{m}"/><origin xyz="{com[0]} {com[1]} {com[2]}" rpy="0 0 0"/>'
                f'<inertia ixx="{i:.6g}" iyy="{i:.6g}" izz="{i:.6g}" ixy="0" ixz="0" iyz="0"/></inertial>'
            )
        lines.append(f'  <link name="{child}">{inert}</link>')
        lines.append(
            f'  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="0 0 0"/>'
            f'<axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>'
            f'<limit lower="{np.deg2rad(lo):.12g}" upper="{np.deg2rad(up):.12g}" effort="300" velocity="2"/>'
            "</joint>"
        )
    lines.append("</robot>\n")
    return "\n".join(lines)


def _sidecar(truth: bool, twin: bool = False) -> str:
    what = "with the link masses of the truth simulation" if truth else "without link masses"
    if twin:
        return (
            f"# Sidecar of {TWIN}{'_truth' if truth else ''}.urdf "
            "(kpioed-drake; written by bench/humanoid.py).\n"
            f"name: {TWIN}\n"
            f"description: The two-arm twin of {NAME} ({what}), the coupled torso and two seven-joint\n"
            "  arms, a marker on each hand (target 1 right, target 2 left).\n"
            "targets:\n"
            f"  - {{link: hand, position_mm: [{', '.join(str(v) for v in REFLECTOR_MM)}]}}\n"
            f"  - {{link: hand_left, position_mm: [{', '.join(str(v) for v in LEFT_REFLECTOR_MM)}]}}\n"
            f"tracker_position_mm: [{', '.join(str(v) for v in TRACKER_MM)}]\n"
            "tracker_rpy_deg: [0, 0, 0]\n"
            "q_work: [0, 10, 10, -20, -60, -20, 0, -60, 0, 0, 0, -60, 20, 0, -60, 0, 0, 0]\n"
            "joint_map:  # the controller commands 17 axes; t4 follows t2 and t3\n"
            f"  controller_axes: [{', '.join(j[0] for j in TWIN_JOINTS if j[0] != 't4')}]\n"
            "  joints: {t4: {t2: -1, t3: -1}}\n"
        )
    return (
        f"# Sidecar of {NAME}{'_truth' if truth else ''}.urdf (kpioed-drake; written by bench/humanoid.py).\n"
        f"name: {NAME}\n"
        f"description: A simulated stand-in of an elastic humanoid upper body ({what}), torso yaw, two\n"
        "  pitch joints and a fourth pitch joint coupled as q4 = -(q2 + q3), a seven-joint arm,\n"
        "  a hand reflector.\n"
        f"reflector_position_mm: [{', '.join(str(v) for v in REFLECTOR_MM)}]\n"
        f"tracker_position_mm: [{', '.join(str(v) for v in TRACKER_MM)}]\n"
        "tracker_rpy_deg: [0, 0, 0]\n"
        "q_work: [0, 10, 10, -20, -60, -20, 0, -60, 0, 0, 0]\n"
    )


def write_models(folder: Path = ROBOTS, *, twin: bool = False) -> tuple[Path, Path]:
    """Write the mass-free model and the truth model (URDF + sidecar each) of the stand-in (or its
    two-arm ``twin``); returns the two URDFs."""
    out = []
    for truth in (False, True):
        stem = (TWIN if twin else NAME) + ("_truth" if truth else "")
        (folder / f"{stem}.urdf").write_text(_urdf(truth, twin))
        (folder / f"{stem}.kpioed.yaml").write_text(_sidecar(truth, twin))
        out.append(folder / f"{stem}.urdf")
    return out[0], out[1]


def poses(robot, n: int, seed: int) -> np.ndarray:
    """(n, 11) poses uniform in the joint box with the coupling ``q_4 = -(q_2 + q_3)`` [rad]."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(robot.lower, robot.upper, size=(n, robot.n_joints))
    q[:, COUPLED - 1] = -(q[:, 1] + q[:, 2])
    return q


if __name__ == "__main__":
    print(*write_models(), *write_models(twin=True))


LATERAL = {1: 1e-4, 5: 3e-4}
"""The truth's lateral compliance [rad/(N m)]: the torso yaw bearing (the upper body tilts) and the
shoulder (hand deflection a few millimetres at most)."""


LATERAL_SPREAD = {1: 5e-5, 3: 2e-5, 5: 1e-4, 6: 5e-5, 8: 5e-5}
"""The two-arm diagnosis stand-in's lateral compliance [rad/(N m)] (issue 46, ``spread``): the torso
yaw and the lower torso pitch bearings, and in each arm the shoulder pitch and roll and the elbow;
with the twin's mirrored left arm, bearings of 8 joints beside the elasticity of 9."""


LEFT = 7
"""Joint k of the right arm (5..11) is joint k + 7 of the left arm in the twin (12..18)."""


def truth_effects(lateral: bool = False, twin: bool = False, spread: bool = False) -> tuple[str, ...]:
    """The truth's effect texts (:data:`ELASTICITY`, with ``lateral`` also :data:`LATERAL`, with
    ``spread`` :data:`LATERAL_SPREAD` instead); the ``twin``'s left arm has the right arm's (its
    joints :data:`LEFT` further on)."""
    el, lat = dict(ELASTICITY), dict(LATERAL_SPREAD if spread else LATERAL) if lateral or spread else {}
    if twin:
        el |= {j + LEFT: c for j, c in ELASTICITY.items() if j >= 5}
        lat |= {j + LEFT: c for j, c in lat.items() if j >= 5}
    out = [f"joint_elasticity:{j}={c}" for j, c in el.items()]
    return tuple(out + [f"lateral_compliance:{j}={c}" for j, c in lat.items()])


def stand_in_data(
    n_fit: int = 400,
    n_hold: int = 100,
    *,
    seed: int = 0,
    sigma_mm: float = 0.5,
    lateral: bool = False,
    twin: bool = False,
    spread: bool = False,
):
    """Simulated data of the stand-in: (model robot, fitted Measurements, held-out Measurements, truth).

    The truth is :func:`write_models`'s truth file with SPEC-sized geometric errors and
    :func:`truth_effects`; the measurements are read against the mass-free model file. The
    ``twin`` measures both hands at every pose (two rows a pose); ``spread``: the two-arm diagnosis
    stand-in (the twin with :data:`LATERAL_SPREAD`).
    """
    from kpioed_drake.robot.models import load_robot
    from kpioed_drake.tracker.data import Measurements

    name, table, rows, info = _truth_table(
        n_fit, n_hold, seed=seed, sigma_mm=sigma_mm, lateral=lateral, twin=twin or spread, spread=spread
    )
    model = load_robot(str(ROBOTS / f"{name}.urdf"))
    fit = Measurements.from_table(table.iloc[:rows].reset_index(drop=True), model, source="stand-in fit")
    hold = Measurements.from_table(
        table.iloc[rows:].reset_index(drop=True), model, source="stand-in held out"
    )
    return model, fit, hold, info


def _truth_table(
    n_fit: int, n_hold: int, *, seed: int, sigma_mm: float, lateral: bool, twin: bool, spread: bool = False
):
    """(model name, the simulated table of n_fit + n_hold poses, the fitted rows, the truth):
    the truth file with SPEC-sized geometric errors and :func:`truth_effects`, both hands of the
    ``twin`` at every pose (two rows a pose)."""
    from kpioed_drake.robot.models import load_robot
    from kpioed_drake.simulation import SimulationOptions, simulate

    name = TWIN if twin else NAME
    truth = load_robot(str(ROBOTS / f"{name}_truth.urdf"))
    q = poses(truth, n_fit + n_hold, seed)
    opts = SimulationOptions(
        sigma_mm=sigma_mm,
        seed=seed,
        effects=truth_effects(lateral, twin, spread),
        n_targets=2 if twin else None,
    )
    table, info = simulate(truth, q, opts)
    return name, table, 2 * n_fit if twin else n_fit, info


def _cpu() -> float:
    """CPU time of this process and of its finished children (the diagnosis's worker processes) [s]."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def measure(
    folder: Path,
    n_fit: int = 400,
    n_hold: int = 100,
    *,
    seed: int = 0,
    lateral: bool = False,
    twin: bool = False,
    spread: bool = False,
) -> dict:
    """The stand-in's experiment: geometric calibration against ``diagnose --out``, both validated
    on the held-out poses (``kpioed validate``, tracker frame kept: the same simulated set-up);
    files in ``folder``. The ``twin``: both hands at every pose, one calibration and one diagnosis
    of the 18 joints.

    Returns:
        ``geometric_mm`` / ``extended_mm`` (held-out mean 3-D error; per hand for the twin:
        ``*_per_target_mm``), ``named`` (the causes), ``diagnose_s`` and ``diagnose_cpu_s`` (the
        diagnosis's wall time and the CPU time of this process and its worker processes).
    """
    from kpioed_drake.calibration import CalibrationOptions
    from kpioed_drake.calibration.validate import validate_file
    from kpioed_drake.calibration.workflow import calibrate_file
    from kpioed_drake.diagnosis import DiagnosisOptions
    from kpioed_drake.diagnosis.workflow import diagnose_file

    twin = twin or spread
    name, table, rows, _ = _truth_table(
        n_fit, n_hold, seed=seed, sigma_mm=0.5, lateral=lateral, twin=twin, spread=spread
    )
    fit_csv, hold_csv = folder / "fit.csv", folder / "holdout.csv"
    table.iloc[:rows].to_csv(fit_csv, index=False)
    table.iloc[rows:].to_csv(hold_csv, index=False)
    model = str(ROBOTS / f"{name}.urdf")
    calibrate_file(model, fit_csv, CalibrationOptions(sigma_mm=0.5), out=folder / "geometric.urdf")
    t0, c0 = time.perf_counter(), _cpu()
    rep = diagnose_file(model, fit_csv, DiagnosisOptions(sigma_mm=0.5), out=folder / "extended.urdf")
    dt, cpu = time.perf_counter() - t0, _cpu() - c0
    out = {}
    for kind in ("geometric", "extended"):
        v = validate_file(str(folder / f"{kind}.urdf"), hold_csv)
        err = np.linalg.norm(v.residuals_W, axis=1)
        out[f"{kind}_mm"] = float(np.mean(err))
        if twin:
            t = np.asarray(table.iloc[rows:]["target"])
            out[f"{kind}_per_target_mm"] = [float(np.mean(err[t == k])) for k in (1, 2)]
    return out | {
        "named": [c.effect.name for c in rep.cause_records],
        "diagnose_s": dt,
        "diagnose_cpu_s": cpu,
        "baseline_holdout_rms_mm": rep.baseline["holdout_rms_mm"],
        "extended_holdout_rms_mm": rep.extended["holdout_rms_mm"],
    }


SECTION = "## 6. Diagnosis of the 11-joint elastic humanoid stand-in (no masses in the model file)"
TARGET_S = 60.0
"""Target wall time of the 1000-pose diagnosis on the 2-core machine [s]."""


def bench_section(sizes=(400, 1000)) -> tuple[list[str], dict]:
    """Markdown rows and a summary of ``diagnose`` (API, this process) on ``sizes`` poses of the
    stand-in (seed 1): wall and CPU time, the named causes, held-out RMS before and after."""
    from kpioed_drake.diagnosis import DiagnosisOptions, diagnose

    rows = [
        "| poses | wall [s] | CPU [s] | named | held-out RMS geometric -> extended [mm] |",
        "|---|---|---|---|---|",
    ]
    walls = {}
    for n in sizes:
        model, fit, _, _ = stand_in_data(n, 0, seed=1)
        t0, c0 = time.perf_counter(), time.process_time()
        rep = diagnose(model, fit, DiagnosisOptions(sigma_mm=0.5))
        walls[n] = time.perf_counter() - t0
        named = ", ".join(c.effect.name for c in rep.cause_records) or "-"
        rows.append(
            f"| {n} | {walls[n]:.1f} | {time.process_time() - c0:.1f} | {named} | "
            f"{rep.baseline['holdout_rms_mm']:.2f} -> {rep.extended['holdout_rms_mm']:.2f} |"
        )
    big = max(sizes)
    return rows, {"wall_s": walls[big], "n": big, "ratio": walls[big] / walls[min(sizes)]}


def section_lines(rows: list[str], summary: dict) -> list[str]:
    """The whole Markdown section."""
    return [
        SECTION,
        "",
        *rows,
        "",
        f"`bench/humanoid.py`: truth with link masses and joint elasticity (hand up to 21 mm), 0.5 mm noise, "
        f"poses with q4 = -(q2 + q3); {summary['n']} poses take {summary['ratio']:.1f}x the time of "
        f"the smallest size in this run. Load average after these rows: {os.getloadavg()[0]:.2f}.",
        "",
    ]


def targets_lines(summary: dict) -> list[str]:
    w = summary["wall_s"]
    return [
        f"- diagnosis of {summary['n']} poses of the 11-joint humanoid stand-in <= {TARGET_S:.0f} s: "
        f"measured {w:.1f} s ({'met' if w <= TARGET_S else 'NOT met'})"
    ]
