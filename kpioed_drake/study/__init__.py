"""The paper's studies (Tables 6, 7, 8; Figures 7, 8; sections 3.3-4): many independent design tasks,
run in parallel and resumable.

A study is a list of :class:`Task` (robot x design method x collision avoidance [x seed],
:mod:`.tasks`), run on local processes or a Dask cluster with one atomic result file per task
(:mod:`.runner`), summarised in Tables 6-8 beside the paper's numbers (:mod:`.tables`,
:mod:`kpioed_drake.paper`), a markdown report (:mod:`.report`) and Figures 7 and 8 (:mod:`.plots`).
Per robot a :class:`BoundTask` computes the lower bound on tr(Cs)/3 of any design (the optimality
certificate's search), joined into the rows and tables as each design's efficiency (:mod:`.bounds`).
:mod:`.workflow`: :func:`run_study` does all of it; :func:`regenerate_tables` rebuilds the tables of a
finished study with the bounds, without making the designs again; its outputs are a
:class:`StudyReport` (:mod:`.report`).

Beside the paper's study: :mod:`.variants`, named variants of the study's problem (the assumptions
the paper leaves open, one change each) and :mod:`.sensitivity`, Table 6 under each of them;
:mod:`.synthetic`, the diagnosis's self-test harness (simulated campaigns with hidden effects and a
known truth); :mod:`.authoring`, writing model files (kinematic rows, capsules, masses, ``q_work`` by
Drake inverse kinematics).
"""

from __future__ import annotations

from kpioed_drake.paper import PAPER
from kpioed_drake.study.report import StudyReport, make_report
from kpioed_drake.study.runner import run_tasks
from kpioed_drake.study.tables import RESULT_COLUMNS, make_tables, per_robot, ratios, results_frame
from kpioed_drake.study.tasks import (
    KUKA,
    METHODS,
    QUICK_NOTIONAL,
    BoundTask,
    Task,
    is_notional,
    make_tasks,
    notional_lambda_mu,
    run_task,
    study_robots,
)
from kpioed_drake.study.variants import DEFAULT, VARIANTS, Variant, get_variant, variant_problem
from kpioed_drake.study.workflow import regenerate_tables, run_study, write_outputs

__all__ = [
    "BoundTask",
    "DEFAULT",
    "KUKA",
    "METHODS",
    "PAPER",
    "QUICK_NOTIONAL",
    "RESULT_COLUMNS",
    "StudyReport",
    "Task",
    "VARIANTS",
    "Variant",
    "get_variant",
    "is_notional",
    "make_report",
    "make_tables",
    "make_tasks",
    "notional_lambda_mu",
    "per_robot",
    "ratios",
    "regenerate_tables",
    "results_frame",
    "run_study",
    "run_task",
    "run_tasks",
    "study_robots",
    "variant_problem",
    "write_outputs",
]
