"""The approximate design (weights on poses) and the certified lower bound on any n-pose design.

:mod:`.search` (local maxima of the pricing function), :mod:`.pool` (the optimum over a finite pool,
the cone program, by :mod:`.barrier`'s structured Newton method), :mod:`.design` (column
generation, rounding: the optimiser's approximate start), :mod:`.certificate` (the bound and a
design's efficiency) and :mod:`.certcache` (the bound's disk cache); with poses already
measured, :mod:`.given` (the approximate design added to them and the tight bound it gives) and
:mod:`.sequential` (the candidates chosen with the measured poses' information, the poses of a
plan to measure first).
"""
