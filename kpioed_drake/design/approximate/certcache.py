"""On-disk cache of the approximate designs behind the optimality certificate.

The search behind a certificate (:func:`kpioed_drake.design.approximate.certificate.certified_design`) takes
4-13 s per robot, cell and setup, the same for every design of that setup; this module stores its
result (:class:`~kpioed_drake.design.approximate.design.ApproximateDesign`) as a compressed ``.npz`` file
so that every later design and ``evaluate`` of the setup only pays for certifying its own poses.

Folder: ``$KPIOED_CACHE`` if set (``off``, ``0`` or empty: no disk cache), else
``$XDG_CACHE_HOME/kpioed`` or ``~/.cache/kpioed``. Files are written to a temporary file in the
folder and renamed (atomic: a reader sees a whole file or none; concurrent writers of the same key
write the same content).

Key: a SHA-256 hash of what the search depends on, by content: the robot's name and joint limits,
the identification rows ``F1`` and the constraint rows (incidence, clearances of the cell) at 16
fixed test poses (so robot kinematics, measurement model, noise, extensions and cell geometry),
the KPI factor ``Js`` (working poses, weights, KPI point), the joint map's coupling equations
(the poses a controller can command), ``collision``, the seed and the search
settings (the module constants passed in ``settings``), and :data:`CACHE_VERSION`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from kpioed_drake.design.approximate.design import ApproximateDesign
from kpioed_drake.design.exact.constraints import DesignConstraints
from kpioed_drake.estimation.problem import Problem

CACHE_VERSION = "certificate-v2"
"""Changes when the stored content or the search changes meaning."""
CACHE_ENV = "KPIOED_CACHE"
"""Environment variable naming the cache folder (``off``, ``0`` or empty: no disk cache)."""
TEST_POSES = 16
"""Fixed test poses at which the rows of the problem enter the key."""
_FIELDS = tuple(f.name for f in dataclasses.fields(ApproximateDesign))


def cache_dir() -> Path | None:
    """The cache folder (not created), or None when disabled by ``$KPIOED_CACHE``."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        return None if env.strip().lower() in ("", "0", "off", "none") else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "kpioed"


def problem_key(problem: Problem, *, collision: bool, seed: int, settings: dict) -> str:
    """Hex SHA-256 key of a certificate search (module docstring: what it covers)."""
    lo, up = problem.robot.lower, problem.robot.upper
    u = np.random.default_rng(20261201).random((TEST_POSES, problem.robot.n_joints))
    q = lo + u * (up - lo)
    rows, _ = DesignConstraints(problem, collision=True).evaluate(q)
    h = hashlib.sha256()
    h.update(
        repr(
            (CACHE_VERSION, problem.robot.name, bool(collision), int(seed), sorted(settings.items()))
        ).encode()
    )
    jm = problem.robot.joint_map  # its couplings restrict the poses searched
    coupling = np.concatenate([m.ravel() for m in jm.coupling_equations()]) if jm else np.zeros(0)
    for a in (lo, up, problem.F1(q), np.asarray(rows, dtype=float), problem.Js(), coupling):
        arr = np.ascontiguousarray(a, dtype=float)
        h.update(repr(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _path(key: str) -> Path | None:
    folder = cache_dir()
    return None if folder is None else folder / f"certificate-{key[:32]}.npz"


def load(key: str) -> ApproximateDesign | None:
    """The stored design of ``key``, or None (no cache, no file, or a file that does not read)."""
    path = _path(key)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            values = {name: z[name] for name in _FIELDS}
    except (OSError, ValueError, KeyError):
        return None
    for name in ("phi", "dual", "g_max", "solve_s"):
        values[name] = float(values[name])
    for name in ("rounds", "n_searched", "n_checked"):
        values[name] = int(values[name])
    for name in ("converged", "collision"):
        values[name] = bool(values[name])
    return ApproximateDesign(**values)


def store(key: str, approx: ApproximateDesign) -> Path | None:
    """Write ``approx`` under ``key`` atomically; the path, or None (no cache or not writable)."""
    path = _path(key)
    if path is None:
        return None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=path.parent)
    except OSError:
        return None
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez_compressed(f, key=np.array(key), **{n: np.asarray(getattr(approx, n)) for n in _FIELDS})
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)
        return None
    return path


def unit_noise(problem: Problem) -> Problem:
    """``problem`` with unit noise, the one whose search is stored: ``sigma`` 1 and a probe's
    orientation noise ``sigma_rot`` over ``sigma`` (every row of F1 times ``sigma``, so that the
    certificate's ``with_noise`` scales back)."""
    rot = None if problem.sigma_rot is None else problem.sigma_rot / problem.sigma
    return dataclasses.replace(problem, sigma=1.0, sigma_rot=rot)
