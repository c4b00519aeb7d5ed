"""kpioed-drake: KPI-based optimum experimental design and calibration of industrial robots.

Implements Jost, Kudruss, Koerkel, Walter (2017), "A computational method for
key-performance-indicator-based parameter identification of industrial manipulators", on Drake.
See ``docs/ARCHITECTURE.md`` for the module map and ``kpioed_drake.api`` for the Python API.
"""

__version__ = "0.1.0"
