"""Independent feasibility check of measurement poses (paper eq. 24b), optimiser-free.

For every pose: joint limits, the laser incidence angle (paper eq. 4), and the clearance of every
checked capsule pair computed by Drake's own signed-distance query
(``QueryObject.ComputeSignedDistancePairwiseClosestPoints``) on the MultibodyPlant + SceneGraph built
from the model files: robot vs floor, wall, mount and car, and the robot self pairs of the model.
The laser beam changes with the pose and is not SceneGraph geometry; its clearance to the robot
links and the car is a segment-segment distance (:func:`kpioed_drake.robot.geometry.segment_distance`,
itself tested against Drake's capsule-capsule distance), for the beam of every target the pose
measures (:func:`kpioed_drake.robot.geometry.beam_targets`).

A pose is feasible if every clearance is ``>= -tol_mm`` and every angle is within its limit up to
``tol_deg`` (defaults: 1 micrometre, 1e-6 degree: the optimiser's feasibility tolerance).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.robot.geometry import beam_targets, segment_distance
from kpioed_drake.robot.kinematics import Frames, flange_point, forward_kinematics
from kpioed_drake.robot.models import Cell, Robot
from kpioed_drake.robot.plant import MM, Scene, build_scene
from kpioed_drake.tracker.measurement import incidence_cosines, nominal_model

TOL_MM = 1e-3
"""A clearance counts as a collision below ``-TOL_MM`` [mm]."""
TOL_DEG = 1e-4
"""An angle counts as beyond its limit by more than this [deg]. Not tighter than the solver: SNOPT's
feasibility tolerance 1e-7 on the incidence row ``cos(beta) - cos(beta_max)`` allows 1.1e-5 deg at
beta_max = 30 deg, so a tighter check would reject SNOPT-optimal designs (docs/design.md)."""


@dataclasses.dataclass
class PoseReport:
    """Feasibility of one pose.

    Attributes:
        index: 0-based pose index.
        feasible: all checks passed.
        failures: list of ``{"check", "name", "value", "limit", "violation"}``; ``check`` is one of
            ``joint_limit`` [deg], ``incidence`` [deg], ``collision`` [mm], ``beam`` [mm].
        min_clearance_mm: smallest clearance over all checked pairs (robot and beam) [mm].
        min_clearance_pair: the pair that has it.
        incidence_deg: the incidence angle [deg].
    """

    index: int
    feasible: bool
    failures: list
    min_clearance_mm: float
    min_clearance_pair: str
    incidence_deg: float

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


class FeasibilityChecker:
    """Checks poses of ``robot`` in ``cell`` with Drake geometry queries.

    Args:
        robot, cell: the models (the cell as loaded for this robot, i.e. with its car shift).
        tol_mm: a clearance counts as a failure below ``-tol_mm`` [mm].
        tol_deg: an angle counts as a failure beyond its limit by more than ``tol_deg`` [deg].
    """

    def __init__(self, robot: Robot, cell: Cell, *, tol_mm: float = TOL_MM, tol_deg: float = TOL_DEG):
        self.robot, self.cell = robot, cell
        self.tol_mm, self.tol_deg = tol_mm, tol_deg
        self.scene: Scene = build_scene(robot, cell)
        self._beam_caps = [c for c in robot.capsules if c.frame in robot.beam_links]
        self._beam_obs = [o for o in cell.obstacles if o.moves_with_car]
        self._beams = beam_targets(robot, cell)
        self._model = nominal_model(robot, cell)

    def clearances(self, q: np.ndarray, *, frames: Frames | None = None) -> dict[str, float]:
        """All pair clearances [mm] of one pose: Drake pairs and the beam pairs (every target's
        beam: ``beam vs B``, several targets ``beam1 vs B`` .. ``beamT vs B``)."""
        q = np.asarray(q, dtype=float)
        sc = self.scene
        sc.set_q(q)
        out = {}
        for pr in sc.query_object().ComputeSignedDistancePairwiseClosestPoints(max_distance=100.0):
            a, b = sc.geometry_names[pr.id_A], sc.geometry_names[pr.id_B]
            if sc.geometry_link[pr.id_A] == -1 or (
                sc.geometry_link[pr.id_B] != -1 and sc.geometry_link[pr.id_A] > sc.geometry_link[pr.id_B]
            ):
                a, b = b, a
            out[f"{a} vs {b}"] = pr.distance / MM
        fr = forward_kinematics(self.robot, q) if frames is None else frames
        for label, p_FQ, link in self._beams:
            p_Q = flange_point(fr, p_FQ, link)[0]
            for c in self._beam_caps:
                A = fr.o[0, c.frame] + fr.R[0, c.frame] @ c.a
                B = fr.o[0, c.frame] + fr.R[0, c.frame] @ c.b
                d, _, _ = segment_distance(p_Q, self.cell.p_WT, A, B)
                out[f"{label} vs {c.name}"] = float(d) - c.radius - self.cell.beam_radius
            for o in self._beam_obs:
                d, _, _ = segment_distance(p_Q, self.cell.p_WT, o.a, o.b)
                out[f"{label} vs {o.name}"] = float(d) - o.radius - self.cell.beam_radius
        return out

    def incidence_deg(self, q: np.ndarray, *, frames: Frames | None = None) -> float:
        """Incidence angle of one pose [deg] (paper eq. 4); several targets: the largest."""
        c = np.min(incidence_cosines(self._model, np.atleast_2d(q), frames=frames)[0])
        return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))

    def check_pose(self, q: np.ndarray, index: int = 0, *, collision: bool = True) -> PoseReport:
        """Report of one pose ``q`` (6,) [rad]: joint limits, incidence and, with ``collision``,
        every robot and beam clearance (without, ``min_clearance_mm`` is inf)."""
        q = np.asarray(q, dtype=float)
        fails = []
        qd, lo, up = np.rad2deg(q), np.rad2deg(self.robot.lower), np.rad2deg(self.robot.upper)
        for j in range(self.robot.n_joints):
            if qd[j] < lo[j] - self.tol_deg or qd[j] > up[j] + self.tol_deg:
                lim = lo[j] if qd[j] < lo[j] else up[j]
                fails.append(
                    dict(
                        check="joint_limit",
                        name=self.robot.joint_names[j],
                        value=float(qd[j]),
                        limit=float(lim),
                        violation=float(abs(qd[j] - lim)),
                    )
                )
        fr = forward_kinematics(self.robot, q)
        inc = self.incidence_deg(q, frames=fr)
        max_inc = float(np.rad2deg(self.cell.max_incidence))
        if inc > max_inc + self.tol_deg:
            fails.append(
                dict(check="incidence", name="reflector", value=inc, limit=max_inc, violation=inc - max_inc)
            )
        clear = self.clearances(q, frames=fr) if collision else {}
        pair, cmin = ("", float("inf"))
        for name, d in clear.items():
            if d < cmin:
                pair, cmin = name, d
            if d < -self.tol_mm:
                kind = "beam" if name.startswith("beam") else "collision"
                fails.append(dict(check=kind, name=name, value=d, limit=0.0, violation=-d))
        return PoseReport(index, not fails, fails, cmin, pair, inc)

    def check(self, q: np.ndarray, *, collision: bool = True) -> list[PoseReport]:
        """Reports for (n, 6) poses [rad]."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return [self.check_pose(qi, i, collision=collision) for i, qi in enumerate(q)]


def summarize(reports: list[PoseReport]) -> dict:
    """Counts of failing poses per check."""
    out = {"n_poses": len(reports), "n_infeasible": sum(not r.feasible for r in reports)}
    for check in ("joint_limit", "incidence", "collision", "beam"):
        out[f"n_{check}"] = sum(any(f["check"] == check for f in r.failures) for r in reports)
    return out
