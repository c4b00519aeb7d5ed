"""kpioed-drake: KPI-based optimum experimental design and calibration of industrial robots.

Implements Jost, Kudruss, Koerkel, Walter (2017), "A computational method for
key-performance-indicator-based parameter identification of industrial manipulators", on Drake.
See ``docs/ARCHITECTURE.md`` for the module map and ``kpioed_drake.api`` for the Python API.

Packages (each docstring names its modules), lowest layer first: :mod:`.robot` (robot and cell
models, kinematics, the Drake plant), :mod:`.files` (the one reader of the tables the package
reads), :mod:`.tracker` (the measurement model and the tracker's data), :mod:`.effects`
(non-geometric effects), :mod:`.estimation` (the estimator, covariance, criteria, tests),
:mod:`.scene3d` (Meshcat pages), :mod:`.design`, :mod:`.simulation`, :mod:`.calibration`,
:mod:`.compensation`, :mod:`.online`, :mod:`.diagnosis`, :mod:`.study` (the workflows), and
:mod:`.cli` (the ``kpioed`` command). Modules: :mod:`.errors` (exit statuses, the errors),
:mod:`.outputs` (atomic writes, output paths), :mod:`.arguments` (checks of command arguments),
:mod:`.options` (options records from YAML), :mod:`.paper` (the paper's numbers),
:mod:`.progress` (progress of long runs on stderr), :mod:`.parallel` (independent tasks in forked
worker processes), :mod:`.api` (one function per command).
"""

import os

# One BLAS thread: the package's linear algebra is many small products (3n x 30 Jacobians), and
# BLAS threads only add contention (docs/design.md). Set before numpy is first imported (so for the
# ``kpioed`` command); a value the user set is kept.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
