"""skincal.workflows: the layer that strings the library packages together, below the CLI.

The library packages (kinematics, skin, protocol, sim, data, calib, perception, control, hw) depend only
downward and never import this layer, ``viz`` or ``cli``; ``cli`` and ``benchmarks/`` call into it
(docs/design.md, "Layout"; checked by tests/test_architecture.py). Modules:

* ``session``: the one factory of simulated sessions from preset names (protocol fitted to the robot);
* ``sweep``: a job function mapped over jobs in local processes or on a Dask cluster;
* benchmarks: ``bench_mle``, ``table1``, ``bench_core``, ``robustness``, ``bench_rosbag``, ``bench_avoid``;
* the closed-loop avoidance experiment: ``avoidance`` (the MuJoCo loop), ``scenarios``, ``avoid_metrics``,
  ``avoid_plot``, ``playback`` (a run as a viewer recording);
* ``script``: the error handling of the scripts in ``benchmarks/``.
"""
