"""Online calibration (the paper's Outlook): re-identify after each batch of measurements, design
the next poses with the measured poses' information and the noise the data show, stop at a
guaranteed TCP precision.

- :mod:`.options`: :class:`NextOptions`, the settings of one step;
- :mod:`.step`: :func:`next_poses`, one step (calibrate, the TCP variance now, done or the next
  poses of a plan to the target);
- :mod:`.report`: :class:`NextReport`, the outcome of a step, its JSON record and summary;
- :mod:`.workflow`: :func:`next_file`, ``kpioed next`` on files (the plan carried from step to step);
- :mod:`.loop`: :func:`closed_loop`, a simulated robot measured in rounds until the loop stops, for
  the study of how many poses it needs and how often the true TCP lies within the reported ellipsoid;
  :func:`start_bound`, how well any number of poses can do after the loop's start.
"""

from kpioed_drake.online.loop import closed_loop, start_bound
from kpioed_drake.online.options import NextOptions
from kpioed_drake.online.report import NextReport
from kpioed_drake.online.step import next_poses
from kpioed_drake.online.workflow import next_file

__all__ = ["NextOptions", "NextReport", "closed_loop", "next_file", "next_poses", "start_bound"]
