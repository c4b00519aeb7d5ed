import sys

from kpioed_drake.cli import main

sys.exit(main())
