"""Reproduce the paper's Table I: a thin wrapper over ``skincal benchmark table1``.

Usage: ``python benchmarks/table1.py [--quick] [--runs 10] [--sets 4] [--methods om,om-joint,mmm,mm]
[--workers 2] [--dask tcp://host:8786] [--json table1.json]`` (same options as the command).
"""

from __future__ import annotations

import sys

from skincal.cli import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", "table1", *sys.argv[1:]]))
