"""The laser tracker: its measurement model (paper eq. 3, 4, 12), measured data and their files, feasibility.

- :mod:`.measurement`: ``h(p, q)``, its Jacobian, incidence, the KPI Jacobian;
- :mod:`.data`: the one :class:`~kpioed_drake.tracker.data.Measurements` type and its CSV reader;
- :mod:`.formats`: files of other tools (format files);
- :mod:`.csvio`: design and measurement CSV columns, row/column messages, JSON values;
- :mod:`.feasibility`: the independent checker (Drake signed distances, limits, incidence; eq. 24b).
"""
