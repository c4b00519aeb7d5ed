"""The outcome of one online step (:class:`NextReport`): its JSON record and summary."""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.calibration.report import CalibrationReport
from kpioed_drake.robot.jointmap import q_to_file
from kpioed_drake.robot.models import Robot


@dataclasses.dataclass
class NextReport:
    """Outcome of one step.

    Attributes:
        done: the precision is reached (``kpi_avg_var_mm2 <= target_var_mm2``): stop measuring.
        n_measured: poses measured so far (distinct joint values).
        kpi_avg_var_mm2: tr(Cs)/3 now [mm^2] (a-posteriori when the fit rejects).
        aposteriori: whether the a-posteriori noise was used.
        sigma_used_mm: the noise the variance and the design use [mm].
        target_var_mm2: the precision asked for [mm^2].
        q_next: (n, n_joints) the next poses [rad] (empty when done).
        predicted_kpi_avg_var_mm2: tr(Cs)/3 of the measured and the next poses together [mm^2].
        n_planned: poses the step planned ahead (the next ones are the most useful of them).
        q_plan: (n_planned, n_joints) the planned poses [rad] (the next ones among them): the
            ``plan`` of the following step.
        min_more_poses: fewest more poses with which the target can be reached at all: with
            fewer, the dual bound of the design with the measured information
            (:func:`~kpioed_drake.design.approximate.given.fewest_certified`) exceeds it, for any
            feasible poses the search reached (nominal kinematics, the noise used); 0 when done,
            ``max_plan + 1`` when not even ``max_plan`` can.
        certificate: the certificate of the combined design (None when done or not asked).
        report: the calibration on the data so far.
        position_var_mm2: data with a 6-DoF probe's orientations: the TCP position's tr(C)/3 now
            [mm^2] (``kpi_avg_var_mm2`` adds ``L^2`` times the orientation's); None for points.
        orientation_std_deg: the TCP orientation's RMS standard deviation per axis now [deg]
            (a-posteriori when the fit rejects); None for points.
        kpi_orientation_mm: L [mm], the orientation's weight in the KPI (0: not in it).
        target_deg: the orientation's precision asked for [deg], or None.
        sigma_deg_used: the orientation noise the design uses [deg]; None for points.
        predicted_orientation_std_deg: the orientation's RMS standard deviation of the measured
            and the next poses together [deg] (nominal kinematics, the noise used); None for points
            or when done.
    """

    done: bool
    n_measured: int
    kpi_avg_var_mm2: float
    aposteriori: bool
    sigma_used_mm: float
    target_var_mm2: float
    q_next: np.ndarray
    predicted_kpi_avg_var_mm2: float | None
    n_planned: int
    q_plan: np.ndarray
    min_more_poses: int
    certificate: dict | None
    report: CalibrationReport
    position_var_mm2: float | None = None
    orientation_std_deg: float | None = None
    kpi_orientation_mm: float = 0.0
    target_deg: float | None = None
    sigma_deg_used: float | None = None
    predicted_orientation_std_deg: float | None = None

    @property
    def with_orientation(self) -> bool:
        """The data hold a 6-DoF probe's orientations."""
        return self.orientation_std_deg is not None

    def to_dict(self, robot: Robot) -> dict:
        """The JSON record (mm, deg)."""
        cert = self.certificate or {}
        return {
            "done": self.done,
            "n_measured": self.n_measured,
            "kpi_avg_var_mm2": self.kpi_avg_var_mm2,
            "target_var_mm2": self.target_var_mm2,
            "aposteriori": self.aposteriori,
            "sigma_used_mm": self.sigma_used_mm,
            "chi2_per_dof": self.report.chi2_per_dof,
            "kpi_mm": np.asarray(self.report.kpi).tolist(),
            "kpi_cov_mm2": (
                self.report.kpi_cov * (self.sigma_used_mm / self.report.result.sigma) ** 2
            ).tolist(),
            "predicted_kpi_avg_var_mm2": self.predicted_kpi_avg_var_mm2,
            "bound_mm2": cert.get("bound_mm2"),
            "efficiency": cert.get("efficiency"),
            "n_next": int(len(self.q_next)),
            "n_planned": self.n_planned,
            "min_more_poses": self.min_more_poses,
            "next_q_deg": q_to_file(robot, self.q_next).tolist() if len(self.q_next) else [],
            **self._orientation_dict(),
        }

    def _orientation_dict(self) -> dict:
        """The record's ``orientation`` block (data with orientations; nothing for points)."""
        if not self.with_orientation:
            return {}
        return {
            "orientation": {
                "position_var_mm2": self.position_var_mm2,
                "orientation_std_deg": self.orientation_std_deg,
                "kpi_orientation_mm": self.kpi_orientation_mm,
                "target_deg": self.target_deg,
                "sigma_deg_used": self.sigma_deg_used,
                "predicted_orientation_std_deg": self.predicted_orientation_std_deg,
                "note": "kpi_avg_var_mm2 = position_var_mm2 + kpi_orientation_mm^2 x orientation variance "
                "[rad^2]; with target_deg, kpi_orientation_mm = sqrt(target_var_mm2) / target_deg [rad], "
                "so that done means position_var_mm2 / target_var_mm2 + (orientation_std_deg / "
                "target_deg)^2 <= 1",
            }
        }

    def _orientation_lines(self) -> list[str]:
        """The summary's line on the TCP's orientation (data with orientations; none for points)."""
        if not self.with_orientation:
            return []
        L = self.kpi_orientation_mm
        if self.target_deg is not None:
            weight = (
                f"target {self.target_deg:g} deg; in the KPI as {L:.4g} mm x angle, so done means "
                f"position / {self.target_var_mm2:g} mm^2 + (orientation / {self.target_deg:g} deg)^2 <= 1"
            )
        else:
            weight = f"in the KPI as {L:g} mm x angle" if L > 0 else "not in the KPI: the position alone"
        return [
            f"  position tr(C)/3 = {self.position_var_mm2:.4g} mm^2; orientation precision "
            f"{self.orientation_std_deg:.4g} deg RMS per axis ({weight})"
        ]

    def summary(self) -> str:
        """A short human-readable summary."""
        post = " (a-posteriori: the fit rejects)" if self.aposteriori else ""
        head = (
            f"{self.n_measured} poses measured: tr(Cs)/3 = {self.kpi_avg_var_mm2:.4g} mm^2{post}, "
            f"target {self.target_var_mm2:g} mm^2"
        )
        forced = [f"  warning: {w}" for w in self.report.warnings if w.startswith("forced:")]
        top = [head, *self._orientation_lines(), *forced]
        if self.done:
            return "\n".join([*top, "  done: the precision is reached; nothing to measure"])
        p = self.predicted_orientation_std_deg
        lines = [
            *top,
            f"  next {len(self.q_next)} poses: combined tr(Cs)/3 = {self.predicted_kpi_avg_var_mm2:.4g} mm^2"
            + ("" if p is None else f", orientation {p:.4g} deg RMS per axis"),
            f"  planned {self.n_planned} more; at least {self.min_more_poses} more are needed "
            "(with fewer, the certified bound exceeds the target)",
        ]
        if self.certificate is not None:
            c = self.certificate
            lines.append(f"  bound {c['bound_mm2']:.4g} mm^2, efficiency {c['efficiency']:.3f}")
        return "\n".join(lines)
