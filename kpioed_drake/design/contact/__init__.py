"""The KPI design of plane contacts: touches of given planes, one row per pose.

:mod:`.poses` (the feasible set: poses whose tool point lies on a plane, sampled, projected and
checked), :mod:`.problem` (:class:`PlaneProblem`: F1 of touches and its closed-form dF1/dq, the
contact gauge) and :mod:`.design` (the approximate design on the planes by column generation with
a search that stays on them, its rounding and the certificate's lower bound).
"""
