"""The laser tracker: its measurement model (paper eq. 3, 4, 12), measured data, feasibility.

- :mod:`.measurement`: ``h(p, q)``, its Jacobian, incidence, the KPI Jacobian;
- :mod:`.orientation`: a 6-DoF probe's orientation ``R_TP(p, q)``, its residual and Jacobian, the
  probe's first registration;
- :mod:`.data`: the one :class:`~kpioed_drake.tracker.data.Measurements` type and the read of a
  measurement file into it (the file formats: :mod:`kpioed_drake.files.tables`);
- :mod:`.orientation`: a 6-DoF probe's orientation ``R_TP``, its residual, Jacobian and joint
  derivatives, the TCP frame's angular Jacobian (the orientation KPI);
- :mod:`.kpi`: the KPI's inputs checked (working poses, weights, KPI point, point or pose
  measurements, the orientation's noise and weight L in the KPI);
- :mod:`.feasibility`: the independent checker (Drake signed distances, limits, incidence; eq. 24b).
"""
