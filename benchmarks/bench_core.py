"""FK and simulation throughput at 1, 10 and 100 units: ``python benchmarks/bench_core.py``
(same as ``skincal benchmark core``)."""

from skincal.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["benchmark", "core", *__import__("sys").argv[1:]]))
