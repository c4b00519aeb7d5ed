"""What ``kpioed compensate`` computed and wrote: :class:`CompensationReport` and its summary."""

from __future__ import annotations

import dataclasses

import numpy as np

from kpioed_drake.compensation.solve import Compensation

LARGE_CORRECTION = (5.0, 50.0)
"""A correction beyond this [deg; prismatic mm] is reported (near a singularity a small error of
the point or orientation takes a large joint motion)."""


@dataclasses.dataclass(frozen=True)
class CompensationReport:
    """What ``kpioed compensate`` computed and wrote.

    Attributes:
        robot: the calibrated model's name; nominal: the nominal model's (programs), else None.
        source: the input file; mode: ``"program"`` or ``"targets"``; out: the file written.
        rows: (n,) the input's row numbers.
        q: (n, nj) the solution in the output's angles and file units [deg; prismatic mm].
        dq: (n,) ``dq_deg``: the largest change of a joint [deg; prismatic mm].
        result: the solver's :class:`~kpioed_drake.compensation.solve.Compensation`.
        effects: names of the effects compensated.
        text: the CSV text written.
    """

    robot: str
    nominal: str | None
    source: str
    mode: str
    out: str
    rows: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    result: Compensation
    effects: tuple[str, ...]
    text: str

    def summary(self) -> str:
        """A human-readable summary."""
        r, n = self.result, self.rows.size
        against = f" (nominal {self.nominal})" if self.nominal else ""
        lines = [
            f"{self.robot}{against}: {n} {self.mode} rows of {self.source}, "
            f"{int(np.count_nonzero(r.reachable))} reached"
            + (f", effects {', '.join(self.effects)}" if self.effects else ""),
            f"  residual max {np.max(r.residual_mm):.3g} mm; correction median {np.median(self.dq):.4g}, "
            f"max {np.max(self.dq):.4g} deg",
        ]
        lines += [f"  row {row}: {why}" for row, why in zip(self.rows, r.reasons, strict=True) if why]
        big: np.ndarray | list = self.rows[self.dq > LARGE_CORRECTION[0]] if self.mode == "program" else []
        if len(big):
            lines.append(
                f"  warning: corrections over {LARGE_CORRECTION[0]:g} deg in rows "
                f"{', '.join(map(str, big[:10]))} (near a singularity)"
            )
        return "\n".join(lines + [f"  wrote {self.out}"])
