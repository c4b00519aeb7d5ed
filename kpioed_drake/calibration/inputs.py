"""The inputs of a command on a measurement file, loaded once: :func:`read_inputs` (``kpioed
calibrate``, ``validate``, ``diagnose`` and ``next``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from kpioed_drake.arguments import check_paths
from kpioed_drake.robot.models import Cell, Robot, load_cell, load_robot
from kpioed_drake.robot.urdf.write import check_out_path, sidecar_of
from kpioed_drake.tracker.data import Measurements, read_data


def read_inputs(
    robot: str | Path,
    data_path: str | Path,
    data_format: str | Path | None = None,
    *,
    cell_path: str | Path | None = None,
    model_out: str | Path | None = None,
    outputs: Sequence[str | Path | None] = (),
    folders: Sequence[str | Path | None] = (),
    html: str | Path | None = None,
) -> tuple[Robot, Cell, Measurements]:
    """The robot, cell and measurements of a command on a data file, each loaded once, after the
    paths are checked (:func:`~kpioed_drake.arguments.check_paths`).

    Args:
        model_out: a model file to write (a ``.urdf`` brings its sidecar; it must suit the robot).
        outputs, folders, html: the command's other output files, output folders and 3-D page.

    Returns:
        (robot, cell, data).

    Raises:
        InputError: a bad path, robot, cell or data file.
    """
    side = sidecar_of(model_out) if model_out is not None and Path(str(model_out)).suffix == ".urdf" else None
    check_paths(
        robot=robot,
        inputs=[data_path, data_format],
        outputs=[model_out, side, *outputs],
        folders=list(folders),
        html=html,
    )
    rob = load_robot(robot)
    check_out_path(rob, model_out)
    return rob, load_cell(cell_path, robot=rob), read_data(data_path, rob, data_format)
