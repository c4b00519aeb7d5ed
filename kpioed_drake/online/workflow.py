"""``kpioed next`` on files: :func:`next_file`, one online step on a measurement file, the next poses,
the plan carried from step to step and the JSON record written."""

from __future__ import annotations

import os
from pathlib import Path

from kpioed_drake.arguments import check_paths
from kpioed_drake.calibration.inputs import read_inputs
from kpioed_drake.files import designs
from kpioed_drake.online.options import NextOptions
from kpioed_drake.online.report import NextReport
from kpioed_drake.online.step import next_poses
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import Robot


def next_file(
    robot: str,
    data_path: str | Path,
    options: NextOptions | None = None,
    *,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
    data_format: str | Path | None = None,
    cell_path: str | os.PathLike | None = None,
    plan_path: str | Path | None = None,
) -> tuple[NextReport, Robot]:
    """``kpioed next``: one step on a measurement file; ``out`` gets the next poses (a design CSV,
    nothing written when done), ``json_path`` the record; written after all succeeded.
    ``plan_path``: a design CSV carrying the plan from step to step: read if it exists (the
    previous plan, :func:`next_poses`), then replaced by this step's plan (removed when done).

    Returns:
        (result, robot).
    """
    check_paths(robot=robot, inputs=[data_path, data_format], outputs=[out, json_path, plan_path])
    rob, cell, data = read_inputs(
        robot, data_path, data_format, cell_path=cell_path, outputs=[out, json_path, plan_path]
    )
    previous = None
    if plan_path is not None and Path(plan_path).is_file():
        previous = designs.read_design(plan_path, rob)
    result = next_poses(rob, data, options, cell=cell, plan=previous)
    with Outputs() as staged:
        if out is not None and not result.done:
            staged.add_text(out, designs.design_csv_text(result.q_next, robot=rob))
        if plan_path is not None and not result.done:
            staged.add_text(plan_path, designs.design_csv_text(result.q_plan, robot=rob))
        if json_path is not None:
            staged.add_json(json_path, result.to_dict(rob))
        staged.commit()
    if plan_path is not None and result.done:
        Path(plan_path).unlink(missing_ok=True)
    return result, rob
