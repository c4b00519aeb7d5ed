"""The contact design's file workflow (``kpioed design`` of planes or a ballbar): :func:`contact_design_file`.

Builds the problem of the measurement system (:data:`CONTACT_PROBLEMS`: the planes of a file or the
robot's default set; a pivot and bar length, default the working TCP and 150 mm), computes the KPI
design and its certificate (:func:`~kpioed_drake.design.contact.design.contact_design`, the search
settings :data:`SEARCH`, those of the studies), checks every pose independently with Drake's
signed distances (:class:`~kpioed_drake.tracker.feasibility.FeasibilityChecker` in the pose's cell:
for a ballbar the pivot's stand an obstacle and the bar as the beam) and writes:

- the design CSV: the joint columns [deg], the plane id (``plane``, 1-based) or the pivot id
  (``pivot``, 1-based) and the bar's nominal length (``length_mm``) per pose, and
  ``min_clearance_mm``: a plane-contact file, or a distance file of pivot rows once the measured
  lengths replace ``length_mm`` (docs/contacts.md), ready for ``kpioed calibrate``;
- the JSON record: the figures, the certificate, the gauge, the planes or pivots and every pose.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_count, check_paths, check_positive, check_seed
from kpioed_drake.design.approximate.certificate import certificate_line
from kpioed_drake.design.contact.design import ContactDesign, contact_design
from kpioed_drake.design.contact.inputs import parse_pivot, robot_planes
from kpioed_drake.design.contact.problem import (
    BALLBAR_SIGMA_MM,
    ContactProblem,
    contact_problem,
    make_ballbar_problem,
)
from kpioed_drake.errors import InputError
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files import designs
from kpioed_drake.outputs import Outputs, jsonable
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Robot, load_robot
from kpioed_drake.tracker.feasibility import FeasibilityChecker

SEARCH = {"pool": 1000, "starts": 48, "verify": 2000}
"""The design's search (:func:`contact_design`'s settings): candidates, local searches a round, fresh
poses verified."""
SYSTEM_ROUNDS = {"plane": 40, "ballbar": 120}
"""Most column-generation rounds by default, per system: a ballbar's one row a pose needs more (kr16:
largest g still 1.53 after 40 rounds, efficiency 0.597; converged after 130 with 120, 0.954)."""
PLANE_SIGMA_MM = 0.01
"""A touch's noise along the normal [mm] (a touch probe)."""


@dataclasses.dataclass(frozen=True)
class ContactDesignReport:
    """A contact design, its problem and the independent check of its poses.

    Attributes:
        design: the poses, figures and certificate; problem: the identification problem.
        clearance: (n,) each pose's smallest clearance by Drake [mm]; pair: (n,) which pair.
        search: the search's settings; seed, collision: as given.
    """

    design: ContactDesign
    problem: ContactProblem
    clearance: np.ndarray
    pair: tuple[str, ...]
    search: dict
    seed: int
    collision: bool

    def certificate(self) -> dict:
        """The certificate as :func:`~kpioed_drake.design.approximate.certificate.certify` records it."""
        d, n = self.design, len(self.design.q)
        return {
            "bound_mm2": d.bound,
            "efficiency": d.efficiency,
            "value_mm2": d.value,
            "n_poses": n,
            "design_beyond_search": d.design_beyond_search,
            "approximate_mm2": d.phi / n,
            "g_max": d.g_max,
            "n_candidates": d.n_candidates,
            "n_local_searches": d.n_searched,
            "rounds": d.rounds,
            "converged": d.converged,
            "method": "dual bound tr(K^T Y)^2 / (n max_x ||F_x Y||^2) with Y from the cone program over "
            "the column generation's candidates on the surfaces; max over the candidates, fresh feasible "
            "poses, the local maxima from the best of them and the design's poses (a search of the "
            "feasible set)",
        }

    def record(self) -> dict:
        """The JSON record of the run."""
        pr, d, S = self.problem, self.design, self.problem.surfaces
        columns = _surface_columns(pr, d)
        poses = [
            {
                "q_deg": q_to_file(pr.robot, qi).tolist(),
                **{c: v[i] for c, v in columns.items()},
                "min_clearance_mm": float(self.clearance[i]),
                "min_clearance_pair": self.pair[i],
            }
            for i, qi in enumerate(d.q)
        ]
        return jsonable(
            {
                "robot": pr.robot.name,
                "measure": pr.measure,
                "n": len(d.q),
                "sigma_mm": pr.sigma,
                "q_work_deg": q_to_file(pr.robot, pr.q_work).tolist(),
                "collision": self.collision,
                "seed": self.seed,
                "search": self.search,
                "kpi_avg_var_mm2": d.value,
                **{k: self.certificate()[k] for k in ("bound_mm2", "efficiency", "design_beyond_search")},
                "certificate": self.certificate(),
                f"{S.kind}s": S.record(),
                f"poses_per_{S.kind}": np.bincount(d.surface, minlength=len(S)).tolist(),
                "estimated": pr.param_names,
                "gauge": {"held": list(pr.gauge.names), "why": pr.gauge.describe().splitlines()},
                "poses": poses,
            }
        )

    def summary(self) -> str:
        """Printed lines: what was designed, its tr(Cs)/3, the certificate, the gauge and the poses."""
        pr, d, S = self.problem, self.design, self.problem.surfaces
        n = len(d.q)
        where = (
            f"touches of {len(S)} planes"
            if S.kind == "plane"
            else "poses of a pivot ballbar ("
            + "; ".join(
                f"pivot {k + 1} at {np.round(c, 1).tolist()} mm, bar {L:g} mm"
                for k, (c, L) in enumerate(zip(S.centres, S.lengths, strict=True))
            )
            + ")"
        )
        per = ", ".join(str(c) for c in np.bincount(d.surface, minlength=len(S)))
        k = int(np.argmin(self.clearance))
        return "\n".join(
            [
                f"KPI design of {pr.robot.name}: {n} {where}, sigma {pr.sigma:g} mm",
                f"  tr(Cs)/3 = {d.value:.4g} mm^2 at the working pose",
                f"  {certificate_line(self.certificate())}",
                f"  search: {d.rounds} rounds ({'converged' if d.converged else 'not converged'}, largest g "
                f"{d.g_max:.4g}), {d.n_candidates} candidates, {d.n_searched} local searches",
                f"  poses per {S.kind}: {per}; smallest clearance {self.clearance[k]:.1f} mm "
                f"({self.pair[k]})",
                *(f"  {line}" for line in pr.gauge.describe().splitlines()),
            ]
        )


def _surface_columns(problem: ContactProblem, design: ContactDesign) -> dict[str, np.ndarray]:
    """The design CSV's columns after the joints: ``plane`` or ``pivot`` (1-based), ``length_mm``."""
    S = problem.surfaces
    if S.kind == "plane":
        return {"plane": design.surface + 1}
    return {"pivot": design.surface + 1, "length_mm": S.lengths[design.surface].astype(float)}


def _clearances(problem: ContactProblem, q: np.ndarray, surface: np.ndarray) -> tuple[np.ndarray, tuple]:
    """Each pose's smallest clearance [mm] and its pair by Drake's signed distances in the pose's cell
    (a plane touch: the robot's pairs, no beam; a ballbar pose: with the stand, the bar as ``bar``)."""
    S = problem.surfaces
    checkers = [FeasibilityChecker(problem.robot, c) for c in S.cells(problem.cell)]
    out, pairs = np.zeros(len(q)), []
    for i, (qi, k) in enumerate(zip(q, surface, strict=True)):
        clear = checkers[k if len(checkers) > 1 else 0].clearances(qi)
        clear = {
            name.replace("beam", "bar", 1): v
            for name, v in clear.items()
            if S.beam or not name.startswith("beam")
        }
        pair = min(clear, key=clear.get)
        out[i] = clear[pair]
        pairs.append(pair)
    return out, tuple(pairs)


def _plane_problem(
    robot: Robot, q_work, sigma_mm, collision: bool, seed: int, *, planes=None, **_
) -> ContactProblem:
    """The plane problem of a plane set (a file, or the robot's default)."""
    base = make_problem(robot, q_work=q_work, sigma_mm=PLANE_SIGMA_MM if sigma_mm is None else sigma_mm)
    return contact_problem(base, robot_planes(robot, planes), collision=collision, seed=seed)


def _ballbar_problem(
    robot: Robot, q_work, sigma_mm, collision: bool, seed: int, *, pivot_mm=None, bar_length_mm=None, **_
) -> ContactProblem:
    """The ballbar problem of a pivot (text ``x,y,z`` or numbers; default the working TCP) and bar."""
    pivot = parse_pivot(pivot_mm) if isinstance(pivot_mm, str) else pivot_mm
    check_positive("bar_length_mm", bar_length_mm, allow_none=True)
    return make_ballbar_problem(
        robot,
        pivot,
        150.0 if bar_length_mm is None else bar_length_mm,
        q_work=q_work,
        sigma_mm=BALLBAR_SIGMA_MM if sigma_mm is None else sigma_mm,
        collision=collision,
    )


CONTACT_PROBLEMS = {"plane": _plane_problem, "ballbar": _ballbar_problem}
"""The contact measurement systems a design can be made for, and how their problem is built."""
PROBLEM_SEED = 20170710
"""Seed of the gauge's poses on the surfaces (as :func:`make_plane_problem`'s default)."""


def _checked(measure: str, n: int, seed: int, rounds: int | None, planes, pivot_mm, bar_length_mm):
    """The arguments that need no problem, checked."""
    if measure not in CONTACT_PROBLEMS:
        raise InputError(
            f"measure: expected one of {', '.join(CONTACT_PROBLEMS)}, got {measure!r}", fields=("measure",)
        )
    check_count("n", n, at_least=1)
    check_seed(seed)
    check_count("rounds", rounds, at_least=1, allow_none=True)
    unused = {"plane": ("pivot_mm", "bar_length_mm"), "ballbar": ("planes",)}[measure]
    given = {"planes": planes, "pivot_mm": pivot_mm, "bar_length_mm": bar_length_mm}
    if wrong := [name for name in unused if given[name] is not None]:
        raise InputError(f"{', '.join(wrong)}: not used by a {measure} design", fields=tuple(wrong))


def contact_design_file(
    robot: str,
    measure: str,
    *,
    planes: str | Path | None = None,
    pivot_mm: str | Sequence[float] | None = None,
    bar_length_mm: float | None = None,
    n: int = 40,
    sigma_mm: float | None = None,
    seed: int = 0,
    collision: bool = True,
    q_work_deg: str | Sequence[float] | None = None,
    rounds: int | None = None,
    out: str | Path | None = None,
    json_path: str | Path | None = None,
) -> ContactDesignReport:
    """The KPI design of a contact system and its certificate, with its files (module docstring).

    Args:
        robot: model name or robot file.
        measure: ``plane`` (touches of planes) or ``ballbar`` (a pivot ballbar).
        planes: ``plane``: a plane-set YAML or CSV file (:mod:`.inputs`; default the robot's
            ``models/planes/NAME.yaml``).
        pivot_mm: ``ballbar``: the pivot in W [mm], ``"x,y,z"`` or 3 numbers (default the TCP at
            the working pose); bar_length_mm: the bar's nominal length (default 150 mm).
        n: poses; sigma_mm: the row's noise [mm] (default 0.01: a touch probe; a ballbar at the
            robot's repeatability); seed: the search's seed; collision: avoid collisions.
        q_work_deg: the working pose [deg] (``"q1,...,qN"`` or numbers; default the model's).
        rounds: most column-generation rounds (default :data:`SYSTEM_ROUNDS` of the system).
        out: the design CSV; json_path: the JSON record.

    Raises:
        InputError: bad arguments or files, a system without enough feasible poses, a design the
            parameters are not determined by.
    """
    rob = load_robot(robot)
    _checked(measure, n, seed, rounds, planes, pivot_mm, bar_length_mm)
    check_positive("sigma_mm", sigma_mm, allow_none=True)
    check_paths(robot=robot, inputs=[planes], outputs=[out, json_path])
    q_work = None if q_work_deg is None else designs.parse_q_work(
        q_work_deg if isinstance(q_work_deg, str) else ",".join(repr(float(v)) for v in q_work_deg), rob
    )  # fmt: skip
    problem = CONTACT_PROBLEMS[measure](
        rob,
        q_work,
        sigma_mm,
        collision,
        PROBLEM_SEED,
        planes=planes,
        pivot_mm=pivot_mm,
        bar_length_mm=bar_length_mm,
    )
    search = SEARCH | {"rounds": SYSTEM_ROUNDS[measure] if rounds is None else rounds}
    des = contact_design(problem, n, seed=seed, collision=collision, **search)
    clearance, pair = _clearances(problem, des.q, des.surface)
    report = ContactDesignReport(des, problem, clearance, pair, search, seed, collision)
    with Outputs() as staged:
        if out is not None:
            extra = {**_surface_columns(problem, des), "min_clearance_mm": clearance}
            staged.add_text(out, designs.design_csv_text(des.q, extra, robot=rob))
        if json_path is not None:
            staged.add_json(json_path, report.record())
        staged.commit()
    return report
