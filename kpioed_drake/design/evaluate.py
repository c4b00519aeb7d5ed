"""``kpioed evaluate``: the KPI variance, standard criterion and feasibility of a given design file.

The covariance of eq. 19 (:meth:`~kpioed_drake.estimation.problem.Problem.covariances`) and the
independent feasibility check with Drake's signed distances
(:class:`~kpioed_drake.tracker.feasibility.FeasibilityChecker`, eq. 24b) of poses read from a CSV,
optionally with the optimality certificate
(:func:`~kpioed_drake.design.approximate.certificate.certify`) and a 3-D page.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_paths
from kpioed_drake.design.approximate.certificate import certificate_fields
from kpioed_drake.design.approximate.certificate import certify as certify_design
from kpioed_drake.errors import InputError, check_sigma
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import parse_q_work, read_design
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import load_robot
from kpioed_drake.scene3d import design_page
from kpioed_drake.tracker.feasibility import FeasibilityChecker, summarize


def evaluate_file(
    robot: str,
    design: str | Path,
    *,
    sigma_mm: float | None = None,
    q_work_deg: str | None = None,
    extend: Sequence[str] = (),
    json_path: str | Path | None = None,
    html: str | Path | None = None,
    cell_path: str | Path | None = None,
    certify: bool = True,
) -> dict:
    """KPI variance, standard criterion and feasibility of a design file (``kpioed evaluate``).

    Args:
        robot: model name or path of a model YAML file.
        design: CSV with columns ``q1_deg`` ... ``q6_deg``.
        sigma_mm: measurement noise per coordinate [mm] (default: the cell's).
        q_work_deg: ``"q1,...,q6"`` [deg] overriding the model's working pose.
        extend: model extensions (``"joint_elasticity:2"``, ``"gear_cyclic:4:2"``) whose parameters
            are estimated too; the KPI variance then includes them.
        json_path: write the returned dict as JSON.
        html: write a 3-D page (Meshcat) of the poses, their feasibility and the KPI ellipsoid.
        certify: compute ``bound_mm2`` (lower bound on tr(Cs)/3 of any design of as many poses
            avoiding collisions), ``efficiency``, ``design_beyond_search`` and ``certificate``
            (:func:`certify`; 4-13 s once per robot and setup, then cached on disk, and 1-4 s for
            the design). False: those fields are null.

    Returns:
        dict with ``kpi_avg_var_mm2`` (tr(Cs)/3), ``kpi_cov_mm2`` (3x3), ``param_crit`` (scaled
        tr(Cp)), ``n_params``, ``n_poses``, ``feasible`` and ``poses`` (per-pose feasibility),
        and the certificate's fields (null without ``certify``).
    """
    check_sigma(sigma_mm, allow_none=True)
    check_paths(robot=robot, inputs=[design], outputs=[json_path], html=html)
    rob = load_robot(robot)
    qw = parse_q_work(q_work_deg, rob) if q_work_deg else None
    prob = make_problem(rob, cell_path=cell_path, q_work=qw, sigma_mm=sigma_mm, extend=extend)
    q = read_design(design, rob)
    if len(q) < prob.min_poses():
        raise InputError(
            f"{design}: {len(q)} poses cannot determine {prob.n_params} parameters "
            f"({prob.rows_per_pose} coordinates per pose: at least {prob.min_poses()} poses are needed)"
        )
    Cp, Cs = prob.covariances(q)
    reports = FeasibilityChecker(prob.robot, prob.cell).check(q)
    result = {
        "robot": rob.name,
        "n_poses": int(len(q)),
        "n_params": prob.n_params,
        "extensions": [e.name for e in prob.extensions],
        "sigma_mm": prob.sigma,
        "q_work_deg": q_to_file(rob, prob.q_work).round(6).tolist(),
        "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
        "kpi_cov_mm2": Cs.tolist(),
        "param_crit": float(np.sum(np.diag(Cp) * prob.scale**2)),
        "feasible": all(r.feasible for r in reports),
        "feasibility": summarize(reports),
        "poses": [r.as_dict() for r in reports],
    }
    result.update(certificate_fields(certify_design(prob, q, collision=True) if certify else None))
    with Outputs() as staged:
        if json_path:
            staged.add_json(json_path, result)
        if html:
            page = design_page(prob.robot, prob.cell, q, reports=reports, q_work=prob.q_work, Cs=Cs)
            staged.add_text(html, page)
        staged.commit()
    return result
