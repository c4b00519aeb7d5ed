"""``kpioed next`` on a 6-DoF probe's data (position and orientation per pose).

The fit uses the orientations; the next poses are pose measurements designed with the problem of
``design --measure pose`` (the predicted KPI recomputed through :func:`make_problem`; at nominal the
step is ``design --measure pose --given``); the stopping rule reads the KPI with the orientation
(``v_pos + L^2 v_rot``, with ``target_deg`` ``L = sqrt(V) / target_deg``: done exactly when
``v_pos / V + (std / target_deg)^2 <= 1``) and the summary names the orientation's precision; two
simulated steps on the kr16 give feasible poses and a better orientation; orientation options for
point data or both weights at once exit 2 with one line, and so does ``diagnose`` on pose data.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from kpioed_drake import api
from kpioed_drake.cli import main
from kpioed_drake.estimation.problem import make_problem
from kpioed_drake.files.designs import read_design, write_design
from kpioed_drake.online import NextOptions, next_poses
from kpioed_drake.robot.models import load_cell
from kpioed_drake.simulation import SimulationOptions, simulate, table_csv_text
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.feasibility import FeasibilityChecker

SIGMA_MM = 0.02
SIGMA_DEG = 0.005
N_START = 20


def _simulate(kr16, q, work, *, seed=8, noise=True):
    options = SimulationOptions(
        sigma_mm=SIGMA_MM if noise else 0.0,
        seed=seed,
        orientation_sigma_deg=SIGMA_DEG if noise else 0.0,
        geometric_errors=noise,
    )
    table, _ = simulate(kr16, q, options)
    (work / "data.csv").write_text(table_csv_text(table))
    return table


@pytest.fixture(scope="module")
def measured(kr16, tmp_path_factory):
    """20 random poses of a kr16 with geometric errors, measured with a probe (0.02 mm, 0.005 deg)."""
    work = tmp_path_factory.mktemp("online-pose")
    q = np.random.default_rng(7).uniform(kr16.lower, kr16.upper, size=(N_START, 6))
    write_design(work / "given.csv", q)
    _simulate(kr16, read_design(work / "given.csv", kr16), work)
    return work


def _now(kr16, work, **orientation):
    data = Measurements.from_table(pd.read_csv(work / "data.csv"), kr16)
    return next_poses(
        kr16, data, NextOptions(target_var_mm2=1e9, sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG, **orientation)
    )


def test_the_kpi_with_the_orientation_and_the_done_rule(kr16, measured):
    now = _now(kr16, measured)
    assert now.done and now.orientation_std_deg is not None and now.kpi_orientation_mm == 0.0
    assert now.kpi_avg_var_mm2 == pytest.approx(now.position_var_mm2, rel=1e-12)  # L = 0: the position
    L = 300.0
    weighted = _now(kr16, measured, kpi_orientation_mm=L)
    v_rot = math.radians(weighted.orientation_std_deg) ** 2
    assert weighted.kpi_avg_var_mm2 == pytest.approx(now.position_var_mm2 + L**2 * v_rot, rel=1e-12)
    for share in (0.9, 1.1):  # done exactly when v_pos / V + (std / D)^2 <= 1
        V, D = now.position_var_mm2 / 0.5 * share, now.orientation_std_deg / math.sqrt(0.5) * share
        data = Measurements.from_table(pd.read_csv(measured / "data.csv"), kr16)
        opts = NextOptions(
            target_var_mm2=V, target_deg=D, sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG, certify=False
        )
        if share > 1:
            rep = next_poses(kr16, data, opts)
            assert rep.done and "done" in rep.summary()
            assert now.position_var_mm2 / V + (now.orientation_std_deg / D) ** 2 <= 1.0
        else:
            assert now.position_var_mm2 / V + (now.orientation_std_deg / D) ** 2 > 1.0


def test_two_steps_design_feasible_pose_measurements(kr16, measured, quick_certificate, quick_start):
    now = _now(kr16, measured)
    V, D = 0.5 * now.position_var_mm2, 0.6 * now.orientation_std_deg
    kw = dict(target_var_mm2=V, target_deg=D, sigma_mm=SIGMA_MM, sigma_deg=SIGMA_DEG, n=5, certify=False)
    rec = api.next("kr16", measured / "data.csv", out=measured / "next.csv", plan=measured / "plan.csv", **kw)
    assert not rec["done"] and rec["n_measured"] == N_START and rec["n_next"] == 5
    o = rec["orientation"]
    assert o["target_deg"] == D and o["kpi_orientation_mm"] == pytest.approx(math.sqrt(V) / math.radians(D))
    assert "orientation precision" in rec["summary"] and "deg RMS per axis" in rec["summary"]
    q_next = read_design(measured / "next.csv", kr16)
    assert all(r.feasible for r in FeasibilityChecker(kr16, load_cell(robot=kr16)).check(q_next))
    # the design's problem is design --measure pose's at the noise used
    problem = make_problem(
        kr16,
        sigma_mm=rec["sigma_used_mm"],
        measure="pose",
        sigma_deg=o["sigma_deg_used"],
        kpi_orientation_mm=o["kpi_orientation_mm"],
    )
    both = np.concatenate([read_design(measured / "given.csv", kr16), q_next])
    assert_allclose(problem.criteria(both)["kpi_avg_var_mm2"], rec["predicted_kpi_avg_var_mm2"], rtol=1e-9)
    assert_allclose(np.sqrt(problem.tcp_variances(both)[1][0]), o["predicted_orientation_std_deg"], rtol=1e-9)
    # measure them (the same true robot, fresh noise) and step again with the plan carried over
    table = _simulate(kr16, both, measured)
    assert len(table) == N_START + 5
    again = api.next(
        "kr16", measured / "data.csv", out=measured / "next.csv", plan=measured / "plan.csv", **kw
    )
    assert again["n_measured"] == N_START + 5
    assert again["orientation"]["orientation_std_deg"] < o["orientation_std_deg"]
    if not again["done"]:
        q2 = read_design(measured / "next.csv", kr16)
        assert all(r.feasible for r in FeasibilityChecker(kr16, load_cell(robot=kr16)).check(q2))


def test_next_at_nominal_with_poses_is_design_given_measure_pose(
    kr16, tmp_path, quick_certificate, quick_start
):
    """Noise-free nominal pose data (the estimate is the nominal model, chi2 0): a target the next
    batch reaches gives the five poses of ``design --measure pose --given``."""
    q = np.random.default_rng(3).uniform(kr16.lower, kr16.upper, size=(N_START, 6))
    write_design(tmp_path / "given.csv", q)
    _simulate(kr16, read_design(tmp_path / "given.csv", kr16), tmp_path, noise=False)
    L = 500.0
    now = _now(kr16, tmp_path, kpi_orientation_mm=L)
    kw = dict(sigma_mm=SIGMA_MM, kpi_orientation_mm=L, certify=False)
    rec = api.next("kr16", tmp_path / "data.csv", target_var_mm2=0.9 * now.kpi_avg_var_mm2, n=5,
                   sigma_deg=SIGMA_DEG, out=tmp_path / "next.csv", **kw)  # fmt: skip
    assert not rec["done"] and not rec["aposteriori"] and rec["n_planned"] == 5
    res = api.design("kr16", criterion="kpi", n=5, measure="pose", sigma_deg=SIGMA_DEG,
                     given=tmp_path / "given.csv", out=tmp_path / "design.csv", **kw)  # fmt: skip
    assert np.array_equal(
        read_design(tmp_path / "next.csv", kr16), read_design(tmp_path / "design.csv", kr16)
    )
    assert_allclose(rec["predicted_kpi_avg_var_mm2"], res.kpi_avg_var_mm2, rtol=1e-9)


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--target-deg", "0.01"], "hold no orientations"),
        (["--kpi-orientation-mm", "200"], "hold no orientations"),
    ],
)
def test_orientation_options_on_point_data_exit_2(kr16, tmp_path, capsys, extra, needle):
    q = np.random.default_rng(4).uniform(kr16.lower, kr16.upper, size=(15, 6))
    table, _ = simulate(kr16, q, SimulationOptions(sigma_mm=SIGMA_MM, seed=1))
    (tmp_path / "points.csv").write_text(table_csv_text(table))
    code = main(["next", "--robot", "kr16", str(tmp_path / "points.csv"), "--target-var", "0.1", *extra,
                 "--out", str(tmp_path / "next.csv")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "points.csv" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "next.csv").exists()


def test_both_orientation_weights_exit_2(measured, tmp_path, capsys):
    code = main(["next", "--robot", "kr16", str(measured / "data.csv"), "--target-var", "0.1",
                 "--target-deg", "0.01", "--kpi-orientation-mm", "200"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "--target-deg" in err and "not both" in err and len(err.strip().splitlines()) == 1


def test_diagnose_refuses_pose_data_naming_what_it_takes(measured, capsys):
    """Not the loop, the same data: ``diagnose`` refuses orientations in one line naming what it takes."""
    code = main(["diagnose", "--robot", "kr16", str(measured / "data.csv")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "data.csv" in err
    assert "takes positions" in err and "without the orientation columns" in err and "format file" in err
