"""kpioed-drake: KPI-based optimum experimental design and calibration of industrial robots.

Implements Jost, Kudruss, Koerkel, Walter (2017), "A computational method for
key-performance-indicator-based parameter identification of industrial manipulators", on Drake.
See ``docs/ARCHITECTURE.md`` for the module map and ``kpioed_drake.api`` for the Python API.
"""

import os

# The package's linear algebra is many small products (3n x 30 Jacobians); BLAS threads only add
# contention: on the 2-core machine a 1000-pose diagnosis took 45 s with OpenBLAS's default threads
# and 6.8 s with one (bench/results.md, "Calibration and diagnosis of 1000 poses"). Set before numpy
# is first imported (so for the ``kpioed`` command); a value the user set is kept.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
