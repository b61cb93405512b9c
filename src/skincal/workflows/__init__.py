"""skincal.workflows: the layer that strings the library packages together, below the CLI.

The library packages (kinematics, skin, protocol, sim, data, calib, perception, control, hw) depend only
downward and never import this layer, ``bench``, ``viz`` or ``cli``; ``cli``, ``bench`` and ``benchmarks/``
call into it (docs/design.md, "Layout"; checked by tests/test_architecture.py). Modules:

* ``session``: the one factory of simulated sessions from preset names (protocol fitted to the robot);
* ``sweep``: a job function mapped over jobs in local processes or on a Dask cluster;
* ``fleet``: many datasets calibrated at once;
* ``handheld``: the hand-held IMU-only session (its benchmark is :mod:`skincal.bench.handheld`);
* the closed-loop avoidance experiment: ``experiment`` (``run_experiment(config)``, the one assembly of
  ``skincal avoid`` and the avoidance benchmark; a run's metrics), ``avoidance`` (the MuJoCo loop, the
  simulated and believed skin), ``stopping`` (the stopping model measured on the torque robot),
  ``avoid_plot``, ``playback`` (a run as a viewer recording);
* ``live``, ``adaptive``, ``monitoring`` (issue 16: the streaming calibrator followed live, the
  next-best-motion loop, work sessions and knocked units; the monitor's benchmark is
  :mod:`skincal.bench.monitor`).

Benchmarks are :mod:`skincal.bench`; scenario files :mod:`skincal.sim.scenarios`; flange tasks
:mod:`skincal.protocol.flange`; robot points and start configurations :mod:`skincal.kinematics.points`;
the stopping-model type :mod:`skincal.kinematics.stopping`; ISO/TS 15066 run metrics
:mod:`skincal.control.iso_metrics`.
"""
