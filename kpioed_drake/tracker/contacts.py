"""Distances and plane contacts in a fit: their parameters, closed-form starts, gauge and rows.

The systems (:mod:`kpioed_drake.tracker.distance`, :mod:`kpioed_drake.tracker.plane`) add their
parameters after the model's (``layout.contacts``). :func:`contact_model` makes such a model from a
tracker model and the data: the pivots' and planes' closed-form starts (bar corrections 0), and the
gauge, the parameters held at their start values:

1. the model's own held parameters (the points' gauge: SPEC's theta1, d1 against the base frame,
   theta6, d6, a6, alpha6 against the tool point; a chain robot's automatic gauge), targets no row
   uses, and, without tracker rows, the tracker pose: distances and planes do not see where the
   robot stands, so the base frame's six degrees of freedom are unobservable (the planes and pivots
   move with it) and the tracker parameters are not part of the fit;
2. the scale: every length of the robot scaled by s scales every modelled distance and every
   plane offset, so unless some row measures a known length (a tracker row, a distance row
   without a bar) one length is held: the first bar's correction if there are bars (the bar's
   nominal length sets the scale), else the tool point's largest coordinate (the tool length);
3. the rank test of the data: the whitened Jacobian of every row (tracker, distances, planes) at
   the start, unit columns, visited in the order environment (tracker, pivots, planes), joint
   rows from the base up, targets, bars; a column that keeps less than ``GAUGE_RTOL`` of its length
   outside the span of those before it is held (as :func:`kpioed_drake.robot.chain.auto_gauge`).
   An environment column that adds no rank is an error of the data (a plane or pivot they do not
   determine).

:class:`ContactRows` are the rows the estimator (:func:`kpioed_drake.estimation.estimator.estimate`)
stacks after the tracker's: ``(L_meas - d_model) / sigma`` (measured minus model, as the tracker's
rows) and the model Jacobian over sigma; :class:`ContactFit` is the outcome it reports, with the
residuals model minus measured (the planes' signed distances). Units: millimetres and radians.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.errors import InputError
from kpioed_drake.robot.chain import GAUGE_RTOL, independent_columns
from kpioed_drake.robot.parameters import ContactLayout, parameter_layout
from kpioed_drake.tracker.contactdata import DistanceData, PlaneData
from kpioed_drake.tracker.distance import distance_jacobian, distance_residuals, pivot_start
from kpioed_drake.tracker.measurement import TrackerModel, measurement_jacobian
from kpioed_drake.tracker.plane import plane_jacobian, plane_residuals, plane_start


@dataclasses.dataclass(frozen=True)
class ContactGauge:
    """What a fit with distances or planes holds at its start values, and why.

    Attributes:
        base: the model's held parameters (the points' gauge), unused targets, and the tracker pose
            when there are no tracker rows.
        held: the parameters held beyond ``base``, by the scale rule and the rank test.
        reasons: (len(held),) why each is held.
        tracker_rows: the fit has tracker rows (the tracker pose is estimated).
    """

    base: tuple[str, ...] = ()
    held: tuple[str, ...] = ()
    reasons: tuple[str, ...] = ()
    tracker_rows: bool = True

    @property
    def names(self) -> tuple[str, ...]:
        """Every held parameter."""
        return self.base + self.held

    def describe(self) -> str:
        """One line per reason: the base frame (without tracker rows), then each held parameter."""
        lines = (
            []
            if self.tracker_rows
            else [
                "no tracker rows: the tracker pose is not estimated; the base frame's 6 degrees of freedom "
                "are unobservable (planes and pivots move with it)"
            ]
        )
        lines.append(f"gauge: {', '.join(self.base)}")
        lines += [f"{n}: {r}" for n, r in zip(self.held, self.reasons, strict=True)]
        return "\n".join(lines)


def contact_layout(distances: DistanceData | None, planes: PlaneData | None) -> ContactLayout:
    """The parameters the data's bars, pivots and planes add."""
    return ContactLayout(
        bars=0 if distances is None else distances.n_bars,
        pivots=0 if distances is None else distances.n_pivots,
        planes=0 if planes is None else planes.n_planes,
    )


def _check_data(model: TrackerModel, data: DistanceData | PlaneData) -> None:
    """The rows' joint count and targets fit the model."""
    nj, T = model.robot.n_joints, model.layout.n_targets
    if data.q.shape[1] != nj:
        raise InputError(f"{data.source}: q: expected {nj} joint values per row, got {data.q.shape[1]}")
    if data.target is not None and data.target.size and data.target.max() >= T:
        k = int(np.argmax(data.target >= T))
        raise InputError(f"{data.source}: row {data.rows[k]}, target: {data.target[k]} but the model has {T}")


def _used_targets(*targets) -> set[int]:
    out: set[int] = set()
    for t in targets:
        out |= {0} if t is None else set(np.unique(t).tolist())
    return out


def _scale_gauge(model: TrackerModel, free: list[str], points: bool, distances) -> tuple[str, str] | None:
    """(name, reason) of the length held as the scale, or None when some row measures a known length."""
    if points or (distances is not None and np.any(distances.bar < 0)):
        return None
    if distances is not None and distances.n_bars:
        return (
            "bar1_dL",
            "no row measures a known length: the bars' lengths scale with the robot; bar 1 sets it",
        )
    lay = model.layout
    names = [lay.names[i] for i in range(lay.size)[lay.target(0)]]
    tool = [(abs(model.p[lay.names.index(n)]), n) for n in names if n in free]
    lengths = [
        (abs(model.p[i]), lay.names[i]) for i in lay.free if not lay.is_angle[i] and i < lay.joints.stop
    ]
    best = max(tool) if tool and max(tool)[0] > 0 else max(lengths, default=(0.0, None))
    if best[1] is None:
        raise InputError("planes fix no scale and the model has no free length to hold as it")
    return best[1], "planes fix no scale (every offset scales with the robot): held as the scale"


def _environment_first(layout, free: np.ndarray) -> tuple[np.ndarray, int]:
    """``free`` reordered: tracker, pivots, planes; joint rows; targets; bars (the rank test's order),
    and how many of them are the environment's (tracker, pivots, planes)."""
    idx = np.arange(layout.size)
    bars = idx[layout.contact][: layout.contacts.bars]
    env = np.concatenate([idx[layout.tracker], idx[layout.contact][layout.contacts.bars :]])
    groups = [g[np.isin(g, free)] for g in (env, idx[layout.joints], idx[layout.targets], bars)]
    return np.concatenate(groups), groups[0].size


def _rank_held(A: np.ndarray, order: np.ndarray, names, n_env: int, rtol: float = GAUGE_RTOL) -> list[str]:
    """Names of the columns ``order`` of ``A`` (whitened, full width) that add no rank in that order;
    InputError if one of the first ``n_env`` (tracker, pivots, planes) does."""
    norms = np.linalg.norm(A[:, order], axis=0)
    live = norms > 1e-9 * max(float(norms.max(initial=0.0)), 1e-300)
    U = np.where(live, A[:, order] / np.where(live, norms, 1.0), 0.0)
    kept = independent_columns(U, rtol)
    for k in np.flatnonzero(~kept[:n_env])[:1]:
        what = names[order[k]]
        raise InputError(f"the rows do not determine {what} (a plane or pivot without enough rows)")
    return [names[order[k]] for k in np.flatnonzero(~kept) if k >= n_env]


@dataclasses.dataclass(frozen=True)
class ContactRows:
    """Distance and plane rows of a fit and its gauge (either system may be None)."""

    distances: DistanceData | None = None
    planes: PlaneData | None = None
    gauge: ContactGauge = ContactGauge()

    @property
    def n_rows(self) -> int:
        return sum(0 if d is None else d.n for d in (self.distances, self.planes))

    def jacobian(self, model: TrackerModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r (m,) model minus measured [mm], H (m, n_full), sigma (m,) [mm]) of all rows, distances first."""
        parts = []
        if self.distances is not None:
            parts.append((*distance_jacobian(model, self.distances), self.distances.sigma))
        if self.planes is not None:
            parts.append((*plane_jacobian(model, self.planes), self.planes.sigma))
        r, H, s = zip(*parts, strict=True)
        return np.concatenate(r), np.concatenate(H), np.concatenate(s)

    def weighted(self, model: TrackerModel, *, jac: bool = True):
        """Whitened ``(measured - model) / sigma`` (m,) and, with ``jac``, ``dmodel/dp_free / sigma``
        (m, n_free): the estimator's convention."""
        if not jac:
            r = np.concatenate(self.residuals(model))
            return -r / self._sigma()
        r, H, s = self.jacobian(model)
        return -r / s, H[:, model.layout.free] / s[:, None]

    def _sigma(self) -> np.ndarray:
        return np.concatenate([d.sigma for d in (self.distances, self.planes) if d is not None])

    def residuals(self, model: TrackerModel) -> tuple[np.ndarray, np.ndarray]:
        """(distance residuals (n_d,), plane residuals (n_p,)) model minus measured [mm] (empty if absent)."""
        d = np.zeros(0) if self.distances is None else distance_residuals(model, self.distances)
        p = np.zeros(0) if self.planes is None else plane_residuals(model, self.planes)
        return d, p

    def stacked(self, model: TrackerModel, tracker, *, jac: bool = True):
        """The tracker rows ``tracker`` (r or (r, J) of the estimator) with these rows after them."""
        if not jac:
            return np.concatenate([tracker, self.weighted(model, jac=False)])
        r, J = self.weighted(model)
        return np.concatenate([tracker[0], r]), np.concatenate([tracker[1], J])

    def fit(self, model: TrackerModel) -> ContactFit:
        """The outcome at the solution ``model``."""
        d, p = self.residuals(model)
        return ContactFit(self.gauge, self.distances, self.planes, d, p)


@dataclasses.dataclass(frozen=True)
class ContactFit:
    """The distance and plane part of an estimate.

    Attributes:
        gauge: what the fit held and why.
        distances, planes: the rows fitted (None when absent).
        distance_residuals: (n_d,) model minus measured length [mm].
        plane_residuals: (n_p,) signed distance minus the measured one [mm].
    """

    gauge: ContactGauge
    distances: DistanceData | None
    planes: PlaneData | None
    distance_residuals: np.ndarray
    plane_residuals: np.ndarray


def contact_model(
    model: TrackerModel,
    *,
    distances: DistanceData | None = None,
    planes: PlaneData | None = None,
    q_points: np.ndarray | None = None,
    target_points: np.ndarray | None = None,
    sigma_points: float = 0.02,
) -> tuple[TrackerModel, ContactGauge]:
    """``model`` with the contact parameters, their starts and the gauge of the module docstring.

    Args:
        model: a tracker model without contact parameters (normally the nominal one).
        distances, planes: the rows (at least one).
        q_points: (m, n_joints) the tracker rows' poses of a mixed fit (None or m = 0: none).
        target_points: (m,) their 0-based targets (None: target 0).
        sigma_points: the tracker rows' noise per coordinate [mm] (weights of the rank test).

    Returns:
        (model, gauge): the model's layout holds ``gauge.names``.

    Raises:
        InputError: bad data, a model with a probe or contact parameters already, a plane or pivot
            the rows do not determine, fewer rows than estimated parameters.
    """
    lay = model.layout
    if lay.probe or lay.contacts.size:
        raise InputError(
            "distances and planes: the model has a probe's orientations or contact parameters already"
        )
    if distances is None and planes is None:
        raise InputError("distances and planes: give distance rows, plane rows or both")
    for data in (distances, planes):
        if data is not None:
            _check_data(model, data)
    points = q_points is not None and len(q_points) > 0
    held = [n for i, n in enumerate(lay.names) if i not in set(lay.free.tolist())]
    if not points:
        held += [n for n in lay.names[lay.tracker] if n not in held]
    used = _used_targets(
        *(d.target for d in (distances, planes) if d is not None), *([target_points] if points else [])
    )
    held += [
        lay.names[i] for t in range(lay.n_targets) if t not in used for i in range(lay.size)[lay.target(t)]
    ]
    cl = contact_layout(distances, planes)
    start = [np.zeros(cl.bars)]
    start.append(np.zeros(0) if not cl.pivots else pivot_start(model, distances).ravel())
    normals, offsets = (np.zeros((0, 3)), np.zeros(0)) if not cl.planes else plane_start(model, planes)
    start.append(np.column_stack([np.zeros((cl.planes, 2)), offsets]).ravel())
    layout = parameter_layout(model.robot, fixed=tuple(held), n_targets=lay.n_targets, contacts=cl)
    out = dataclasses.replace(
        model, p=np.concatenate([model.p, *start]), layout=layout, n_W_ref=normals if cl.planes else None
    )
    rows = ContactRows(distances, planes)
    free = [layout.names[i] for i in layout.free]
    scale = _scale_gauge(out, free, points, distances)
    extra, reasons = ([scale[0]], [scale[1]]) if scale else ([], [])
    _, H, s = rows.jacobian(out)
    A = H / s[:, None]
    if points:
        _, Hp = measurement_jacobian(out, q_points, target=target_points)
        A = np.concatenate([Hp.reshape(-1, layout.size) / sigma_points, A])
    order, n_env = _environment_first(
        layout, np.setdiff1d(layout.free, [layout.names.index(n) for n in extra])
    )
    rank = _rank_held(A, order, layout.names, n_env)
    extra += rank
    reasons += ["not determined by these rows (adds no rank to the parameters before it)"] * len(rank)
    layout = parameter_layout(model.robot, fixed=tuple(held + extra), n_targets=lay.n_targets, contacts=cl)
    n_rows = rows.n_rows + (3 * len(q_points) if points else 0)
    if n_rows < layout.n_free:
        raise InputError(
            f"distances and planes: {n_rows} rows, fewer than the {layout.n_free} estimated parameters"
        )
    gauge = ContactGauge(tuple(held), tuple(extra), tuple(reasons), tracker_rows=points)
    return dataclasses.replace(out, layout=layout), gauge


def contact_inputs(
    model: TrackerModel,
    q: np.ndarray | None,
    eta: np.ndarray | None,
    *,
    distances: DistanceData | None,
    planes: PlaneData | None,
    sigma: float,
    mask: np.ndarray | None,
    conditions,
    other_rows: bool,
) -> tuple[TrackerModel, ContactRows, np.ndarray, np.ndarray]:
    """The estimator's contact inputs: the tracker rows (None: none, as (0, n_joints), (0, 3)), the
    model with the contact parameters (:func:`contact_model` on the tracker rows ``mask`` uses,
    unless ``model`` has them for these data already) and the rows. ``conditions``: the estimator's
    per-pose conditions (their ``target``: the tracker rows' 0-based targets).

    Raises:
        InputError: ``other_rows`` (effects or orientations are not modelled with contacts), a mask
            of another length, a model whose contact parameters do not fit the data.
    """
    if other_rows:
        raise InputError(
            "estimate: effects or orientation rows together with distances or planes are not modelled"
        )
    nj = model.robot.n_joints
    q = np.zeros((0, nj)) if q is None else np.atleast_2d(np.asarray(q, dtype=float))
    eta = np.zeros((0, 3)) if eta is None else np.atleast_2d(np.asarray(eta, dtype=float))
    used = np.ones(len(q), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if used.shape != (len(q),):
        raise InputError("estimate: mask and weights must have one entry per pose, weights > 0")
    if not model.layout.contacts.size:
        target = None if conditions.target is None else np.asarray(conditions.target)[used]
        model, gauge = contact_model(
            model,
            distances=distances,
            planes=planes,
            q_points=q[used],
            target_points=target,
            sigma_points=sigma,
        )
        return model, ContactRows(distances, planes, gauge), q, eta
    want = contact_layout(distances, planes)
    if model.layout.contacts != want or (want.planes and model.n_W_ref is None):
        raise InputError(
            f"estimate: the model's contact parameters {model.layout.contacts} do not fit the data's {want}"
        )
    lay = model.layout
    held = tuple(n for i, n in enumerate(lay.names) if i not in set(lay.free.tolist()))
    return (
        model,
        ContactRows(distances, planes, ContactGauge(base=held, tracker_rows=bool(used.any()))),
        q,
        eta,
    )
