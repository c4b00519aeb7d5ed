"""``kpioed simulate``: simulated tracker data of a design file, written atomically.

The measurement table's CSV text (:func:`table_csv_text`), the truth's JSON (:func:`truth_json`) and
the file workflow (:func:`simulate_file`) over :func:`kpioed_drake.simulation.truth.simulate`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from kpioed_drake.arguments import check_paths, check_positive
from kpioed_drake.files.designs import read_condition_offsets, read_design
from kpioed_drake.outputs import Outputs
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import (
    ORIENTATION_COLUMNS,
    ORIENTATION_DECIMALS,
    Q_DECIMALS,
    XYZ_DECIMALS,
    simulate,
)


def table_csv_text(table: pd.DataFrame) -> str:
    """CSV text of a measurement table (joint angles to 1e-8 deg, positions to 1e-6 mm)."""
    out = table.copy()
    for c in [c for c in out.columns if c.startswith("q") and c.endswith(("_deg", "_mm"))]:
        out[c] = out[c].map(lambda v: f"{v:.{Q_DECIMALS}f}")
    for c in ("x_mm", "y_mm", "z_mm"):
        out[c] = out[c].map(lambda v: f"{v:.{XYZ_DECIMALS}f}")
    for c in [c for c in ORIENTATION_COLUMNS if c in out]:
        out[c] = out[c].map(lambda v: f"{v:.{ORIENTATION_DECIMALS}f}")
    for c in ("temperature_C", "time_s", "payload_kg"):
        if c in out:
            out[c] = out[c].map(lambda v: f"{v:.6g}")
    return out.to_csv(index=False, lineterminator="\n")


def truth_json(truth: dict) -> dict:
    """The JSON-serialisable part of a truth dict."""

    def effect_repr(e):
        return e.to_dict() if hasattr(e, "to_dict") else str(e)

    return {
        "robot": truth["robot"],
        "parameters": truth["parameters"],
        "R_WT": np.asarray(truth["R_WT"]).tolist(),
        "p_WT_mm": np.asarray(truth["p_WT_mm"]).tolist(),
        "effects": [effect_repr(e) for e in truth["effects"]],
        "sigma_mm": truth["sigma_mm"],
        "seed": truth["seed"],
        "geometric_errors": truth["geometric_errors"],
        "n_targets": truth["n_targets"],
        **(
            {}
            if truth.get("R_FP") is None
            else {
                "probe_R_FP": np.asarray(truth["R_FP"]).tolist(),
                "orientation_sigma_deg": truth["orientation_sigma_deg"],
            }
        ),
        "targets_mm": truth["model"].target_offsets[: truth["n_targets"]].tolist(),
    }


def simulate_file(
    robot: str,
    design: str,
    out: str,
    options: SimulationOptions | None = None,
    *,
    payload_kg: float = 0.0,
    truth_path: str | None = None,
    cell_path: Path | str | None = None,
) -> tuple[pd.DataFrame, dict]:
    """Simulated laser-tracker data of a design file (``kpioed simulate``), written atomically.

    Args:
        robot: model name or YAML path; design: design CSV; out: measurement CSV to write.
        options: :class:`~kpioed_drake.simulation.options.SimulationOptions` (noise, seed, effects,
            geometric errors, targets per pose: one row per pose and target, with a ``target``
            column when several).
        payload_kg: payload at the reflector [kg] (>= 0).
        truth_path: also write the true parameters as JSON.
        cell_path: cell file (default ``models/cell.yaml``).

    Returns:
        (table, truth): the measurement table (pandas) and the truth dict. Nothing is written unless
        the whole simulation succeeds.
    """
    check_positive("payload_kg", payload_kg, zero_ok=True)
    check_paths(robot=robot, inputs=[design], outputs=[out, truth_path])
    rob = load_robot(robot)
    q = read_design(design, rob)
    table, truth = simulate(
        rob,
        q,
        options,
        payload_kg=payload_kg,
        condition_offsets=read_condition_offsets(design),
        cell=load_cell(cell_path, robot=rob),
    )
    with Outputs() as staged:
        staged.add_text(out, table_csv_text(table))
        if truth_path:
            staged.add_json(truth_path, truth_json(truth))
        staged.commit()
    return table, truth
