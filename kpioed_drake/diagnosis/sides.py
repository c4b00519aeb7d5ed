"""The side of a backlash when the link masses are uncertain: sign patterns from the mass prior.

A backlash of joint j is an angle error ``b s_i`` whose side ``s_i`` follows the sign of the joint's
gravity torque at pose i. The torque is linear in the links' first mass moments,
``tau_j(q) = Y_j(q) pi + tau_payload`` (:func:`~kpioed_drake.effects.gravity_basis.link_regressor`),
and the model file's moments ``pi`` are uncertain (masses and centres of mass +-30 %,
:data:`~kpioed_drake.effects.gravity_basis.MASS_PRIOR_SPREAD`). Where the file's torque is within
that uncertainty of zero (wrist joints, whose torques come from centres of mass near their axes) its
sign is a coin flip, and a backlash column with the wrong side at a few poses keeps only part of the
signal.

:func:`side_patterns` gives each loaded joint a small set of candidate sides: the expected sign
``erf(tau / (sqrt 2 u))`` (:func:`backlash_sides`) first, then
the distinct sign patterns of the torques of :data:`N_PRIOR_DRAWS` seeded draws of the moments from
the prior (each mass times ``U(1 - s, 1 + s)``, each centre-of-mass coordinate shifted by
``U(-s, s)`` times the centre of mass's distance, 100 mm where it is 0). A selection step scores a
backlash candidate with each of its joint's patterns and keeps the best; the family-wise level of
the step counts every pattern as a test (weighted min-p over all candidates and patterns,
:mod:`~kpioed_drake.estimation.multiplicity`), with the weights of :func:`side_weights`: the
expected side 1 like every other candidate, the other patterns 1 together, so that choosing the side
from the data costs the backlash what the choice is worth and the other candidates one test (the
patterns of one joint differ at a few poses and are strongly correlated: far fewer effective tests
than patterns, and with weight 1 each they would raise every other candidate's correction). To
rank a backlash against the other candidates of a step, its likelihood ratio is lowered by
:func:`side_penalty` (the choice of the side is worth that much under "no effect"), and a named
backlash is tried against the gravity basis of its joint
(:func:`~kpioed_drake.diagnosis.elastic_basis.upgrade_elasticity`): a large elasticity whose torque
the file's masses get wrong can look like a backlash with a chosen side.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.options import BACKLASH_MIN_SIDE
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.estimation.multiplicity import effective_tests, min_p_null
from kpioed_drake.robot.kinematics import subtree_links
from kpioed_drake.robot.models import Robot

N_PRIOR_DRAWS = 50
"""Draws of the link moments from the mass prior per joint (distinct sign patterns are kept)."""
SEED = 7
"""Seed of the draws (a diagnosis is deterministic)."""


def prior_moments(
    robot: Robot, joint: int, rng: np.random.Generator, n: int, *, spread: float = gb.MASS_PRIOR_SPREAD
) -> np.ndarray:
    """(n, 4 (N - j + 1)) first moments ``m_k, m_k c_k`` of links j..N drawn from the mass prior."""
    ks = subtree_links(robot, joint)
    m0, c0 = robot.masses[ks], robot.coms[ks]
    r = gb.com_scales(c0)[:, None]
    m = m0[None, :] * rng.uniform(1 - spread, 1 + spread, size=(n, ks.size))
    c = c0[None] + rng.uniform(-spread, spread, size=(n, ks.size, 3)) * r[None]
    return np.concatenate([m[..., None], m[..., None] * c], axis=2).reshape(n, -1)


def backlash_sides(prob: FitProblem) -> np.ndarray:
    """(n, 6) the side of a backlash per pose for the fit: the expected sign of each joint's gravity
    torque when the file's masses and centres of mass are uncertain
    (:func:`~kpioed_drake.effects.gravity_basis.expected_side` with
    :func:`~kpioed_drake.effects.gravity_basis.torque_std`): +-1 where the file's torque is clearly
    on one side, towards 0 where its sign is within its uncertainty (those poses say little about
    the side, and a wrong sign there would work against the test)."""
    tau = prob.tau
    side = np.sign(tau)
    for j in range(1, prob.robot.n_joints + 1):  # joints gravity loads (a vertical joint 1: rank 0)
        if gb.joint_basis(prob.robot, j).rank:
            side[:, j - 1] = gb.expected_side(tau[:, j - 1], gb.torque_std(prob.robot, prob.data.q, j))
    return side


def with_expected_sides(prob: FitProblem) -> FitProblem:
    """``prob`` with every backlash on :func:`backlash_sides`."""
    return prob.with_sides(backlash_sides(prob))


def side_patterns(
    prob: FitProblem, joints: Iterable[int], *, n_draws: int = N_PRIOR_DRAWS, seed: int = SEED
) -> dict:
    """Candidate sides of a backlash per joint: ``{j: (K_j, n)}``, row 0 the current (expected) side
    of ``prob.conditions.side``, then the distinct sign patterns of prior draws of the torque
    (a pattern and its negative are one: the backlash's value takes the sign)."""
    q, tau, side = prob.data.q, prob.tau, prob.conditions.side
    out = {}
    for j in joints:
        Y = gb.link_regressor(prob.robot, q, j)
        payload = tau[:, j - 1] - Y @ gb.link_moments(prob.robot, j)  # the recorded payload's torque
        rng = np.random.default_rng([seed, j])
        pats = np.sign(prior_moments(prob.robot, j, rng, n_draws) @ Y.T + payload[None, :])
        pats *= np.where(pats[:, :1] < 0, -1.0, 1.0)  # one of each +- pair
        pats = pats[np.min([np.sum(pats > 0, axis=1), np.sum(pats < 0, axis=1)], axis=0) >= BACKLASH_MIN_SIDE]
        first = side[:, j - 1] if side is not None else np.sign(tau[:, j - 1])
        out[j] = np.concatenate([first[None, :], np.unique(pats, axis=0)])
    return out


def unit_columns(prob: FitProblem, fit: Fit, joints: Sequence[int]) -> dict:
    """Weighted (3 n,) column of a backlash of each joint with side +1 at every pose, at ``fit``: a
    side pattern's column is this one times the pattern (per pose)."""
    if not joints:
        return {}
    side = (np.sign(prob.tau) if prob.conditions.side is None else prob.conditions.side).copy()
    side[:, np.asarray(list(joints)) - 1] = 1.0
    n = prob.data.n
    cands = [fx.Effect("backlash", j) for j in joints]
    _, _, E = prob.with_sides(side).response(fit.model, list(fit.effects) + cands, np.arange(n))
    k0 = fit.k
    return {j: E[:, :, k0 + i].reshape(-1) / prob.sigma for i, j in enumerate(joints)}


def side_penalty(bases: Sequence[np.ndarray], *, level: float = 0.01) -> float:
    """``2 ln K_eff``: what choosing the best of a backlash's sides adds to its likelihood ratio under
    "no effect", ``K_eff = level / q`` with ``q`` the ``level`` quantile of the smallest p-value over
    the sides' (correlated) columns ``bases`` (:func:`~kpioed_drake.estimation.multiplicity.min_p_null`;
    1 for a single side, the number of sides for independent ones). The selection subtracts it when
    it ranks the candidates, so that a side chosen from the data does not win over a one-column
    candidate by the choice alone (for large LR, ``-2 ln p`` grows by ``2 ln K`` when p is multiplied
    by K)."""
    return float(2.0 * np.log(max(effective_tests(min_p_null(list(bases)), level), 1.0)))


SIDE_SEARCH_WEIGHT = 1.0
"""Weight, in a selection step's weighted min-p test, of a backlash's sides other than the expected
one, together (the expected side, row 0 of :func:`side_patterns`, has weight 1 like every other
candidate): choosing the side from the data is one more test, paid by the backlash's other sides."""


def side_weights(bases: Sequence[np.ndarray], *, level: float = 0.01) -> np.ndarray:
    """(K,) weights of one candidate's K sides in a selection step's weighted min-p test
    (:func:`~kpioed_drake.estimation.multiplicity.min_p_null`): the expected side (``bases[0]``) 1,
    each other side :data:`SIDE_SEARCH_WEIGHT` divided by the effective number of tests of the other
    sides (``level / q``, ``q`` the ``level`` quantile of their null minimum p-value; 1 to K - 1).
    A single side: [1].

    A backlash thus costs the other candidates two tests (its expected side and the search over the
    others), however many sides it is scored with; a side unlike the file's masses' needs a smaller
    p-value. The weights depend on the poses only, not on the residuals.
    """
    k = len(bases)
    if k == 1:
        return np.ones(1)
    rest = list(bases[1:])
    k_eff = 1.0 if k == 2 else float(np.clip(effective_tests(min_p_null(rest), level), 1.0, k - 1))
    return np.concatenate([[1.0], np.full(k - 1, SIDE_SEARCH_WEIGHT / k_eff)])
