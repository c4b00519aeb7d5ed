"""The Python API: one documented function per command-line command.

Example::

    from kpioed_drake import api
    print(api.info("kr16")["n_params"])                     # 27
    report = api.evaluate("kr16", "design.csv")              # the design's KPI variance
    print(report["kpi_avg_var_mm2"], report["feasible"])

Units follow the files: millimetres and degrees in and out.
"""

from __future__ import annotations

import numpy as np

from kpioed_drake.designio import parse_q_work, read_design
from kpioed_drake.errors import InputError
from kpioed_drake.identifiability import check_identifiability
from kpioed_drake.measurement import parameter_layout
from kpioed_drake.models import load_cell, load_robot
from kpioed_drake.problem import make_problem


def info(robot: str, *, cell_path=None) -> dict:
    """What the tool knows about a robot.

    Returns:
        dict with ``robot``, ``reach_mm``, ``q_work_deg``, ``joint_limits_deg``, ``parameters``
        (all 33 names), ``estimated`` (the 27), ``fixed`` (the 6 held at nominal), ``n_params``
        (identifiable count from a rank test at random poses), ``identifiable`` (bool) and
        ``unidentifiable`` (names, if any).
    """
    rob = load_robot(robot)
    rep = check_identifiability(rob, load_cell(cell_path, robot=rob))
    lay = parameter_layout(rob)
    return {
        "robot": rob.name,
        "reach_mm": rob.reach,
        "q_work_deg": None if rob.q_work is None else np.rad2deg(rob.q_work).round(6).tolist(),
        "joint_limits_deg": np.rad2deg(np.stack([rob.lower, rob.upper], 1)).round(6).tolist(),
        "parameters": list(lay.names),
        "estimated": lay.free_names,
        "fixed": [n for n in lay.names if n not in lay.free_names],
        "n_params": rep.rank,
        "identifiable": rep.identifiable,
        "unidentifiable": rep.unidentifiable,
        "car_shift_x_mm": rob.car_shift_x,
    }


def evaluate(
    robot: str,
    design: str,
    *,
    sigma_mm: float | None = None,
    q_work_deg: str | None = None,
    cell_path=None,
    extend=(),
) -> dict:
    """KPI variance, standard criterion and feasibility of a design file.

    Args:
        robot: model name or path of a model YAML file.
        design: CSV with columns ``q1_deg`` ... ``q6_deg``.
        sigma_mm: measurement noise per coordinate [mm] (default: the cell's).
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        extend: model extensions (``"joint_elasticity:2"``, ``"gear_cyclic:4:2"``) whose parameters
            are estimated too; the KPI variance then includes them.

    Returns:
        dict with ``kpi_avg_var_mm2`` (tr(Cs)/3), ``kpi_cov_mm2`` (3x3), ``param_crit`` (scaled
        tr(Cp)), ``n_params``, ``n_poses``, ``feasible`` and ``poses`` (per-pose feasibility).
    """
    from kpioed_drake.feasibility import FeasibilityChecker, summarize

    rob = load_robot(robot)
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    prob = make_problem(rob, cell_path=cell_path, q_work=qw, sigma_mm=sigma_mm, extend=extend)
    q = read_design(design, rob)
    if len(q) < prob.min_poses():
        raise InputError(
            f"{design}: {len(q)} poses cannot determine {prob.n_params} parameters "
            f"(3 coordinates per pose: at least {prob.min_poses()} poses are needed)"
        )
    Cp, Cs = prob.covariances(q)
    reports = FeasibilityChecker(prob.robot, prob.cell).check(q)
    return {
        "robot": rob.name,
        "n_poses": int(len(q)),
        "n_params": prob.n_params,
        "extensions": [e.name for e in prob.extensions],
        "sigma_mm": prob.sigma,
        "q_work_deg": np.rad2deg(prob.q_work).round(6).tolist(),
        "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
        "kpi_cov_mm2": Cs.tolist(),
        "param_crit": float(np.sum(np.diag(Cp) * prob.scale**2)),
        "feasible": all(r.feasible for r in reports),
        "feasibility": summarize(reports),
        "poses": [r.as_dict() for r in reports],
    }


# The other commands' library functions, re-exported so that the API has one entry point.
def design(robot: str, **kwargs):
    """Optimum experimental design (``kpioed design``); see :func:`kpioed_drake.design.run_design`."""
    from kpioed_drake.design import run_design

    return run_design(robot, **kwargs)


def simulate(robot: str, design_path: str, out: str, **kwargs):
    """Simulated tracker data (``kpioed simulate``); see :func:`kpioed_drake.simulation.simulate_file`."""
    from kpioed_drake.simulation import simulate_file

    return simulate_file(robot, design_path, out, **kwargs)


def calibrate(robot: str, data_path: str, **kwargs):
    """Calibration from measured data (``kpioed calibrate``); see
    :func:`kpioed_drake.calibration.calibrate_file`."""
    from kpioed_drake.calibration import calibrate_file

    return calibrate_file(robot, data_path, **kwargs)


def diagnose(robot: str, data_path: str, **kwargs):
    """Model-discrepancy diagnosis (``kpioed diagnose``); see :func:`kpioed_drake.diagnosis.diagnose`."""
    from kpioed_drake.diagnosis import diagnose as _diagnose

    return _diagnose(robot, data_path, **kwargs)


def study(out_dir: str, **kwargs):
    """The paper's studies (``kpioed study``); see :func:`kpioed_drake.study.run_study`."""
    from kpioed_drake.study import run_study

    return run_study(out_dir, **kwargs)
