"""Statistics of the calibration: the one estimator, its covariance (eq. 19), criteria and tests.

- :mod:`.estimator`: Levenberg-Marquardt (eq. 6) on position (and orientation) rows, the estimate's
  covariance; :mod:`.registration`: the tracker's and a probe's closed-form first registration;
- :mod:`.covariance`: eq. 19 in KKT, Cholesky and null-space (Appendix) forms;
- :mod:`.criteria`: the design criteria (eq. 24a, 25, 8) with closed-form gradients;
- :mod:`.problem`: F1 (eq. 24d), Js (eq. 24e), Cp, Cs of a robot, cell and working poses;
- :mod:`.identifiability`, :mod:`.residuals`, :mod:`.plausibility`, :mod:`.multiplicity`: rank tests,
  studentised residuals, checks of the data before a fit, family-wise p-values;
- :mod:`.accuracy`: the accuracy figures every report prints (fit or held-out, per target);
- :mod:`.noise`: the sigma a diagnosis rests on (given, repeated poses or the residuals' scale).
"""
