"""``kpioed compensate``: a program or a target file in, the compensated joint values out.

Input files are CSVs with a header (rows numbered as everywhere: header = row 1):

- a *program* (``--program``): the joint values a nominal controller commands, one pose per row,
  columns ``q1_deg`` ... (a prismatic joint ``q{i}_mm``), as a design file;
- *targets* (``--targets``): points in W, columns ``x_mm``, ``y_mm``, ``z_mm`` [mm], with optional
  start joint columns (without them every row starts from the model's ``q_work``).

Both may carry ``temperature_C``, ``payload_kg`` and ``time_s`` (the effects' conditions) and any
other columns. With ``angles="controller"`` the joint columns hold controller angles: the model
file's ``joint_map`` (:mod:`kpioed_drake.robot.jointmap`) turns them into model angles and the
output back into controller angles (no map: the same angles).

Output: the input's columns in its order, the joint columns holding the solution (added in front
for targets without them) and every other column's text unchanged, plus ``residual_mm`` (the
model's remaining distance from the goal), ``dq_deg`` (the largest change of a joint in the output's
angles [deg; a prismatic joint's in mm]), ``reachable`` (1 or 0) and, for targets,
``orientation_deg`` (the flange orientation's change from the start). A row that is not reachable
is an error naming its row and reason (nothing written, exit 3) unless ``allow_unreachable``.

The models: ``robot`` is the calibrated model file (``kpioed calibrate --out``); the nominal model
(programs) is ``nominal``, by default the model whose name the file's name carries before
``-calibrated`` (as ``calibrate --out`` names it), else the file itself. Effects with estimated
values come as an argument (:func:`effects_argument`) or from an extended model file's
``effects:`` (:func:`file_effects`).
"""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kpioed_drake.arguments import check_paths, require
from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.compensation.report import CompensationReport
from kpioed_drake.compensation.solve import (
    TOL_MM,
    TOL_RAD,
    Compensation,
    compensate_program,
    reach_targets,
)
from kpioed_drake.effects import model_effects, parse_effect, resolve
from kpioed_drake.effects.model import Effect
from kpioed_drake.errors import InputError, SolverError
from kpioed_drake.files.tables import OPTIONAL_COLUMNS, XYZ_COLUMNS, read_joint_table
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.jointmap import q_columns, q_to_file
from kpioed_drake.robot.models import Robot, load_cell, load_robot
from kpioed_drake.tracker.measurement import TrackerModel, nominal_model

ANGLES = ("model", "controller")
"""What the joint columns hold: the model's angles, or the controller's (through the joint map)."""
OUTPUT_COLUMNS = ("residual_mm", "dq_deg", "reachable")
ORIENTATION_COLUMN = "orientation_deg"
CALIBRATED_SUFFIX = "-calibrated"
EffectsArgument = Effect | str | Sequence[Effect | str] | CalibrationReport | dict
"""What ``effects`` may be (:func:`effects_argument`): effects or their texts, or a calibration report."""


def file_effects(robot: Robot) -> tuple[Effect, ...]:
    """The estimated effects an extended model file carries (``effects:``; the one place they enter)."""
    return tuple(model_effects(robot))


def _report_model(model: TrackerModel, report: dict) -> TrackerModel:
    """``model`` with the robot-side estimates (joint rows, target offsets) of an extended fit's report."""
    lay, p = model.layout, model.p.copy()
    robot_side = set(range(lay.joints.stop)) | set(range(lay.targets.start, lay.targets.stop))
    for d in report.get("parameters", []):
        if d.get("name") not in lay.names:
            raise InputError(
                f"effects: the calibration report's parameter {d.get('name')!r} is not one of "
                f"{model.robot.name}'s"
            )
        i = lay.names.index(d["name"])
        if i in robot_side:
            p[i] = np.deg2rad(d["value"]) if d.get("unit") == "deg" else float(d["value"])
    return model.with_params(p)


def _report_effect(d: dict, model: TrackerModel) -> Effect:
    """An effect of an extended fit's report (display units) with its estimated value."""
    parts = [d.get("effect", "?")] + [str(d[k]) for k in ("joint", "harmonic", "coupled_joint") if k in d]
    values = np.atleast_1d(d.get("value", []))
    return parse_effect(":".join(parts) + "=" + ",".join(repr(float(v)) for v in values), model=model)


def effects_argument(
    model: TrackerModel, effects: EffectsArgument
) -> tuple[TrackerModel, tuple[Effect, ...]]:
    """The calibrated model and its effects from the ``effects`` argument.

    Args:
        model: the model file's model.
        effects: effects with estimated values: :class:`~kpioed_drake.effects.model.Effect`
            objects or texts (``"joint_elasticity:2=7.7e-7"``, display units); or the report of an
            extended calibration (:class:`~kpioed_drake.calibration.report.CalibrationReport` or its
            JSON dict): its effects, and its joint rows and target offsets replace the file's (they
            were estimated together).
            Empty: the model file's own (:func:`file_effects`).

    Raises:
        InputError: an effect without a value, a report of another robot or with unknown names.
    """
    if isinstance(effects, CalibrationReport):
        effects = effects.to_dict()
    if isinstance(effects, dict):
        if effects.get("robot") not in (model.robot.name, model.robot.name.removesuffix(CALIBRATED_SUFFIX)):
            raise InputError(
                f"effects: the calibration report is of robot {effects.get('robot')!r}, "
                f"not {model.robot.name!r}"
            )
        model = _report_model(model, effects)
        return model, tuple(_report_effect(d, model) for d in effects.get("effects", []))
    if isinstance(effects, str):
        effects = [effects]
    out = []
    for e in effects or file_effects(model.robot):
        e = resolve(parse_effect(e, model=model) if isinstance(e, str) else e, model)
        if e.values is None:
            raise InputError(
                f"effects: {e.name} has no value; give the estimated one ('{e.name}=...')",
                fields=("effects",),
            )
        out.append(e)
    return model, tuple(out)


def _nominal_robot(robot: Robot, nominal: str | None) -> Robot:
    """The controller's model: ``nominal``, else the model named before ``-calibrated``, else ``robot``."""
    if nominal is None and not robot.name.endswith(CALIBRATED_SUFFIX):
        return robot
    name = nominal if nominal is not None else robot.name.removesuffix(CALIBRATED_SUFFIX)
    try:
        nom = load_robot(name)
    except InputError as exc:
        hint = "" if nominal is not None else f" (the nominal model of {robot.name}; give it as nominal)"
        raise InputError(f"{exc}{hint}", fields=(*exc.fields, "nominal")) from None
    if nom.n_joints != robot.n_joints or nom.conventions != robot.conventions:
        raise InputError(
            f"nominal {name}: its joints ({nom.n_joints}, {', '.join(nom.conventions)}) are not those of "
            f"{robot.name} ({robot.n_joints}, {', '.join(robot.conventions)})",
            fields=("nominal",),
        )
    return nom


def _check_target(target, *robots: Robot) -> int:
    """The 0-based target of ``target`` (1-based, as in files), defined by every model."""
    n = min(r.n_targets for r in robots)
    ok = isinstance(target, int | np.integer) and not isinstance(target, bool) and 1 <= target <= n
    require(
        ok,
        f"target: expected a number in 1..{n} (the targets the models define), got {target!r}",
        fields=("target",),
    )
    return int(target) - 1


@dataclasses.dataclass(frozen=True)
class _Table:
    """An input file: header, text rows, row numbers, model joint values, points and conditions."""

    path: str
    header: list[str]
    data: list[list[str]]
    rows: np.ndarray
    q: np.ndarray | None
    points: np.ndarray | None
    conditions: dict


def _read_table(path, robot: Robot, *, program: bool, angles: str) -> _Table:
    """Read and check a program or target file through the one table reader (joint values to model
    angles, limits checked)."""
    t = read_joint_table(
        path,
        robot,
        joints="required" if program else "optional",
        required=() if program else XYZ_COLUMNS,
        optional=OPTIONAL_COLUMNS,
        angles=angles,
    )
    points = None if program else np.stack([t.values[c] for c in XYZ_COLUMNS], axis=1)
    cond = {c: t.values[c] for c in OPTIONAL_COLUMNS if c in t.values}
    return _Table(t.path, t.header, list(t.data), t.rows, t.q, points, cond)


def _check_conditions(table: _Table, effects) -> None:
    for e in effects:
        if e.family == "thermal_expansion" and "temperature_C" not in table.conditions:
            raise InputError(f"{table.path}: row 1 (header): effect {e.name} needs column 'temperature_C'")


def _output_text(
    table: _Table, robot: Robot, q_file: np.ndarray, dq: np.ndarray, res: Compensation, mode: str
) -> str:
    """The output CSV: the input's columns (joint columns replaced or added) and the results."""
    qcols = list(q_columns(robot))
    added = list(OUTPUT_COLUMNS) + ([ORIENTATION_COLUMN] if mode == "targets" else [])
    keep = [h for h in table.header if h not in added]
    header = keep if qcols[0] in keep else qcols + keep
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header + added)
    for k, cells in enumerate(table.data):
        raw = dict(zip(table.header, cells, strict=True))
        raw.update({c: f"{v:.10f}" for c, v in zip(qcols, q_file[k], strict=True)})
        extra = [f"{res.residual_mm[k]:.3g}", f"{dq[k]:.6f}", "1" if res.reachable[k] else "0"]
        if mode == "targets":
            extra.append(f"{np.rad2deg(res.residual_rad[k]):.6f}")
        w.writerow([raw[h] for h in header] + extra)
    return buf.getvalue()


def _start_poses(table: _Table, robot: Robot) -> np.ndarray:
    if table.q is not None:
        return table.q
    if robot.q_work is None:
        raise InputError(
            f"{table.path}: no start joint columns and {robot.name} has no q_work; "
            f"add columns {', '.join(q_columns(robot))}"
        )
    return np.tile(robot.q_work, (table.rows.size, 1))


def compensate_file(
    robot: str,
    *,
    program: str | Path | None = None,
    targets: str | Path | None = None,
    out: str | Path,
    nominal: str | None = None,
    target: int = 1,
    angles: str = "model",
    effects: EffectsArgument = (),
    allow_unreachable: bool = False,
    cell_path: Path | str | None = None,
) -> CompensationReport:
    """Compensate a program or reach target points with a calibrated model (``kpioed compensate``).

    Args:
        robot: the calibrated model (name or file, e.g. what ``kpioed calibrate --out`` wrote).
        program: program CSV (nominal joint values); targets: target CSV (points in W); exactly one.
        out: the CSV to write (atomically, after everything succeeded).
        nominal: the controller's nominal model (programs; default see the module docstring).
        target: the target (1-based) whose point is compensated (default 1, the reflector/tool point).
        angles: ``"model"`` or ``"controller"`` (the joint columns in and out, :data:`ANGLES`).
        effects: estimated effects (:func:`effects_argument`; an extended calibration's report too).
        allow_unreachable: write rows that cannot be reached, marked ``reachable`` 0, instead of failing.
        cell_path: cell file (default ``models/cell.yaml``: reflector, when a model file has none).

    Returns:
        :class:`CompensationReport`.

    Raises:
        InputError: bad arguments or files (the file, row and column named).
        SolverError: rows that cannot be reached within the joint limits to ``TOL_MM`` (and
            ``TOL_RAD`` for programs), each named with its row and reason; nothing is written.
    """
    _check_arguments(program, targets, nominal, angles, allow_unreachable)
    source = program if program is not None else targets
    check_paths(robot=robot, inputs=[source], outputs=[out])
    rob = load_robot(robot)
    model, effs = effects_argument(nominal_model(rob, load_cell(cell_path, robot=rob)), effects)
    table = _read_table(source, rob, program=program is not None, angles=angles)
    _check_conditions(table, effs)
    kw = dict(effects=effs, conditions=table.conditions)
    nom = None
    if program is not None:
        nom = _nominal_robot(rob, nominal)
        t = _check_target(target, rob, nom)
        res = compensate_program(
            model, nominal_model(nom, load_cell(cell_path, robot=nom)), table.q, target=t, **kw
        )
    else:
        res = reach_targets(
            model, table.points, _start_poses(table, rob), target=_check_target(target, rob), **kw
        )
    to_out = (
        rob.joint_map.to_controller if angles == "controller" and rob.joint_map is not None else (lambda x: x)
    )
    q_file = q_to_file(rob, to_out(res.q))
    dq = np.max(np.abs(q_file - q_to_file(rob, to_out(res.q_start))), axis=1)
    if not allow_unreachable:
        _check_reached(res, table, source, program=program is not None)
    mode = "program" if program is not None else "targets"
    text = _output_text(table, rob, q_file, dq, res, mode)
    with Outputs() as staged:
        staged.add_text(out, text)
        staged.commit()
    return CompensationReport(
        robot=rob.name,
        nominal=None if nom is None else nom.name,
        source=str(source),
        mode=mode,
        out=str(out),
        rows=table.rows,
        q=q_file,
        dq=dq,
        result=res,
        effects=tuple(e.text() for e in effs),
        text=text,
    )


def _check_arguments(
    program: Path | str | None,
    targets: Path | str | None,
    nominal: str | None,
    angles: str,
    allow_unreachable: bool,
) -> None:
    """InputError unless exactly one of program and targets is given, ``angles`` is one of
    :data:`ANGLES`, ``allow_unreachable`` a bool and ``nominal`` comes with a program."""
    require(
        (program is None) != (targets is None),
        "give exactly one of program and targets",
        fields=("program", "targets"),
    )
    require(
        angles in ANGLES, f"angles: expected one of {', '.join(ANGLES)}, got {angles!r}", fields=("angles",)
    )
    require(
        isinstance(allow_unreachable, bool),
        f"allow_unreachable: expected True or False, got {allow_unreachable!r}",
    )
    require(
        nominal is None or program is not None,
        "nominal is used with a program only",
        fields=("nominal", "program"),
    )


def _check_reached(res: Compensation, table: _Table, source: Path | str, *, program: bool) -> None:
    """SolverError naming the rows (the first five) that cannot be reached, if any."""
    bad = np.flatnonzero(~res.reachable)
    if not bad.size:
        return
    named = "; ".join(f"row {table.rows[k]}: {res.reasons[k]}" for k in bad[:5]) + (
        "; ..." if bad.size > 5 else ""
    )
    what = f"{TOL_MM:g} mm" + (f" and {TOL_RAD:g} rad" if program else "")
    raise SolverError(
        f"{source}: {bad.size} of {table.rows.size} rows cannot be reached within the joint "
        f"limits to {what}: "
        f"{named} (nothing written; allow_unreachable writes them marked reachable=0)",
        fields=("allow_unreachable",),
    )
