"""The exact design: n poses optimised by SNOPT/IPOPT in a Drake ``MathematicalProgram`` (paper eq. 24).

:mod:`.objective` (cost and gradient), :mod:`.constraints` (incidence and clearance rows),
:mod:`.program` (the program), :mod:`.check` (the independent check) and :mod:`.solve` (solver runs,
the all-rows retry, block sweeps). The entry point with its starts is
:func:`kpioed_drake.design.optimize.optimize_design`.
"""
