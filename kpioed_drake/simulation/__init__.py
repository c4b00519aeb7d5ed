"""Simulated laser-tracker data: a true robot with random errors and effects, measured with noise.

- :mod:`.options`: :class:`SimulationOptions`, the settings of one simulation;
- :mod:`.truth`: the true robot (:func:`true_model`) and its simulated measurements (:func:`simulate`);
- :mod:`.workflow`: ``kpioed simulate`` (:func:`simulate_file`), CSV text and the truth's JSON.
"""

from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import random_rotation, simulate, true_model
from kpioed_drake.simulation.workflow import simulate_file, table_csv_text, truth_json

__all__ = [
    "SimulationOptions",
    "random_rotation",
    "simulate",
    "simulate_file",
    "table_csv_text",
    "true_model",
    "truth_json",
]
