"""Designs that tell two explanations (effects) apart, and measurement plans of a condition.

:mod:`.explanations` (the competing models), :mod:`.design` (T-optimal poses through the KPI worst
case), :mod:`.conditions` and :mod:`.plan` (temperature, time or payload pairs: two blocks, the span).
"""
