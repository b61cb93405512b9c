"""The calibrator under faults of real robots and IMUs: a thin wrapper over ``skincal benchmark robustness``.

Usage: ``python benchmarks/robustness.py [--quick] [--robots panda,sawyer,ur5e] [--backends analytic,mujoco]
[--faults knock,gravity] [--seeds 5] [--workers 2] [--dask tcp://host:8786] [--out robustness.json]``
(same options as the command; ``--list`` lists the faults).
"""

from __future__ import annotations

import sys

from skincal.cli import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", "robustness", *sys.argv[1:]]))
