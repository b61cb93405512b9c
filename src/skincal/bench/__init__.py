"""skincal.bench: every benchmark, beside ``workflows`` and below ``cli`` (docs/design.md, "Layout").

One harness protocol (:mod:`skincal.bench.harness`): options declared once (:class:`~skincal.bench.harness.Opt`)
serve both ``skincal benchmark ...`` (typer, :func:`~skincal.bench.harness.typer_params`) and the scripts in
``benchmarks/`` (argparse, :func:`~skincal.bench.harness.add_arguments`); a benchmark turns its options into a
config, the config into jobs, each job into a typed record, the records into a summary and the summary into
a report. Modules:

* ``table1`` (the paper's Table I), ``robustness`` (faults of real robots and IMUs), ``mle`` (the default
  calibrator's targets), ``core`` (FK and simulation throughput), ``rosbag`` (a bag round trip), ``online``
  (the streaming calibrator), ``adaptive`` (the next-best-motion loop), ``avoid`` and ``qp`` (the avoidance
  controller), ``handheld`` (IMU-only unit-to-unit), ``monitor`` (a unit that moved);
* ``script``: the error handling of the scripts in ``benchmarks/``.
"""
