"""Joint maps of any size: model joint = sum of factors times controller axes plus an offset; the
controller may have fewer axes than the model has joints (a passive joint coupled to others)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import simulation
from kpioed_drake.design import heuristic_design, optimize_design
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.robot.jointmap import CouplingSpec, JointMapSpec, joint_map_from_spec, joint_map_spec
from kpioed_drake.robot.models import MODELS_DIR, load_robot
from kpioed_drake.tracker.data import Measurements, read_data

COUPLED = """joint_map:
  controller_axes: [c0, c1, c2, c3, c4, c5]
  joints:
    {lift: {c0: 1}, A1: {c1: 1}, A2: {c2: 1}, A3: {c3: 1}, A4: {c4: 1}, A5: {c5: 1}, A6: {c4: -1, c5: -1}}
  offsets_deg: {A2: 10.0, lift: 5.0}
"""
"""lift7 with a passive last joint: A6 = -(A4 + A5), six controller axes for seven joints."""


@pytest.fixture(scope="module")
def coupled(tmp_path_factory):
    work = tmp_path_factory.mktemp("jm")
    shutil.copy(MODELS_DIR / "robots" / "lift7.urdf", work / "c.urdf")
    side = (MODELS_DIR / "robots" / "lift7.kpioed.yaml").read_text().replace("name: lift7", "name: lift7c")
    (work / "c.kpioed.yaml").write_text(side + COUPLED)
    return load_robot(str(work / "c.urdf")), work


def test_the_general_form_equals_the_six_joint_coupling_form():
    """Fanuc's q3 = J3 + J2 written both ways; a joint neither given nor an axis is an error."""
    six = joint_map_from_spec(
        JointMapSpec(couplings=[CouplingSpec(joint=3, from_joint=2, factor=1.0)]), "six"
    )
    names = [f"A{i}" for i in range(1, 7)]
    general = joint_map_from_spec(
        JointMapSpec(controller_axes=names, joints={"A3": {"A3": 1, "A2": 1}}), "general", joint_names=names
    )
    assert_allclose(general.A, six.A, atol=0)
    missing = "joint 'A1' is not given and no controller axis has its name"
    with pytest.raises(InputError, match=missing):
        joint_map_from_spec(
            JointMapSpec(controller_axes=["x"], joints={"A2": {"x": 1}}), "g", joint_names=["A1", "A2"]
        )


def test_fewer_axes_than_joints_map_and_invert(coupled):
    robot, _ = coupled
    jm = robot.joint_map
    assert jm.A.shape == (7, 6) and jm.n_axes == 6
    J = np.random.default_rng(2).uniform(-0.3, 0.3, size=(20, 6))
    q = jm.to_model(J)
    assert_allclose(q[:, 6], -(q[:, 4] + q[:, 5]), atol=1e-12)
    assert_allclose(q[:, 2] - J[:, 2], np.deg2rad(10.0), atol=1e-12)
    assert_allclose(q[:, 0] - J[:, 0], 5.0, atol=1e-12)  # the lift's offset in mm
    assert_allclose(jm.to_controller(q), J, atol=1e-12)
    broken = q.copy()
    broken[3, 6] += 0.01
    with pytest.raises(InputError, match="pose 4: its joint values break the joint map's coupling"):
        jm.to_controller(broken)
    back = joint_map_from_spec(
        joint_map_spec(jm), "again", joint_names=robot.joint_names, prismatic=robot.prismatic
    )
    assert_allclose(back.A, jm.A, atol=0) and assert_allclose(back.b, jm.b, atol=1e-15)


def test_a_controller_file_in_axes_reads_as_model_angles(coupled):
    robot, work = coupled
    rng = np.random.default_rng(4)
    J = np.column_stack([rng.uniform(50, 400, 30), rng.uniform(-0.3, 0.3, (30, 5))])
    J[:, 1:] = np.rad2deg(J[:, 1:])
    q = robot.joint_map.to_model(np.column_stack([J[:, 0], np.deg2rad(J[:, 1:])]))
    table, _ = simulation.simulate(robot, q, simulation.SimulationOptions(sigma_mm=0.02, seed=1))
    data = Measurements.from_table(table, robot)
    lines = [" ".join(f"{v:.9f}" for v in [*J[i], *data.eta[i]]) for i in range(30)]
    (work / "ctrl.txt").write_text("\n".join(lines) + "\n")
    (work / "ctrl.yaml").write_text(
        "header: false\ncolumns: [c0, c1, c2, c3, c4, c5, x, y, z]\nseparator: whitespace\n"
        "joints: [c0, c1, c2, c3, c4, c5]\nposition: {x: x, y: y, z: z}\n"
    )
    read = read_data(work / "ctrl.txt", robot, work / "ctrl.yaml")
    assert_allclose(read.q, data.q, atol=1e-7)
    assert_allclose(read.eta, data.eta, atol=1e-6)


@pytest.mark.parametrize(
    "section, match",
    [
        ("joint_map: {controller_axes: [a, a], joints: {}}\n", "distinct names"),
        ("joint_map: {controller_axes: [a], joints: {nope: {a: 1}}}\n", "'nope' is not a joint"),
        (
            "joint_map: {controller_axes: [lift, A1, A2, A3, A4, A5, A6], joints: {A1: {zz: 1}}}\n",
            "'zz' is not in controller_axes",
        ),
        ("joint_map: {sign: [1, 1, 1, 1, 1, 1, 1]}\n", "use controller_axes and joints"),
    ],
)
def test_bad_general_maps_name_the_file_and_field(tmp_path, section, match):
    shutil.copy(MODELS_DIR / "robots" / "lift7.urdf", tmp_path / "b.urdf")
    side = (MODELS_DIR / "robots" / "lift7.kpioed.yaml").read_text().replace("name: lift7", "name: lift7b")
    (tmp_path / "b.kpioed.yaml").write_text(side + section)
    with pytest.raises(InputError, match=f"b.kpioed.yaml: joint_map.*{match}"):
        load_robot(str(tmp_path / "b.urdf"))


def test_designs_of_a_coupled_robot_are_commandable(coupled):
    """A6 = -(A4 + A5): the heuristic draws on the coupling, the optimiser keeps it (one linear
    equality per pose), and the poses go to the controller's six axes."""
    robot, _ = coupled
    N, c = robot.joint_map.coupling_equations()
    assert N.shape == (1, 7)
    problem = make_problem(robot)
    q0 = heuristic_design(problem, n=15, seed=1)
    assert_allclose(q0 @ N.T, np.broadcast_to(c, (15, 1)), atol=1e-9)
    res = optimize_design(problem, criterion="kpi", n=15, seed=1, start="heuristic")
    assert res.feasible
    assert_allclose(res.q @ N.T, np.broadcast_to(c, (15, 1)), atol=1e-7)
    J = robot.joint_map.to_controller(res.q)
    assert J.shape == (15, 6)
    assert res.kpi_avg_var_mm2 < problem.criteria(q0)["kpi_avg_var_mm2"]
