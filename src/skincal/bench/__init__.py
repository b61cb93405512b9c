"""skincal.bench: benchmark drivers that string simulation, faults and calibration together.

``runner`` maps a picklable job function over jobs in local processes or on a Dask cluster (shared
by every benchmark); ``robustness`` is ``skincal benchmark robustness``. Nothing in the library
packages imports this one.
"""
