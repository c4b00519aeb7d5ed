"""Distance and plane-contact measurements (tracker/distance.py, tracker/plane.py, tracker/contacts.py):
Jacobians against finite differences (kr16, the lift7 URDF chain), simulate -> fit recovering the
truth within 3 sigma (distances, planes, points with planes, distances with planes), the covariance
of the stacked whitened Jacobian, the gauge, and the data checks."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import chi2, norm

from kpioed_drake.errors import InputError
from kpioed_drake.estimation.estimator import estimate
from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.robot.parameters import parameter_layout
from kpioed_drake.simulation.contacts import simulate_distances, simulate_planes, truth_parameters
from kpioed_drake.simulation.options import SimulationOptions
from kpioed_drake.simulation.truth import simulate
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.contacts import ContactRows, contact_model
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.distance import distance_jacobian, distance_residuals
from kpioed_drake.tracker.measurement import nominal_model, reflector_world
from kpioed_drake.tracker.plane import plane_jacobian, plane_normals, plane_residuals

NORMALS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 1.0]])
NORMALS /= np.linalg.norm(NORMALS, axis=1, keepdims=True)
OFFSETS = np.array([400.0, -900.0, -700.0, 1300.0])
"""Four planes in the kr16's reach [mm]: a table, two walls facing the robot, a tilted plane."""


def _nominal(name):
    robot = load_robot(name)
    return robot, nominal_model(robot, load_cell(robot=robot))


def _poses(robot, n, rng):
    return rng.uniform(robot.lower, robot.upper, size=(n, robot.n_joints))


def _plane_poses(robot, model, per_plane, seed, normals=NORMALS, offsets=OFFSETS):
    """Commanded poses whose nominal tool point is within 20 mm of its plane, the flange on the
    normal's side with the tool within 73 deg of the normal (the touch probe comes from there)."""
    q = _poses(robot, 60000, np.random.default_rng(seed))
    p = reflector_world(model, q)
    o_F = model.frames(q).at_link(None)[1]
    tool = np.einsum("ni,ki->nk", o_F - p, normals) / np.linalg.norm(o_F - p, axis=1)[:, None]
    out = []
    for k in range(len(offsets)):
        ok = np.flatnonzero((np.abs(p @ normals[k] - offsets[k]) < 20.0) & (tool[:, k] > 0.3))[:per_plane]
        assert ok.size == per_plane
        out.append(q[ok])
    return np.concatenate(out), np.repeat(np.arange(len(offsets)), per_plane)


def _perturbed(model, rng):
    p = model.p + np.where(
        model.layout.is_angle, rng.normal(0, 0.02, model.p.size), rng.normal(0, 1.0, model.p.size)
    )
    return model.with_params(p)


def _fd(f, model, h=1e-6):
    """Central differences of ``f(model)`` (m,) over every parameter: (m, n_full)."""
    cols = []
    for k in range(model.p.size):
        dp = np.zeros(model.p.size)
        dp[k] = h
        cols.append((f(model.with_params(model.p + dp)) - f(model.with_params(model.p - dp))) / (2 * h))
    return np.stack(cols, axis=1)


def _two_targets(model):
    """``model`` with a second tool point (target 1) on the flange."""
    lay = parameter_layout(model.robot, n_targets=2)
    return dataclasses.replace(model, p=np.concatenate([model.p, [30.0, -40.0, 250.0]]), layout=lay)


@pytest.mark.parametrize("name", ["kr16", "lift7"])
def test_jacobians_match_finite_differences(name):
    """Pair, pivot and bar rows and plane rows (tilted away from their references, second target
    on half of the rows): every column of the closed form against central differences."""
    robot, model = _nominal(name)
    model = _two_targets(model)
    rng = np.random.default_rng(3)
    n = 12
    q, q2 = _poses(robot, n, rng), _poses(robot, n, rng)
    target = np.arange(n) % 2
    dist = DistanceData.from_arrays(
        q,
        900.0,
        q_other=q2,
        pivot=np.where(np.arange(n) < 8, np.arange(n) % 2, -1),
        bar=np.arange(n) % 3 - 1,
        target=target,
    )
    planes = PlaneData.from_arrays(
        _poses(robot, 9, rng), np.arange(9) % 3, distance_mm=0.3, target=np.arange(9) % 2
    )
    full, _ = contact_model(model, distances=dist, planes=planes, q_points=q[:6], target_points=target[:6])
    full = _perturbed(full, rng)
    assert np.abs(full.p[full.layout.plane_columns(np.arange(3))[:, :2]]).min() > 1e-4
    r, H = distance_jacobian(full, dist)
    assert_allclose(r, distance_residuals(full, dist), atol=1e-12)
    assert_allclose(H, _fd(lambda m: distance_residuals(m, dist), full), atol=2e-6, rtol=1e-6)
    lay = full.layout
    assert (
        not np.any(H[:, lay.tracker])
        and np.any(H[:, lay.target(1)])
        and np.all(H[:, lay.bar_columns([1])][dist.bar == 1] == -1)
    )
    r, H = plane_jacobian(full, planes)
    assert_allclose(r, plane_residuals(full, planes), atol=1e-12)
    assert_allclose(H, _fd(lambda m: plane_residuals(m, planes), full), atol=2e-6, rtol=1e-6)
    assert not np.any(H[:, lay.tracker]) and not np.any(H[:, lay.bar_columns([0, 1])])


def _z(res, truth):
    """z-scores of the estimated parameters against the truth (the estimate's a-priori std) and
    their Mahalanobis distance."""
    true = truth_parameters(res.model, truth)
    free = res.model.layout.free
    e = res.model.p[free] - true[free]
    return e / res.std, float(e @ np.linalg.solve(res.Cp, e))


def _recovered(res, truth):
    """Every estimated parameter within 3 sigma of the truth but at most one, which stays within the
    family-wise 1 % bound of the k parameters (k ~ 40 independent z-scores exceed 3 about one time in
    ten: the seeds were fixed before the first run); the Mahalanobis distance within chi^2_k's 99.9 %
    quantile; chi^2/dof near 1."""
    z, d2 = _z(res, truth)
    k = res.n_params
    bound = norm.ppf(1 - (1 - 0.99 ** (1 / k)) / 2)
    detail = dict(zip(res.free_names, np.round(z, 2), strict=True))
    assert res.converged
    assert np.count_nonzero(np.abs(z) > 3.0) <= 1 and np.abs(z).max() < bound, detail
    assert d2 < chi2.ppf(0.999, k), (d2, k)
    assert 0.5 < res.chi2_per_dof < 1.6


def test_distances_recover_the_truth():
    """80 rows: 30 to a pivot (its position estimated), 30 pairs of known length, 20 pairs of a bar
    of unknown length: every free parameter within 3 sigma."""
    robot, model = _nominal("kr16")
    rng = np.random.default_rng(5)
    n = 80
    q, q2 = _poses(robot, n, rng), _poses(robot, n, rng)
    kw = dict(q_other=q2, pivot=np.where(np.arange(n) < 30, 0, -1), bar=np.where(np.arange(n) >= 60, 0, -1))
    _, gauge = contact_model(model, distances=DistanceData.from_arrays(q, 1.0, **kw))
    assert gauge.held == ()  # the robot side is determined up to the points' gauge
    data, truth = simulate_distances(robot, q, pivots=np.array([[800.0, 200.0, 300.0]]), seed=4, **kw)
    res = estimate(model, None, None, distances=data)
    assert res.dof == n - res.n_params and {"pivot1_x", "bar1_dL"} <= set(res.free_names)
    assert not set(res.model.layout.tracker_names) & set(res.free_names)
    _recovered(res, truth)


def test_planes_recover_the_truth_in_their_gauge():
    """80 touches of four planes: planes fix no scale, so the tool length is held (nominal in the
    truth, as the points' gauge is); the rest within 3 sigma."""
    robot, model = _nominal("kr16")
    q, plane = _plane_poses(robot, model, 20, 1)
    _, gauge = contact_model(model, planes=PlaneData.from_arrays(q, plane))
    assert gauge.held == ("reflector_z",) and "scale" in gauge.reasons[0]
    data, truth = simulate_planes(robot, q, plane, normals=NORMALS, offsets=OFFSETS, seed=3, hold=gauge.held)
    res = estimate(model, None, None, planes=data)
    assert "reflector_z" not in res.free_names and res.n_params == 32
    _recovered(res, truth)
    n, d = plane_normals(res.model)
    assert_allclose(np.abs(np.sum(n * NORMALS, axis=1)), 1.0, atol=1e-8)


def test_points_with_planes_recover_the_truth():
    """40 tracker rows and 40 touches of the same true robot: the tracker fixes the scale (nothing
    beyond the points' gauge is held); the covariance is that of the stacked whitened Jacobian."""
    robot, model = _nominal("kr16")
    q, plane = _plane_poses(robot, model, 10, 1)
    q_pts = _poses(robot, 40, np.random.default_rng(7))
    table, point_truth = simulate(robot, q_pts, SimulationOptions(sigma_mm=0.02, seed=11))
    meas = Measurements.from_table(table, robot)
    data, truth = simulate_planes(
        robot, q, plane, normals=NORMALS, offsets=OFFSETS, seed=3, truth=point_truth["model"]
    )
    res = estimate(model, meas.q, meas.eta, sigma=0.02, planes=data)
    assert res.contacts.gauge.held == () and res.contacts.gauge.tracker_rows
    assert res.J.shape == (3 * 40 + 40, res.n_params) and res.dof == 160 - res.n_params
    rows = ContactRows(planes=data)
    _, H, s = rows.jacobian(res.model)
    assert_allclose(res.J[120:], H[:, res.model.layout.free] / s[:, None], rtol=1e-9, atol=1e-12)
    assert_allclose(res.Cp, np.linalg.inv(res.J.T @ res.J), rtol=1e-6, atol=1e-14)
    assert_allclose(res.contacts.plane_residuals, plane_residuals(res.model, data), atol=1e-12)
    _recovered(res, truth)


def test_distances_with_planes_recover_the_truth():
    """40 pairs of known length fix the scale the planes leave open: nothing beyond the gauge held."""
    robot, model = _nominal("kr16")
    q, plane = _plane_poses(robot, model, 10, 1)
    rng = np.random.default_rng(7)
    qd, qd2 = _poses(robot, 40, rng), _poses(robot, 40, rng)
    _, gauge = contact_model(
        model,
        distances=DistanceData.from_arrays(qd, 1.0, q_other=qd2),
        planes=PlaneData.from_arrays(q, plane),
    )
    assert gauge.held == ()
    dist, truth = simulate_distances(robot, qd, q_other=qd2, seed=8)
    planes, plane_truth = simulate_planes(
        robot, q, plane, normals=NORMALS, offsets=OFFSETS, seed=9, truth=truth["model"]
    )
    truth |= {k: plane_truth[k] for k in ("normals", "offsets")}
    res = estimate(model, None, None, distances=dist, planes=planes)
    assert res.J.shape[0] == 80 and res.contacts.distance_residuals.shape == (40,)
    _recovered(res, truth)


def test_gauge_names_what_the_data_do_not_determine():
    robot, model = _nominal("kr16")
    rng = np.random.default_rng(2)
    q, q2 = _poses(robot, 30, rng), _poses(robot, 30, rng)
    # every length of one bar of unknown length: the bar sets the scale
    _, gauge = contact_model(model, distances=DistanceData.from_arrays(q, 1.0, q_other=q2, bar=np.zeros(30)))
    assert gauge.held == ("bar1_dL",) and not gauge.tracker_rows
    assert "6 degrees of freedom are unobservable" in gauge.describe()
    assert {"theta1", "d1", "tracker_x", "tracker_rz"} <= set(gauge.base)
    # a horizontal plane touched from one pose turned about joint 1: every tool point has the same
    # height, so every robot column is constant (the plane offset's) or zero (a1, horizontal)
    turned = np.repeat(q[:1], 8, axis=0)
    turned[:, 0] = np.linspace(-2.5, 2.5, 8)
    _, gauge = contact_model(model, planes=PlaneData.from_arrays(turned, np.zeros(8)))
    assert gauge.held[0] == "reflector_z" and all("no rank" in r for r in gauge.reasons[1:])
    robot_side = {n for n in parameter_layout(robot).free_names if not n.startswith("tracker")}
    assert set(gauge.held) == robot_side
    # a plane whose contact points lie on one line (here: one point), a pivot with three rows
    with pytest.raises(InputError, match="plane 0 .* on one line"):
        contact_model(model, planes=PlaneData.from_arrays(np.repeat(q[:1], 3, axis=0), [0, 0, 0]))
    with pytest.raises(InputError, match="pivot 0 .* one plane"):
        contact_model(model, distances=DistanceData.from_arrays(q[:3], 800.0, pivot=[0, 0, 0]))


def test_data_checks_name_the_row_and_field():
    q = np.zeros((4, 6))
    with pytest.raises(InputError, match=r"row 3, length_mm: -1"):
        DistanceData.from_arrays(q, [1.0, 2.0, -1.0, 3.0], q_other=q)
    with pytest.raises(InputError, match=r"row 2, q_other: a pair row"):
        DistanceData.from_arrays(
            q, 1.0, q_other=np.where(np.arange(4)[:, None] == 1, np.nan, q), pivot=[0, -1, 0, 0]
        )
    with pytest.raises(InputError, match=r"pivot 0 \(0-based\) has no row"):
        DistanceData.from_arrays(q, 1.0, pivot=[1, 1, 1, 1])
    with pytest.raises(InputError, match=r"row 4, sigma_mm"):
        DistanceData.from_arrays(q, 1.0, q_other=q, sigma_mm=[1, 1, 1, 0])
    with pytest.raises(InputError, match=r"row 1, plane: 0.5"):
        PlaneData.from_arrays(q, [0.5, 0, 0, 0])
    with pytest.raises(InputError, match=r"plane 1 \(0-based\) has 1 rows"):
        PlaneData.from_arrays(q, [0, 0, 0, 1])
    with pytest.raises(InputError, match=r"q: expected \(n, 6\)"):
        PlaneData.from_arrays(np.zeros((4, 5)), [0, 0, 0, 0], n_joints=6)
    robot, model = _nominal("kr16")
    planes = PlaneData.from_arrays(_poses(robot, 4, np.random.default_rng(0)), [0, 0, 0, 0])
    with pytest.raises(InputError, match="effects or orientation rows"):
        estimate(model, None, None, planes=planes, R_TP=np.zeros((0, 3, 3)))


def test_the_guide_example_prints_what_the_guide_says(capsys):
    """docs/contacts.md: its Python block runs and prints its text block."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "contacts.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)
    shown = re.search(r"It prints:\n\n```text\n(.*?)```", text, re.DOTALL).group(1)
    exec(compile(code, "docs/contacts.md", "exec"), {})
    assert capsys.readouterr().out == shown


def test_a_model_with_its_own_gauge_is_used_as_given():
    """``contact_model``'s model with one more parameter held: ``estimate`` keeps that layout; a
    model whose contact parameters do not fit the data is refused."""
    robot, model = _nominal("kr16")
    q, plane = _plane_poses(robot, model, 10, 1)
    data, _ = simulate_planes(robot, q, plane, normals=NORMALS, offsets=OFFSETS, seed=3)
    start, gauge = contact_model(model, planes=data)
    held = gauge.names + ("a1",)
    lay = parameter_layout(robot, fixed=held, contacts=start.layout.contacts)
    res = estimate(dataclasses.replace(start, layout=lay), None, None, planes=data)
    assert "a1" not in res.free_names and res.n_params == start.layout.n_free - 1
    assert set(res.contacts.gauge.base) == set(held) | set(robot.extra_gauge)
    with pytest.raises(InputError, match="do not fit the data"):
        estimate(start, None, None, planes=dataclasses.replace(data, plane=np.minimum(data.plane, 2)))
    with pytest.raises(InputError, match="give distance rows, plane rows or both"):
        contact_model(model)
