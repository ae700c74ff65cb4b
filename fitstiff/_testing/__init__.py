"""Synthetic datasets shared by the test suite and the benchmarks (private, like
``numpy.testing``: no stability promise; it lives in the package so that both import it from
an installed fitstiff, a fresh clone included).

- :mod:`~fitstiff._testing.recovery`: the parameter-recovery datasets (four logs at 0-6 bar);
- :mod:`~fitstiff._testing.calibration`: the posterior-calibration datasets (two logs, AR(1)
  force noise, truths drawn over realistic ranges);
- :mod:`~fitstiff._testing.speed`: the 4 000-sample log of the fit and posterior speed
  benchmarks;
- :mod:`~fitstiff._testing.rig_sim`: an independent NumPy rig simulator (no physics code
  shared with fitstiff);
- :mod:`~fitstiff._testing.withheld`: the withheld-effect datasets made with it.

The benchmarks that score these datasets stay in ``benchmarks/``. A seed gives the same data
as before the move (issue 14).
"""
