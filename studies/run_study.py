"""Run the paper's study (Tables 6-8, Figures 7-8): ``python studies/run_study.py [--quick] --out DIR``.

A thin wrapper of :func:`kpioed_drake.study.run_study` (the same as ``kpioed study``).
"""

from __future__ import annotations

import sys

from kpioed_drake.cli import main

if __name__ == "__main__":
    sys.exit(main(["study", *sys.argv[1:]]))
