"""URDFs as published: a sidecar's ``tip_link`` picks the measured chain of a tree (sensor branches
ignored), ``<mimic>`` joints follow their leader (an automatic joint map; the gauge is chosen on poses
the controller can command)."""

from __future__ import annotations

import numpy as np
import pytest

from kpioed_drake import calibration, simulation
from kpioed_drake.errors import InputError
from kpioed_drake.robot.models import MODELS_DIR, load_robot
from kpioed_drake.tracker.data import Measurements

ROBOTS = MODELS_DIR / "robots"
BRANCH = """  <link name="tilt_sensor"/>
  <joint name="tilt" type="revolute"><parent link="carriage"/><child link="tilt_sensor"/>
    <axis xyz="1 0 0"/><limit lower="-0.1" upper="0.1" effort="1" velocity="1"/></joint>
</robot>"""
"""A tilt-sensor branch on the carriage (a movable joint off the measured chain)."""


def _write(tmp_path, name: str, urdf: str, side_extra: str = "") -> str:
    (tmp_path / f"{name}.urdf").write_text(urdf)
    side = (ROBOTS / "lift7.kpioed.yaml").read_text().replace("name: lift7", f"name: {name}")
    (tmp_path / f"{name}.kpioed.yaml").write_text(side + side_extra)
    return str(tmp_path / f"{name}.urdf")


def test_a_branch_needs_tip_link_and_then_is_ignored(tmp_path):
    urdf = (ROBOTS / "lift7.urdf").read_text().replace("</robot>", BRANCH)
    with pytest.raises(InputError, match="the tree branches .*tip_link: LINK"):
        load_robot(_write(tmp_path, "branchy", urdf))
    robot = load_robot(_write(tmp_path, "tipped", urdf, "tip_link: flange\n"))
    plain = load_robot("lift7")
    assert robot.joint_names == plain.joint_names and robot.gauge == plain.gauge
    with pytest.raises(InputError, match="tip_link 'hand' is not a link"):
        load_robot(_write(tmp_path, "nohand", urdf, "tip_link: hand\n"))


def _telescoping(text: str) -> str:
    """lift7 with a two-stage column: ``lift`` moves a stage, ``lift2`` (mimic of lift, x1) the
    carriage on it."""
    old = '<joint name="lift" type="prismatic"><parent link="column"/><child link="carriage"/>'
    new = (
        '<joint name="lift" type="prismatic"><parent link="column"/><child link="stage"/>'
        '<origin xyz="0 0 0.05" rpy="0 0 0"/><axis xyz="0 0 1"/>'
        '<limit lower="0" upper="0.25" effort="5000" velocity="0.3"/></joint>\n'
        '  <link name="stage"><inertial><mass value="10"/>'
        '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>\n'
        '  <joint name="lift2" type="prismatic"><parent link="stage"/><child link="carriage"/>'
        '<mimic joint="lift" multiplier="1.0"/>'
    )
    assert old in text
    text = text.replace(old, new)
    first = '<origin xyz="0 0 0.05" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="0" upper="0.5"'
    return text.replace(
        first, '<origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="0" upper="0.25"', 1
    )


def test_mimic_joints_follow_their_leader_and_calibrate(tmp_path):
    urdf = _telescoping((ROBOTS / "lift7.urdf").read_text())
    side = "q_work: [50.0, 50.0, -16.1793, -22.9015, 2.9864, 92.0071, -84.1839, -7.1889]\n"
    text = (ROBOTS / "lift7.kpioed.yaml").read_text()
    text = "\n".join(
        line for line in text.splitlines() if not line.startswith(("q_work", "self_collision", "beam"))
    )
    (tmp_path / "tele.urdf").write_text(urdf)
    (tmp_path / "tele.kpioed.yaml").write_text(text.replace("name: lift7", "name: tele") + "\n" + side)
    robot = load_robot(str(tmp_path / "tele.urdf"))
    jm = robot.joint_map
    assert robot.n_joints == 8 and jm.axes == ("lift", "A1", "A2", "A3", "A4", "A5", "A6")
    J = np.column_stack([np.full(3, 100.0), np.zeros((3, 6))])
    q = jm.to_model(J)
    assert np.allclose(q[:, 1], q[:, 0])  # lift2 = lift
    rng = np.random.default_rng(6)
    lo_ax, up_ax = robot.lower[[0, 2, 3, 4, 5, 6, 7]], robot.upper[[0, 2, 3, 4, 5, 6, 7]]
    q = jm.to_model(rng.uniform(lo_ax, up_ax, size=(60, 7)) * 0.5)
    table, _ = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=2))
    report = calibration.calibrate(
        robot, Measurements.from_table(table, robot), calibration.CalibrationOptions(sigma_mm=0.02)
    )
    assert report.result.converged and report.chi2_per_dof < 1.5
