"""The self-test harness of the diagnosis: simulated campaigns with hidden effects and a known truth.

Used by ``tests/test_diagnosis.py`` and ``studies/diagnosis_rates.py``: :func:`synthetic_case`
simulates data (the true robot from :func:`kpioed_drake.simulation.truth.true_model`, the same truth as
``kpioed simulate``), :func:`run_synthetic_case` draws hidden effects, diagnoses and compares, and
:func:`detectability` says how visible each hidden effect is in the data at all.
"""

from __future__ import annotations

import dataclasses
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from kpioed_drake import effects as fx
from kpioed_drake.diagnosis.fit import Fit, FitProblem
from kpioed_drake.diagnosis.options import DiagnosisOptions
from kpioed_drake.diagnosis.workflow import diagnose
from kpioed_drake.effects import gravity_basis as gb
from kpioed_drake.effects.gravity_basis import FAMILY as BASIS_FAMILY
from kpioed_drake.robot.drivetrain import coupling_pairs
from kpioed_drake.robot.geometry import ClearanceModel
from kpioed_drake.robot.models import Cell, Robot, load_cell, load_robot
from kpioed_drake.simulation.truth import true_model
from kpioed_drake.tracker.data import Measurements
from kpioed_drake.tracker.measurement import TrackerModel, kpi_jacobian, nominal_model


@dataclasses.dataclass
class SyntheticCase:
    """Simulated data with a known truth.

    Attributes:
        data: the simulated measurements.
        model_true: the true geometry and tracker pose.
        effects: the hidden effects with their values.
        sigma: the noise per coordinate [mm].
    """

    data: Measurements
    model_true: TrackerModel
    effects: list
    sigma: float

    @property
    def names(self) -> set[str]:
        """Names of the hidden effects (e.g. ``gear_cyclic:4:2``)."""
        return {e.name for e in self.effects}


def random_poses(robot: Robot, n: int, rng: np.random.Generator, *, cell: Cell | None = None) -> np.ndarray:
    """(n, 6) poses uniform within the joint limits whose capsules clear the floor, the wall and
    the cell's obstacles (:class:`~kpioed_drake.robot.geometry.ClearanceModel`, no beam/incidence check)."""
    cell = load_cell(robot=robot) if cell is None else cell
    cm = ClearanceModel(robot, cell, collision=True, beam=False)
    out = []
    while sum(len(x) for x in out) < n:
        q = rng.uniform(robot.lower, robot.upper, size=(4 * n, robot.n_joints))
        vals = cm.values(q)
        kinds = np.array(cm.rows.kinds)
        keep = np.all(vals[:, kinds != "self"] >= 0.0, axis=1)
        out.append(q[keep])
    return np.concatenate(out)[:n]


def synthetic_case(
    robot: Robot,
    rng: np.random.Generator,
    effects: Iterable[str | fx.Effect] = (),
    *,
    n_poses: int = 80,
    sigma: float = 0.02,
    seconds_per_pose: float = 20.0,
    payload_kg: float | Sequence[float] | None = None,
    cell: Cell | None = None,
    q: ArrayLike | None = None,
    mass_spread: float = 0.0,
) -> SyntheticCase:
    """Simulate a measurement campaign with hidden effects (texts or :class:`Effect`).

    True robot: :func:`kpioed_drake.simulation.truth.true_model` (nominal + N(0, 0.5 mm) on the free
    lengths and N(0, 0.05 deg) on the free angles of the joints and the reflector, gauge parameters
    nominal; a tracker frame with a random orientation and its origin within +-200 mm of the
    nominal one). Poses: ``q`` (n, 6) [rad] or
    :func:`random_poses`.
    ``time_s`` = ``seconds_per_pose`` per pose; ``temperature_C`` = 20 C plus a smooth swing of 3-10 K
    amplitude (SPEC: +-10 K) over the run; noise N(0, sigma^2) per coordinate.
    ``mass_spread`` > 0: the true robot's link masses and centres of mass differ from the file's
    (:func:`perturbed_masses`, from a generator seeded by one draw of ``rng``).
    ``payload_kg``: None, one mass for every pose, or a tuple of levels drawn per pose (a payload
    that changes over the campaign).
    """
    cell = load_cell(robot=robot) if cell is None else cell
    truth = true_model(nominal_model(robot, cell), rng, tracker_spread_mm=200.0, scalar_first=False)
    if mass_spread > 0:
        truth = dataclasses.replace(
            truth, robot=perturbed_masses(robot, np.random.default_rng(rng.integers(2**62)), mass_spread)
        )
    q = random_poses(robot, n_poses, rng, cell=cell) if q is None else np.asarray(q, dtype=float)
    n_poses = q.shape[0]
    t = np.arange(n_poses) * seconds_per_pose
    phase, cycles = rng.uniform(0, 2 * np.pi), rng.uniform(0.5, 1.5)
    temp = 20.0 + rng.uniform(3.0, 10.0) * np.sin(2 * np.pi * cycles * t / max(t[-1], 1.0) + phase)
    effs = [
        fx.parse_effect(e, rng, model=truth) if isinstance(e, str) else fx.resolve(e, truth) for e in effects
    ]
    if payload_kg is None or np.ndim(payload_kg) == 0:
        pay = None if payload_kg is None else np.full(n_poses, float(payload_kg))
    else:
        pay = rng.choice(np.asarray(payload_kg, dtype=float), size=n_poses)
    h = fx.true_measurements(truth, q, effs, temperature_C=temp, time_s=t, payload_kg=pay)
    eta = h + sigma * rng.standard_normal(h.shape)
    data = Measurements.from_arrays(
        q, eta, temperature_C=np.round(temp, 3), time_s=t, payload_kg=pay, source="synthetic"
    )
    return SyntheticCase(data, truth, effs, sigma)


def perturbed_masses(robot: Robot, rng: np.random.Generator, spread: float = 0.3) -> Robot:
    """``robot`` with other link masses and centres of mass: each mass times ``U(1 - spread, 1 + spread)``,
    each centre-of-mass coordinate shifted by ``U(-spread, spread)`` times the link's centre-of-mass
    distance (for a link whose centre of mass is at its frame origin: times 100 mm). A URDF robot's
    Drake plant (its gravity torques) gets the same masses (:func:`_urdf_masses`)."""
    m = robot.masses * rng.uniform(1 - spread, 1 + spread, size=robot.masses.shape)
    r = gb.com_scales(robot.coms)[:, None]
    c = robot.coms + rng.uniform(-spread, spread, size=robot.coms.shape) * r
    urdf = robot.urdf if robot.urdf is None else _urdf_masses(robot, m, c)
    return dataclasses.replace(robot, masses=m, coms=c, urdf=urdf)


def _urdf_masses(robot: Robot, masses: np.ndarray, coms: np.ndarray):
    """The robot's URDF source with links 1..n of masses (n+1,) [kg] and centres of mass (n+1, 3)
    [mm, link frame] (the child link of each movable joint takes the change; links welded to it keep
    theirs; inertia tensors scaled with the mass)."""
    root = ET.fromstring(robot.urdf.text)
    links = {lk.get("name"): lk for lk in root.findall("link")}
    joints = {j.get("name"): j for j in root.findall("joint")}
    for i, name in enumerate(robot.urdf.joints, start=1):
        inertial = links[joints[name].find("child").get("link")].find("inertial")
        if inertial is None or inertial.find("mass") is None:
            continue  # massless in the file: nothing to perturb
        origin = inertial.find("origin")
        origin = ET.SubElement(inertial, "origin") if origin is None else origin
        m_p = float(inertial.find("mass").get("value"))
        c_p = np.array([float(x) for x in origin.get("xyz", "0 0 0").split()]) * 1e3
        m_w = robot.masses[i] - m_p  # welded to it
        mc_w = robot.masses[i] * robot.coms[i] - m_p * c_p
        m_new = masses[i] - m_w
        if m_new <= 0:
            raise ValueError(f"{robot.source}: link {i}'s welded parts outweigh its perturbed mass")
        inertial.find("mass").set("value", repr(float(m_new)))
        origin.set("xyz", " ".join(repr(float(x) * 1e-3) for x in (masses[i] * coms[i] - mc_w) / m_new))
        tensor = inertial.find("inertia")
        for key in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz") if tensor is not None else ():
            tensor.set(key, repr(float(float(tensor.get(key, "0")) * m_new / m_p)))
    return dataclasses.replace(robot.urdf, text=ET.tostring(root, encoding="unicode"))


def draw_effect_text(
    rng: np.random.Generator, exclude: Iterable[str] = (), families: Sequence[str] = fx.FAMILIES
) -> str:
    """A random effect (family, joint, harmonic uniform; a coupling among the diagnosis's candidates
    of a six-joint arm, :func:`~kpioed_drake.robot.drivetrain.coupling_pairs`), without a value. A
    family given with its joint (``column_compliance:1``: a robot's lift) is taken as it is."""
    while True:
        fam = families[rng.integers(len(families))]
        if ":" in fam:
            text = fam
        elif fam == "joint_elasticity":
            text = f"{fam}:{rng.integers(2, 7)}"
        elif fam == "gear_cyclic":
            text = f"{fam}:{rng.integers(1, 7)}:{rng.integers(1, 3)}"
        elif fam in ("joint_scale", "backlash"):
            text = f"{fam}:{rng.integers(1 if fam == 'joint_scale' else 2, 7)}"
        elif fam == "joint_coupling":
            pairs = coupling_pairs(None, 6)
            i, j = pairs[rng.integers(len(pairs))]
            text = f"{fam}:{i}:{j}"
        else:
            text = fam
        if fx.parse_effect(text).name not in {fx.parse_effect(x).name for x in exclude}:
            return text


def detectability(case: SyntheticCase, *, given_others: bool = False) -> list[float]:
    """Non-centrality ``|P s|^2 / sigma^2`` of each hidden effect's signal s after projecting out the
    span of the free geometric columns (at the truth). Under 'no effect' the likelihood-ratio statistic
    is chi^2(k); with the effect its mean is about ``k + lambda``: below ~25 no test at a corrected
    1 % level finds the effect reliably. ``given_others``: the span of the other hidden effects'
    columns is projected out too (what a test of this effect beside the others can see; the same for
    a single effect)."""
    prob = FitProblem(case.model_true.robot, case.data, case.sigma)
    _, H, E = prob.response(case.model_true, case.effects, np.arange(case.data.n))
    free = case.model_true.layout.free
    G = H[:, :, free].reshape(-1, free.size)
    Q, _ = np.linalg.qr(G)
    out, c = [], 0
    for e in case.effects:
        s = (E[:, :, c : c + e.n_params] @ e.value_array()).reshape(-1)
        if given_others:
            others = np.concatenate([E[:, :, :c], E[:, :, c + e.n_params :]], axis=2).reshape(G.shape[0], -1)
            Q, _ = np.linalg.qr(np.concatenate([G, others], axis=1))
        c += e.n_params
        s = s - Q @ (Q.T @ s)
        out.append(float(s @ s) / case.sigma**2)
    return out


def kpi_error(case: SyntheticCase, fit: Fit) -> float | None:
    """|TCP(fit) - TCP(truth)| at q_work under KPI conditions (no payload, 20 C) [mm]."""
    qw = case.model_true.robot.q_work
    if qw is None:
        return None
    s_true = kpi_jacobian(case.model_true, qw)[0] + fx.effect_tcp_shift(case.model_true, qw, case.effects)
    s = kpi_jacobian(fit.model, qw)[0] + fx.effect_tcp_shift(fit.model, qw, fit.effects)
    return float(np.linalg.norm(s - s_true))


CASE_KINDS = ("single", "pair", "clean")
RATE_FAMILIES = fx.FAMILIES + ("joint_scale", "joint_coupling", "tracker_scale", "backlash")
"""The families of the rate study (SPEC's four and four further ones)."""
NEAR_THRESHOLD = (15.0, 150.0)
"""Range of the hidden signal's non-centrality lambda (log-uniform) in ``near_threshold`` cases."""
PAYLOAD_KG = (2.0, 15.0)
"""Range of the second payload level of a ``payload="changes"`` case (the first is 0 kg)."""


def _as_elasticity(name: str) -> str:
    """A gravity-basis elasticity names the elasticity of its joint."""
    family, _, rest = name.partition(":")
    return f"joint_elasticity:{rest}" if family == BASIS_FAMILY else name


def _hard_case(
    robot: Robot, rng: np.random.Generator, effect_seed: list, texts: list, kw: dict, near_threshold: bool
) -> SyntheticCase:
    """A case of the harder harness: the effects ``texts`` drawn from their own stream (seeded by
    ``effect_seed``: rescaling them leaves every other draw of ``rng`` alone), and with
    ``near_threshold`` rescaled to a log-uniform lambda in :data:`NEAR_THRESHOLD` and simulated again
    from the same state of ``rng`` (``kw``: :func:`synthetic_case`'s keywords)."""
    state = rng.bit_generator.state
    erng = np.random.default_rng(effect_seed)
    effs = [fx.parse_effect(t, erng) for t in texts]
    case = synthetic_case(robot, rng, effs, **kw)
    if near_threshold and effs:
        lam = np.maximum(detectability(case), 1e-30)
        target = np.exp(erng.uniform(*np.log(NEAR_THRESHOLD), size=len(lam)))
        effs = [
            e.with_values(e.value_array() * np.sqrt(t / x))
            for e, t, x in zip(case.effects, target, lam, strict=True)
        ]
        rng.bit_generator.state = state
        case = synthetic_case(robot, rng, effs, **kw)
    return case


def run_synthetic_case(
    kind: str,
    seed: int,
    robot: str | Path | Robot = "kr16",
    *,
    n_poses: int = 80,
    sigma: float = 0.02,
    families: Sequence[str] = fx.FAMILIES,
    mass_spread: float = 0.0,
    payload: str | None = None,
    near_threshold: bool = False,
) -> dict:
    """One seeded case of the rate study: draw hidden effects (``single``: one, ``pair``: two
    different ones, ``clean``: none; family, joint and harmonic uniform, sizes in SPEC's ranges),
    simulate, diagnose, compare. Used by ``tests/test_diagnosis.py`` and
    ``studies/diagnosis_rates.py``. ``families`` restricts the draw (e.g. to ``("gear_cyclic",)``).

    The harder harness (defaults off; without it a case draws what the plain one draws):
    ``mass_spread`` (true link masses and centres of mass off the file's,
    :func:`perturbed_masses`); ``payload="changes"``
    (each pose carries 0 kg or a second level uniform in :data:`PAYLOAD_KG`, recorded in the data);
    ``near_threshold`` (each hidden effect rescaled so that its lambda is log-uniform in
    :data:`NEAR_THRESHOLD`; the same truth, poses and noise otherwise). ``explained``: every hidden
    effect is named or among a cause's ``alternatives`` and every cause stands for one (a named
    gravity-basis elasticity counts as the elasticity of its joint). ``lambda`` is in the order of
    ``truth`` (``truth_names`` is sorted).
    """
    robot = load_robot(robot) if isinstance(robot, str | Path) else robot
    rng = np.random.default_rng([seed, CASE_KINDS.index(kind) + 1])
    texts = []
    if kind != "clean":
        texts.append(draw_effect_text(rng, families=families))
    if kind == "pair":
        texts.append(draw_effect_text(rng, exclude=texts, families=families))
    hard = mass_spread > 0 or payload is not None or near_threshold
    pay = None
    if payload == "changes":
        pay = (0.0, float(rng.uniform(*PAYLOAD_KG)))
    kw = {"n_poses": n_poses, "sigma": sigma, "mass_spread": mass_spread, "payload_kg": pay}
    if not hard:
        case = synthetic_case(robot, rng, texts, **kw)
    else:
        case = _hard_case(robot, rng, [seed, CASE_KINDS.index(kind) + 1, 7], texts, kw, near_threshold)
    t0 = time.perf_counter()
    rep = diagnose(robot, case.data, DiagnosisOptions(sigma_mm=sigma))
    seconds = time.perf_counter() - t0
    named = {_as_elasticity(k) for k in rep.cause_names}
    explain = [{_as_elasticity(k) for k in ks} for ks in rep.explanation_names]
    truth = case.names
    explained = all(any(k in ks for ks in explain) for k in truth) and all(ks & truth for ks in explain)
    return {
        "kind": kind,
        "seed": seed,
        "truth": [e.text() for e in case.effects],
        "truth_names": sorted(truth),
        "lambda": detectability(case),
        "lambda_given_others": detectability(case, given_others=True),
        "named": sorted(named),
        "named_raw": [c.get("name", c["effect"]) for c in rep.causes],
        "alternatives": [sorted(ks) for ks in explain],
        "exact": named == truth,
        "explained": bool(explained),
        "all_named": truth <= named,
        "discrepancy": rep.discrepancy,
        "p_gof": rep.test["p_value"],
        "holdout_base_over_sigma": rep.baseline["holdout_rms_mm"] / sigma,
        "holdout_ext_over_sigma": rep.extended["holdout_rms_mm"] / sigma,
        "chi2_per_dof_ext": rep.extended["chi2_per_dof"],
        "kpi_error_base_mm": kpi_error(case, rep.details["base"]),
        "kpi_error_ext_mm": kpi_error(case, rep.details["ext"]),
        "payload_kg": pay,
        "mass_spread": mass_spread,
        "seconds": seconds,
    }
