"""The harness protocol and its options declared once: argparse and typer see the same names and defaults."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from skincal.bench.harness import FORCE, Opt, RunInfo, parse, run_harness, typer_command
from skincal.errors import ConfigError

OPTIONS = (
    Opt("runs", int, 20, "runs", aliases=("--repeats",)),
    Opt("quick", bool, False, "quick"),
    Opt("om", bool, True, "om"),
    Opt("sets", int | None, None, "sets"),
    Opt("json_out", Path | None, None, "json", flag="--json"),
    Opt("storage", str, "mcap", choices=("sqlite3", "mcap")),
    Opt("list_faults", bool, False, "list", flag="--list", switch=False),
)

CASES = [
    ([], {"runs": 20, "quick": False, "om": True, "sets": None, "json_out": None, "storage": "mcap",
          "list_faults": False}),
    (["--runs", "3", "--quick", "--no-om", "--sets", "2", "--json", "x.json", "--storage", "sqlite3", "--list"],
     {"runs": 3, "quick": True, "om": False, "sets": 2, "json_out": Path("x.json"), "storage": "sqlite3",
      "list_faults": True}),
    (["--repeats", "4"], {"runs": 4, "quick": False, "om": True, "sets": None, "json_out": None, "storage": "mcap",
                          "list_faults": False}),  # an older name, still accepted
]  # fmt: skip


def typer_values(argv: list[str]) -> dict[str, Any]:
    app = typer.Typer()
    got: dict[str, Any] = {}

    def body(values: dict[str, Any]) -> None:
        """A test command."""
        got.update(values)

    typer_command(app, "t", OPTIONS, body)

    @app.command("other")
    def other() -> None:  # a second command keeps "t" a subcommand
        pass

    result = CliRunner().invoke(app, ["t", *argv])
    assert result.exit_code == 0, result.output
    return got


@pytest.mark.parametrize("argv, expected", CASES)
def test_argparse_and_typer_read_the_same_options_the_same_way(argv, expected):
    assert parse("test", OPTIONS, argv) == expected
    assert typer_values(argv) == expected


def test_a_count_of_placements_is_called_placements_in_every_benchmark():
    """``--runs`` (mle) and ``--seeds`` (robustness) both counted random placements, while ``--seeds`` elsewhere
    lists seeds: both are ``--placements`` now, the old names kept as aliases; robustness's ``--out`` takes
    ``--json`` as every other benchmark does."""
    from skincal.bench import options

    for group, old in ((options.MLE, "--runs"), (options.ROBUSTNESS, "--seeds")):
        (o,) = [o for o in group if o.name == "placements"]
        assert o.cli_flag == "--placements" and o.aliases == (old,)
        for argv in ([old, "3"], ["--placements", "3"]):
            assert parse("t", group, argv)["placements"] == 3
    assert parse("t", options.ROBUSTNESS, ["--json", "x.json"])["out"] == Path("x.json")


def test_every_benchmark_that_lists_seeds_takes_them_the_same_way():
    """``--seeds 0 1`` in every benchmark (``bench_avoid.py`` took ``--seeds 0,1`` alone); a comma list is a
    usage error there, not a silently different run."""
    from skincal.bench import options

    groups = [g for n in dir(options) if n.isupper() and isinstance(g := getattr(options, n), tuple)]
    listing = [g for g in groups if any(getattr(o, "name", None) == "seeds" for o in g)]
    assert options.AVOID in listing and len(listing) >= 4
    for group in listing:
        assert parse("t", group, ["--seeds", "3", "1"])["seeds"] == [3, 1]
        with pytest.raises(SystemExit):
            parse("t", group, ["--seeds", "0,1"])


@pytest.mark.parametrize("argv", [["robustness", "--placements", "0"], ["robustness", "--seeds", "-2"],
                                  ["mle", "--placements", "-1"], ["mle", "--runs", "0"]])  # fmt: skip
def test_a_count_of_no_placements_is_refused_by_its_name(argv, capsys):
    from skincal.cli import main

    assert main(["benchmark", *argv, "--quick"]) == 2
    err = capsys.readouterr().err
    assert "--placements must be at least 1" in err and len(err.strip().splitlines()) == 1


def test_argparse_refuses_a_value_outside_the_choices():
    with pytest.raises(SystemExit):
        parse("test", OPTIONS, ["--storage", "zip"])


@pytest.mark.parametrize(
    "module", ["table1", "robustness", "mle", "core", "qp", "online", "adaptive", "rosbag", "avoid", "handheld",
               "monitor", "speed"],
)  # fmt: skip
def test_every_benchmark_declares_its_options_once_with_unique_flags(module):
    options = getattr(importlib.import_module("skincal.bench.options"), module.upper())
    flags = [f for o in options for f in (o.cli_flag, *o.aliases)]
    assert len(set(flags)) == len(flags) and len({o.name for o in options}) == len(options)
    defaults = parse("test", options, [])
    assert defaults == {o.name: o.default for o in options}


@dataclasses.dataclass(frozen=True)
class SquaresConfig:
    n: int


def square(job: int) -> dict[str, int]:
    return {"job": job, "square": job * job}


class Squares:
    """A toy harness: jobs 0..n-1, each squared, summed."""

    options = (Opt("n", int, 3), FORCE)
    run_job = staticmethod(square)

    def config(self, values):
        if values["n"] < 1:
            raise ConfigError("n must be at least 1")
        return SquaresConfig(values["n"])

    def jobs(self, config):
        return list(range(config.n))

    def summary(self, config, records, run: RunInfo):
        return {"records": records, "sum": sum(r["square"] for r in records), "workers": run.workers}

    def report(self, config, doc, run):
        return [f"sum {doc['sum']}"]


def test_run_harness_maps_jobs_in_order_and_summarises():
    harness = Squares()
    config = harness.config(parse("test", harness.options, ["--n", "4"]))
    seen = []
    doc, run = run_harness(harness, config, progress=seen.append)
    assert [r["job"] for r in doc["records"]] == [0, 1, 2, 3] and doc["sum"] == 14
    assert len(seen) == 4 and run.workers == 1 and run.dask is None and run.wall_time_s >= 0
    assert harness.report(config, doc, run) == ["sum 14"]


def test_run_harness_refuses_no_workers():
    harness = Squares()
    with pytest.raises(ConfigError, match="--workers must be at least 1"):
        run_harness(harness, SquaresConfig(1), workers=0)


@pytest.mark.parametrize(
    ("module", "n_jobs"), [("table1", 40), ("robustness", None), ("rosbag", 3), ("adaptive", 3), ("speed", 4)]
)
def test_harness_benchmarks_build_picklable_jobs_from_their_default_options(module, n_jobs):
    import pickle

    harness = importlib.import_module(f"skincal.bench.{module}").HARNESS
    config = harness.config(parse("test", harness.options, []))
    jobs = harness.jobs(config)
    assert jobs and (n_jobs is None or len(jobs) == n_jobs)
    assert pickle.loads(pickle.dumps(harness.run_job)) is harness.run_job  # a module-level function
    pickle.dumps(jobs)  # a local pool or a Dask worker receives them
