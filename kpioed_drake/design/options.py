"""The settings of one design (:class:`DesignOptions`): what :func:`~kpioed_drake.design.run_design`
optimises and how, checked when the record is made."""

from __future__ import annotations

import dataclasses

from kpioed_drake.arguments import check_count, check_positive, check_seed, require
from kpioed_drake.design.settings import DESIGN_METHODS, SOLVERS
from kpioed_drake.errors import check_sigma
from kpioed_drake.tracker.kpi import MEASURES


@dataclasses.dataclass(frozen=True)
class DesignOptions:
    """The settings of one design (``kpioed design``); read from YAML with
    :func:`kpioed_drake.options.load_options`."""

    criterion: str = "kpi"
    """The design criterion (:data:`~kpioed_drake.design.settings.DESIGN_METHODS`): ``kpi`` (the
    TCP variance at the working poses, paper eq. 24), ``param`` (the standard A-criterion) or
    ``heuristic``."""
    n: int = 60
    """Poses to design (with ``given``: new poses)."""
    sigma_mm: float | None = None
    """Measurement noise per coordinate [mm] (None: the cell's)."""
    collision: bool = True
    """Avoid collisions of the robot, the cell and the laser beam (paper eq. 25)."""
    solver: str = "snopt"
    """The nonlinear solver (:data:`~kpioed_drake.design.settings.SOLVERS`)."""
    seed: int = 0
    """Seed of the random starts."""
    starts: int = 1
    """Solver starts; the best feasible design wins."""
    start: str | None = None
    """The first start: ``approximate`` (the approximate design's support), ``heuristic`` or a
    design CSV (None: the approximate design for ``kpi``)."""
    allow_infeasible: bool = False
    """Return (and write) a failed or infeasible design instead of raising."""
    certify: bool | None = None
    """Add the optimality certificate (a bound on tr(Cs)/3 and the design's efficiency); None:
    certify unless ``discriminate``."""
    extend: tuple[str, ...] = ()
    """Model extensions (e.g. ``joint_elasticity:2``) the design also estimates; the KPI variance
    includes them."""
    kpi_aggregate: str = "mean"
    """``mean`` (weighted mean of the working poses' tr(Cs_k)/3) or ``max`` (the worst one)."""
    target_var_mm2: float | None = None
    """Find the fewest poses whose design reaches tr(Cs)/3 <= this [mm^2] (``n`` is then not
    used)."""
    discriminate: str | None = None
    """``"A|B"``, two competing explanations: poses that tell them apart (instead of
    ``criterion``)."""
    condition_span: str | None = None
    """With ``discriminate``: the span of block 2 from block 1 (``"3K"``, ``"600s"``; None: the
    span for power 0.8)."""

    measure: str = "point"
    """What a pose measures: ``point`` (the reflector's position, 3 rows) or ``pose`` (a 6-DoF
    probe's position and orientation, 6 rows; the probe's rotation on the flange is estimated)."""
    sigma_deg: float | None = None
    """``pose``: the orientation's noise per tracker axis [deg] (None:
    :data:`~kpioed_drake.tracker.kpi.SIGMA_ROT_DEG`, 0.005 deg)."""
    kpi_orientation_mm: float = 0.0
    """L [mm]: the TCP's orientation joins the KPI as the displacement ``L * angle`` it makes at L mm
    from the TCP, tr(Cs)/3 = v_pos + L^2 v_rot (0: the position alone, the paper's KPI)."""

    def __post_init__(self):
        self._check_discriminate()
        require(
            self.measure in MEASURES,
            f"measure: expected one of {', '.join(MEASURES)}, got {self.measure!r}",
            fields=("measure",),
        )
        require(
            self.criterion in DESIGN_METHODS,
            f"criterion: expected one of {', '.join(DESIGN_METHODS)}, got {self.criterion!r}",
            fields=("criterion",),
        )
        require(
            self.solver in SOLVERS,
            f"solver: expected one of {', '.join(SOLVERS)}, got {self.solver!r}",
            fields=("solver",),
        )
        check_count("n", self.n)
        check_count("starts", self.starts)
        check_seed(self.seed)
        check_sigma(self.sigma_mm, allow_none=True)
        check_positive("target_var_mm2", self.target_var_mm2, allow_none=True)
        check_positive("sigma_deg", self.sigma_deg, allow_none=True)
        check_positive("kpi_orientation_mm", self.kpi_orientation_mm, zero_ok=True)
        require(
            self.measure == "pose" or self.sigma_deg is None,
            "sigma_deg is the orientation noise of pose measurements",
            fields=("sigma_deg", "measure"),
        )
        object.__setattr__(self, "extend", tuple(self.extend or ()))

    def _check_discriminate(self) -> None:
        """InputError where ``discriminate`` meets a setting it excludes."""
        if self.discriminate is not None:
            require(
                self.criterion == "kpi",
                f"discriminate replaces criterion (got {self.criterion!r})",
                fields=("discriminate", "criterion"),
            )
            require(
                self.target_var_mm2 is None and not self.certify,
                "discriminate takes no target_var_mm2 or certify",
                fields=("discriminate", "target_var_mm2", "certify"),
            )
        require(
            self.discriminate is None or (self.measure == "point" and not self.kpi_orientation_mm),
            "discriminate tells explanations apart with point measurements and no orientation KPI",
            fields=("discriminate", "measure", "kpi_orientation_mm"),
        )
        require(
            self.discriminate is not None or self.condition_span is None,
            "condition_span goes with discriminate",
            fields=("condition_span", "discriminate"),
        )

    @property
    def certified(self) -> bool:
        """Whether the design gets its certificate."""
        return bool(self.certify) or (self.certify is None and self.discriminate is None)
