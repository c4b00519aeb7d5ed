"""kpioed-drake: KPI-based optimum experimental design and calibration of industrial robots.

Implements Jost, Kudruss, Koerkel, Walter (2017), "A computational method for
key-performance-indicator-based parameter identification of industrial manipulators", on Drake.
See ``docs/ARCHITECTURE.md`` for the module map and ``kpioed_drake.api`` for the Python API.
"""

import os

# One BLAS thread: the package's linear algebra is many small products (3n x 30 Jacobians), and
# BLAS threads only add contention (docs/design.md). Set before numpy is first imported (so for the
# ``kpioed`` command); a value the user set is kept.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
