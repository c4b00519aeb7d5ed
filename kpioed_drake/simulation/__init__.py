"""Simulated laser-tracker data: a true robot with random errors and effects, measured with noise.

- :mod:`.options`: :class:`SimulationOptions`, the settings of one simulation;
- :mod:`.truth`: the true robot (:func:`true_model`) and its simulated measurements (:func:`simulate`);
- :mod:`.workflow`: ``kpioed simulate`` (:func:`simulate_file`), CSV text and the truth's JSON;
- :mod:`.contacts`: distance and plane-contact data of a true robot (:func:`simulate_distances`,
  :func:`simulate_planes`) and the truth in a fitted model's parameter vector.
"""

from kpioed_drake.simulation.contacts import simulate_distances, simulate_planes, truth_parameters
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import random_rotation, simulate, true_model
from kpioed_drake.simulation.workflow import simulate_file, table_csv_text, truth_json

__all__ = [
    "SimulationOptions",
    "random_rotation",
    "simulate",
    "simulate_distances",
    "simulate_file",
    "simulate_planes",
    "table_csv_text",
    "true_model",
    "truth_parameters",
    "truth_json",
]
