"""The published numbers of the paper that the study compares with (data only, no computation).

Source: F. Jost, M. Kudruss, S. Körkel and S. F. Walter, "A computational method for
key-performance-indicator-based parameter identification of industrial manipulators", J. Math.
Industry 7:7 (2017) (../shared/paper/kpi-oed-manipulators-2017.md): Table 6 (three KUKA robots),
Table 7 (minimum and maximum over the 90 notional robots), Table 8 (means over the 90 notional
robots) and section 3.3.2 (share of colliding poses of designs made without collision avoidance).

Every value is the KPI average variance tr(Cs)/3 [mm^2] of a 60-pose design: the A criterion (paper
eq. 24a) of the covariance Cs of the tool centre point at the working pose (eq. 25).
``None`` stands for the paper's "-" (not given). Keys: ``heuristic`` = the seeded random design,
``param`` = phi_A(Cp) (the paper's "standard method"), ``kpi`` = phi_A(Cs) (the paper's "KPI
method"); ``ca``/``noca`` = optimised with/without collision avoidance.
"""

from __future__ import annotations

TABLE6: dict[str, dict[str, float]] = {
    # robot -> heuristic, phi_A(Cp) with CA, phi_A(Cs) with CA; our kr16 is the paper's KR 15
    "kr16": {"heuristic": 0.59, "param_ca": 0.40, "kpi_ca": 0.33},
    "kr300": {"heuristic": 0.58, "param_ca": 0.39, "kpi_ca": 0.35},
    "kr500": {"heuristic": 0.61, "param_ca": 0.40, "kpi_ca": 0.35},
}
"""Paper Table 6: the KUKA robots, one design each."""

TABLE7: dict[str, dict[str, float | None]] = {
    # method -> min/max over the 90 notional robots, without and with collision avoidance
    "heuristic": {"noca_min": None, "noca_max": None, "ca_min": 0.55, "ca_max": 0.71},
    "param": {"noca_min": 0.39, "noca_max": 0.39, "ca_min": 0.42, "ca_max": 0.45},
    "kpi": {"noca_min": 0.33, "noca_max": 0.34, "ca_min": 0.34, "ca_max": 0.37},
}
"""Paper Table 7: minimum and maximum over the 90 notional robots."""

TABLE8: dict[str, dict[str, float | None]] = {
    # method -> mean over the 90 notional robots, without and with collision avoidance
    "heuristic": {"noca_mean": None, "ca_mean": 0.61},
    "param": {"noca_mean": 0.39, "ca_mean": 0.43},
    "kpi": {"noca_mean": 0.33, "ca_mean": 0.35},
}
"""Paper Table 8: means over the 90 notional robots."""

COLLIDING_SHARE_NOCA: tuple[float, float] = (0.50, 0.70)
"""Section 3.3.2: 50-70 % of the poses of designs optimised without collision avoidance collide."""

PAPER = {
    "table6": TABLE6,
    "table7": TABLE7,
    "table8": TABLE8,
    "colliding_share_noca": COLLIDING_SHARE_NOCA,
}
"""All of the above in one mapping (``kpioed_drake.study.PAPER``, named in the study's report)."""
