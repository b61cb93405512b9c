"""The default calibrator's targets: ``python benchmarks/bench_mle.py [--runs 20] [--json out.json]``
(same as ``skincal benchmark mle``)."""

from skincal.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["benchmark", "mle", *__import__("sys").argv[1:]]))
