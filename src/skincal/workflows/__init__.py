"""skincal.workflows: the layer that strings the library packages together, below the CLI.

The library packages (kinematics, skin, protocol, sim, data, calib, perception, control, hw) depend only
downward; this layer builds simulated sessions (``session``), runs sweeps of independent jobs in local
processes or on Dask (``sweep``), and holds the benchmarks and the closed-loop avoidance experiment.
``cli`` and ``benchmarks/`` call into it. See docs/design.md ("Layout").
"""
