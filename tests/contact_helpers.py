"""Drake's forward kinematics of a contact design's tool points, shared by the contact design tests."""

import numpy as np

from kpioed_drake.robot.plant import MM, build_scene


def drake_tool_points(problem, q):
    """(n, 3) the tool point in W [mm] by Drake's forward kinematics (the plant, not the numpy model)."""
    scene = build_scene(problem.robot)
    out = []
    for qi in q:
        scene.set_q(qi)
        out.append(scene.X_WB(problem.robot.n_joints) @ (problem.model.p_FQ * MM) / MM)
    return np.array(out)
