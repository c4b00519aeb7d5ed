"""The laser tracker: its measurement model (paper eq. 3, 4, 12), measured data, feasibility.

- :mod:`.measurement`: ``h(p, q)``, its Jacobian, incidence, the KPI Jacobian;
- :mod:`.orientation`: a 6-DoF probe's orientation ``R_TP(p, q)``, its residual, Jacobian and joint
  derivatives, the probe's first registration, the TCP frame's angular Jacobian (the orientation KPI);
- :mod:`.data`: the one :class:`~kpioed_drake.tracker.data.Measurements` type and the read of a
  measurement file into it (the file formats: :mod:`kpioed_drake.files.tables`);
- :mod:`.kpi`: the KPI's inputs checked (working poses, weights, KPI point, point or pose
  measurements, the orientation's noise and weight L in the KPI);
- :mod:`.feasibility`: the independent checker (Drake signed distances, limits, incidence; eq. 24b);
- measurements without a tracker: :mod:`.contactdata` (the data types ``DistanceData`` and
  ``PlaneData``), :mod:`.distance` (lengths between tool points or to a pivot), :mod:`.plane`
  (a tool point touching a plane), :mod:`.contacts` (their parameters, starts, gauge and rows in a fit).
"""
