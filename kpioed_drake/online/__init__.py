"""Online calibration (the paper's Outlook): re-identify after each batch of measurements, design
the next poses at the current estimate, stop at a guaranteed TCP precision.

- :mod:`.step`: :func:`next_poses` (one step: calibrate, the TCP variance now, done or the next
  poses) and :func:`next_file` (``kpioed next``);
- :mod:`.loop`: :func:`closed_loop`, a simulated robot measured in rounds until the loop stops, for
  the study of how many poses it needs and how often the true TCP lies within the reported ellipsoid.
"""

from kpioed_drake.online.loop import closed_loop
from kpioed_drake.online.step import NextOptions, NextResult, next_file, next_poses

__all__ = ["NextOptions", "NextResult", "closed_loop", "next_file", "next_poses"]
