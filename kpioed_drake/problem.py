"""The identification problem of one robot in one cell: F1, Js, Cp, Cs for a set of poses.

Bundles the robot, the cell, the nominal measurement model, the working pose and the noise, and
evaluates paper eqs. (19), (24c)-(24e) for a design: ``F1 = dh/dp / sigma`` over the 27 estimated
parameters (rows pose-major: x, y, z of pose 1, then pose 2, ...), ``Js = dTCP/dp`` at ``q_work``,
``Cp = (F1^T F1)^-1`` and ``Cs = Js Cp Js^T``.

Model extensions (non-geometric effects of :mod:`kpioed_drake.effects`, e.g. joint elasticity)
add parameters: their measurement columns are appended to F1 (and to dF1/dq) and their TCP
columns to Js, so that a design for the extended model estimates them too and its KPI variance
includes them (paper outlook; issue "model discrepancy").
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake import covariance
from kpioed_drake.errors import InputError
from kpioed_drake.measurement import TrackerModel, kpi_jacobian, measurement_jacobian, nominal_model
from kpioed_drake.models import Cell, Robot, load_cell, load_robot


@dataclasses.dataclass(frozen=True)
class Problem:
    """Everything the covariance of a design depends on.

    Attributes:
        robot, cell: the models (cell as loaded for this robot).
        model: measurement model at the parameter values the design is evaluated at.
        q_work: (6,) working configuration [rad].
        sigma: noise standard deviation per coordinate [mm].
        tool_offset: (3,) TCP relative to the reflector, flange axes [mm].
    """

    robot: Robot
    cell: Cell
    model: TrackerModel
    q_work: np.ndarray
    sigma: float
    tool_offset: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    extensions: tuple = ()

    @property
    def free(self) -> np.ndarray:
        return self.model.layout.free

    @property
    def n_params(self) -> int:
        """Estimated parameters: 27 geometric plus those of the extensions."""
        return self.model.layout.n_free + sum(e.n_params for e in self.extensions)

    @property
    def param_names(self) -> list[str]:
        from kpioed_drake.effects import extension_param_names

        return self.model.layout.free_names + extension_param_names(self.extensions)

    @property
    def scale(self) -> np.ndarray:
        """(k,) scaling of the standard criterion to millimetres at the tool.

        SPEC: lengths 1, angles times the reach. An extension parameter is scaled by how far one
        unit of it moves the TCP at ``q_work`` (its KPI column's norm) [mm per unit].
        """
        geo = self.model.layout.scale(self.robot.reach)
        if not self.extensions:
            return geo
        ext = np.linalg.norm(self._ext_kpi_columns(), axis=0)
        return np.concatenate([geo, np.where(ext > 0, ext, 1.0)])

    def _ext_kpi_columns(self) -> np.ndarray:
        from kpioed_drake.effects import effect_kpi_columns

        return effect_kpi_columns(self.model, self.q_work, self.extensions, tool_offset=self.tool_offset)

    def min_poses(self) -> int:
        """Fewest poses whose 3 coordinates can determine the parameters."""
        return int(np.ceil(self.n_params / 3))

    def F1(self, q, *, with_dq: bool = False, frames=None):
        """Weighted identification Jacobian (3n, 27); with ``with_dq`` also (n, 6, 3, 27).

        ``frames``: ``self.model.frames(q)`` if the caller has it already.
        """
        out = measurement_jacobian(self.model, q, with_dq=with_dq, frames=frames)
        H = out[1][:, :, self.free] / self.sigma
        dH = out[2][..., self.free] / self.sigma if with_dq else None
        if self.extensions:
            from kpioed_drake.effects import extension_columns

            ext = extension_columns(self.model, q, self.extensions, with_dq=with_dq)
            E, dE = (ext[0], ext[1]) if with_dq else (ext, None)
            H = np.concatenate([H, E / self.sigma], axis=2)
            if with_dq:
                dH = np.concatenate([dH, dE / self.sigma], axis=3)
        n = H.shape[0]
        if not with_dq:
            return H.reshape(3 * n, -1)
        return H.reshape(3 * n, -1), dH

    def Js(self) -> np.ndarray:
        """(3, 27) KPI Jacobian at ``q_work``."""
        _, Js = kpi_jacobian(self.model, self.q_work, self.tool_offset)
        Js = Js[:, self.free]
        if self.extensions:
            Js = np.concatenate([Js, self._ext_kpi_columns()], axis=1)
        return Js

    def covariances(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``Cp`` (27, 27) and ``Cs`` (3, 3) [mm^2] of a design ``q`` (n, 6) [rad].

        Raises:
            InputError: if the design does not determine all parameters.
        """
        try:
            return covariance.kpi_covariance(self.F1(q), self.Js())
        except np.linalg.LinAlgError:
            raise InputError(
                f"the {len(np.atleast_2d(q))} poses do not determine the {self.n_params} parameters "
                "(information matrix singular); use more or more varied poses"
            ) from None

    def criteria(self, q) -> dict[str, float]:
        """``kpi_avg_var_mm2`` (tr(Cs)/3) and ``param_crit`` (scaled tr(Cp)) of a design."""
        Cp, Cs = self.covariances(q)
        return {
            "kpi_avg_var_mm2": float(np.trace(Cs) / 3.0),
            "param_crit": float(np.sum(np.diag(Cp) * self.scale**2)),
        }


def make_problem(
    robot: str | Robot,
    *,
    cell_path=None,
    q_work: np.ndarray | None = None,
    sigma_mm: float | None = None,
    tool_offset_mm=(0.0, 0.0, 0.0),
    extend=(),
) -> Problem:
    """Build the :class:`Problem` of a robot (name, file path or :class:`Robot`).

    Args:
        q_work: (6,) [rad]; default: the model file's ``q_work_deg``.
        sigma_mm: noise per coordinate [mm]; default: the cell's ``noise_sigma_mm``.
        extend: model extensions, e.g. ``["joint_elasticity:2", "gear_cyclic:4:2"]`` (texts of
            :func:`kpioed_drake.effects.parse_effect`, values not needed). Only effects that do not
            need per-pose temperature or time (elasticity, gear errors) can extend a design.
    """
    robot = load_robot(robot) if isinstance(robot, str) else robot
    cell = load_cell(cell_path, robot=robot)
    if q_work is None:
        if robot.q_work is None:
            raise InputError(f"{robot.name}: the model file has no q_work_deg; pass --q-work")
        q_work = robot.q_work
    q_work = np.asarray(q_work, dtype=float)
    if np.any(q_work < robot.lower - 1e-9) or np.any(q_work > robot.upper + 1e-9):
        raise InputError(f"{robot.name}: q_work is outside the joint limits")
    sigma = cell.sigma if sigma_mm is None else float(sigma_mm)
    if not np.isfinite(sigma) or sigma <= 0:
        raise InputError(f"--sigma-mm must be a positive number of millimetres, got {sigma_mm!r}")
    exts = _parse_extensions(extend)
    return Problem(
        extensions=exts,
        robot=robot,
        cell=cell,
        model=nominal_model(robot, cell),
        q_work=q_work,
        sigma=sigma,
        tool_offset=np.asarray(tool_offset_mm, dtype=float),
    )


def _parse_extensions(extend) -> tuple:
    if not extend:
        return ()
    from kpioed_drake.effects import parse_effect

    out = []
    for e in extend:
        eff = parse_effect(e) if isinstance(e, str) else e
        if eff.family not in ("joint_elasticity", "gear_cyclic"):
            raise InputError(
                f"--extend {eff.name}: only joint_elasticity and gear_cyclic can extend a design or an "
                "evaluation (thermal_expansion and tracker_drift need per-pose temperature and time)"
            )
        if any(o.key == eff.key for o in out):
            raise InputError(f"--extend {eff.name} is given twice")
        out.append(eff)
    return tuple(out)
