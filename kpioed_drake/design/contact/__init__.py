"""The KPI design of contact systems: plane touches or a pivot ballbar, one row per pose.

:mod:`.surfaces` (the systems: planes, and ballbar pivots whose spheres the tool ball stays on; each
one's residual, gradient, rows and rules), :mod:`.poses` (the feasible set: poses on a surface,
sampled, projected and checked), :mod:`.problem` (:class:`ContactProblem`: F1 of the poses and its
closed-form dF1/dq, the contact gauge) and :mod:`.design` (the approximate design on the surfaces by
column generation with a search that stays on them, its rounding and the certificate's lower bound).
"""
