"""The paper's Table I benchmark: random placement sets x optimiser runs, per-unit errors per method.

Protocol (paper Sec. V-A): ``sets`` random placements (default 4) of one unit per link 2..7 of the Panda
(:func:`skincal.skin.placement.random_placement`), each simulated noise-free with the ``paper-sim``
protocol (:func:`skincal.workflows.session.make_session`, analytic simulator); every method calibrates
each set ``runs`` times (default 10) with different optimiser seeds, the link of each unit given (the
table compares pose estimation, not link discovery). Per unit ``SU1..SU6`` (the unit on link ``k + 1``)
and over all units: mean and standard deviation over the ``sets x runs`` trials of the position error
(mm; the paper prints cm) and of the paper's quaternion distance ``min(|q1 - q2|, |q1 + q2|)``; also the
rotation error in degrees and the wall time of each calibration (all units of a set, one process).

One job is one ``(set, run)`` pair and runs every method (:func:`run_job`): a pure function of a
picklable :class:`Job`, so it runs the same in a local process pool or on a Dask cluster. The
datasets are rebuilt from their seeds in each worker (cached per process).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np

from skincal.bench.harness import RunInfo
from skincal.bench.options import TABLE1
from skincal.errors import ConfigError
from skincal.protocol import ProtocolConfig, get_protocol

_PAPER_POSITION_CM: dict[str, list[tuple[float, float]]] = {
    "om": [
        (0.28, 0.15),
        (0.39, 0.15),
        (0.78, 0.39),
        (1.15, 0.88),
        (0.80, 0.36),
        (0.25, 0.095),
        (0.66, 0.60),
    ],
    "mmm": [(5.3, 7.1), (2.6, 0.23), (5.4, 4.9), (9.5, 9.0), (1.4, 0.91), (2.3, 2.4), (4.4, 5.9)],
}
"""Paper Table I's position error as printed there: (mean, std) in cm for SU1..SU6 and the average."""

PAPER_TABLE_I: dict[str, dict[str, list[tuple[float, float]]]] = {
    "om": {
        "position_mm": [(10.0 * m, 10.0 * s) for m, s in _PAPER_POSITION_CM["om"]],
        "quaternion_distance": [
            (0.010, 0.0058),
            (0.0054, 0.0041),
            (0.0023, 0.0012),
            (0.0019, 0.0013),
            (0.0021, 0.0023),
            (0.0045, 0.0053),
            (0.0044, 0.0059),
        ],
    },
    "mmm": {
        "position_mm": [(10.0 * m, 10.0 * s) for m, s in _PAPER_POSITION_CM["mmm"]],
        "quaternion_distance": [
            (0.55, 0.59),
            (0.016, 0.011),
            (0.36, 0.61),
            (0.0057, 0.0022),
            (0.0044, 0.0015),
            (0.25, 0.43),
            (0.20, 0.44),
        ],
    },
}
"""Paper Table I as (mean, std) for SU1..SU6 and the average (last entry), position in mm (the paper prints
cm). The paper prints the quaternion distance multiplied by 10; these are the actual distances."""

PAPER_RUNTIME_S = {"om": 433.0, "om-joint": 1797.0}
"""Paper Sec. V-A: wall time for 6 units, two-stage vs joint problem (i7-9750H laptop), s."""

QUICK_PROTOCOL = dict(n_poses=3, rate_hz=200.0, excite_duration=1.5, rest_duration=1.0, static_duration=0.5)
"""``--quick``: a short paper-sim protocol (3 poses, 1.5 s per joint)."""
QUICK_OPTIONS = dict(maxeval_static=300, maxeval_dynamic=300, maxeval_joint=600)
"""``--quick``: small optimiser budgets."""


@dataclass(frozen=True)
class Table1Config:
    """What the benchmark runs.

    Attributes:
        sets: number of random placement sets.
        runs: optimiser runs (seeds) per set.
        methods: calibration methods (names in :data:`skincal.calib.METHODS`).
        links: 1-based link of each unit ``su1..`` (one unit per link).
        robot: robot preset.
        protocol: data-collection protocol.
        seed: base seed (set ``s`` draws its placement and poses from ``[seed, s]``, run ``r``
            calibrates with seed ``r``).
        options: optimiser options passed to every method (``calibrate(**options)``).
    """

    sets: int = 4
    runs: int = 10
    methods: tuple[str, ...] = ("om", "mmm", "mm")
    links: tuple[int, ...] = (2, 3, 4, 5, 6, 7)
    robot: str = "panda"
    protocol: ProtocolConfig = field(default_factory=lambda: get_protocol("paper-sim"))
    seed: int = 0
    options: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from skincal.calib import METHODS

        if self.sets < 1 or self.runs < 1:
            raise ConfigError(f"table1: sets and runs must be at least 1, got {self.sets} and {self.runs}")
        if not self.methods:
            raise ConfigError("table1: no method given")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            available = ", ".join(sorted(METHODS))
            raise ConfigError(f"table1: unknown method(s) {', '.join(unknown)} (available: {available})")
        if not self.links:
            raise ConfigError("table1: no unit links given")

    @classmethod
    def quick(cls, methods: tuple[str, ...] = ("om", "mmm", "mm"), **kw: Any) -> Table1Config:
        """The reduced benchmark of ``--quick``: 1 set x 1 run, 2 units, short protocol, small budgets."""
        base = dict(
            sets=1,
            runs=1,
            methods=methods,
            links=(4, 7),
            protocol=replace(get_protocol("paper-sim"), **QUICK_PROTOCOL),
            options=dict(QUICK_OPTIONS),
        )
        return cls(**{**base, **kw})


@dataclass(frozen=True)
class Job:
    """One ``(set, run)`` pair of a :class:`Table1Config`."""

    config: Table1Config
    set_index: int
    run_index: int


def jobs(config: Table1Config) -> list[Job]:
    """All jobs, set-major."""
    return [Job(config, s, r) for s in range(config.sets) for r in range(config.runs)]


@lru_cache(maxsize=4)
def _dataset(robot: str, protocol_key: str, links: tuple[int, ...], seed: int, set_index: int):
    import json

    from skincal.sim import simulate
    from skincal.workflows.session import make_session

    protocol = ProtocolConfig.from_dict(json.loads(protocol_key))
    return simulate(make_session(robot, "random", None, "none", protocol, [seed, set_index], links=links))


def set_dataset(config: Table1Config, set_index: int):
    """The noise-free dataset of placement set ``set_index`` (deterministic; cached per process)."""
    import json

    key = json.dumps(config.protocol.to_dict(), sort_keys=True)
    return _dataset(config.robot, key, tuple(config.links), config.seed, set_index)


def run_job(job: Job) -> dict[str, Any]:
    """Calibrate one set with every method once; errors per unit and wall time per method.

    Returns ``{"set", "run", "methods": {name: {"runtime_s", "units": {unit: {"link",
    "position_mm", "quaternion_distance", "rotation_deg"}}, "failed": {unit: reason}}}}``.
    """
    from skincal.calib import calibrate, evaluate

    ds = set_dataset(job.config, job.set_index)
    out: dict[str, Any] = {"set": job.set_index, "run": job.run_index, "methods": {}}
    for method in job.config.methods:
        start = time.perf_counter()
        result = calibrate(ds, method, seed=job.run_index, use_truth_links=True, **dict(job.config.options))
        runtime = time.perf_counter() - start
        ev = evaluate(result, ds)
        out["methods"][method] = {
            "runtime_s": runtime,
            "units": {
                name: {
                    "link": u.link_true,
                    "position_mm": u.position_error_mm,
                    "quaternion_distance": u.quaternion_distance,
                    "rotation_deg": u.rotation_error_deg,
                }
                for name, u in ev.units.items()
            },
            "failed": dict(result.failed_units),
        }
    return out


def run_local(
    config: Table1Config, workers: int = 1, progress: Callable[[dict[str, Any]], None] | None = None
) -> list[dict[str, Any]]:
    """Run every job in ``workers`` local processes (``1``: in this process); ``progress`` gets each record."""
    from skincal.workflows.sweep import map_local

    return map_local(run_job, jobs(config), workers, progress)


def run_dask(
    config: Table1Config, address: Any, progress: Callable[[dict[str, Any]], None] | None = None
) -> list[dict[str, Any]]:
    """Run every job on an existing ``dask.distributed`` cluster (scheduler address or a ``Client``)."""
    from skincal.workflows.sweep import map_dask

    return map_dask(run_job, jobs(config), address, progress)


def _mean_std(values: Iterable[float]) -> list[float] | None:
    arr = np.asarray(list(values), dtype=float)
    return [float(arr.mean()), float(arr.std())] if arr.size else None


def summarise(config: Table1Config, records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per method: mean and std over trials per unit (``su1..``) and over all units, and wall times.

    ``{"methods": {m: {"units": {u: {"link", "position_mm", "quaternion_distance", "rotation_deg"}},
    "average": {...}, "runtime_s": [mean, std], "failed": n}}}``; each statistic is ``[mean, std]``.
    """
    keys = ("position_mm", "quaternion_distance", "rotation_deg")
    summary: dict[str, Any] = {}
    for method in config.methods:
        per_unit: dict[str, dict[str, list[float]]] = {}
        links: dict[str, int] = {}
        failed = 0
        for rec in records:
            m = rec["methods"][method]
            failed += len(m["failed"])
            for name, u in m["units"].items():
                links[name] = u["link"]
                for k in keys:
                    per_unit.setdefault(name, {}).setdefault(k, []).append(u[k])
        names = sorted(per_unit, key=lambda n: links[n])
        summary[method] = {
            "units": {n: {"link": links[n], **{k: _mean_std(per_unit[n][k]) for k in keys}} for n in names},
            "average": {k: _mean_std(v for n in names for v in per_unit[n][k]) for k in keys},
            "runtime_s": _mean_std(rec["methods"][method]["runtime_s"] for rec in records),
            "failed": failed,
        }
    return {"methods": summary}


def config_dict(config: Table1Config) -> dict[str, Any]:
    """JSON-ready description of the configuration."""
    return {
        "sets": config.sets,
        "runs": config.runs,
        "methods": list(config.methods),
        "links": list(config.links),
        "robot": config.robot,
        "protocol": config.protocol.to_dict(),
        "seed": config.seed,
        "options": dict(config.options),
    }


# --------------------------------------------------------------------------- the benchmark as run and shown
def config_from_options(
    quick: bool = False,
    runs: int | None = None,
    sets: int | None = None,
    methods: str = "om,mmm,mm",
    seed: int = 0,
) -> Table1Config:
    """The configuration of the command's options (``methods`` comma-separated; ``None``: the default)."""
    names = tuple(m.strip() for m in methods.split(",") if m.strip())
    overrides: dict[str, Any] = {"methods": names, "seed": seed}
    if runs is not None:
        overrides["runs"] = runs
    if sets is not None:
        overrides["sets"] = sets
    return Table1Config.quick(**overrides) if quick else Table1Config(**overrides)


def _cell(stat: list[float] | None, scale: float = 1.0, digits: int = 2) -> str:
    if stat is None:
        return "-"
    return f"{stat[0] * scale:.{digits}f} ± {stat[1] * scale:.{digits}f}"


def table1_table(config: Table1Config, summary: dict[str, Any]):
    """A rich table laid out like the paper's Table I, with the paper's rows beside ours."""
    from rich.table import Table

    n_units = len(config.links)
    table = Table(
        title=f"Table I: {config.sets} placement sets x {config.runs} runs, {config.robot}, noise-free "
        f"(quaternion distance x 10 as in the paper)"
    )
    table.add_column("metric")
    table.add_column("method")
    for k in range(n_units):
        table.add_column(f"SU{k + 1} (link {config.links[k]})", justify="right")
    table.add_column("average", justify="right")
    table.add_column("wall time / set (s)", justify="right")
    metrics = (
        ("position_mm", "position (mm)", 1.0, 1),
        ("quaternion_distance", "quat. dist. x10", 10.0, 3),
        ("rotation_deg", "rotation (deg)", 1.0, 2),
    )
    for key, label, scale, digits in metrics:
        for method in config.methods:
            s = summary["methods"][method]
            cells = [_cell(u[key], scale, digits) for u in s["units"].values()]
            cells += ["-"] * (n_units - len(cells))
            runtime = _cell(s["runtime_s"], 1.0, 1)
            table.add_row(label, method, *cells, _cell(s["average"][key], scale, digits), runtime)
            paper = PAPER_TABLE_I.get(method, {}).get(key)
            if paper is not None and n_units == 6:
                ptime = f"{PAPER_RUNTIME_S[method]:.0f}" if method in PAPER_RUNTIME_S else ""
                table.add_row(
                    "", f"{method} (paper)", *[_cell(list(p), scale, digits) for p in paper], ptime, style="dim"
                )
        table.add_section()
    return table


def report(config: Table1Config, doc: dict[str, Any], workers: int = 1, dask: Any = None) -> list[Any]:
    """What the command prints after a run: the table and the summary line."""
    where = f"dask {dask}" if dask else f"{workers} local process(es)"
    line = f"{len(doc['records'])} jobs in {doc['wall_time_s']:.1f} s wall ({where})"
    return [table1_table(config, doc["summary"]), line]




class Table1Harness:
    """The Table I benchmark as a :class:`~skincal.bench.harness.Harness`."""

    options = TABLE1
    jobs = staticmethod(jobs)
    run_job = staticmethod(run_job)

    def config(self, values: Mapping[str, Any]) -> Table1Config:
        """:func:`config_from_options` of the parsed options."""
        v = values
        return config_from_options(v["quick"], v["runs"], v["sets"], v["methods"], v["seed"])

    def summary(self, config: Table1Config, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
        """The ``--json`` document: ``{"config", "summary", "records", "wall_time_s"}``, records by set, run."""
        records = sorted(records, key=lambda r: (r["set"], r["run"]))
        return {"config": config_dict(config), "summary": summarise(config, records), "records": records,
                "wall_time_s": run.wall_time_s}  # fmt: skip

    def report(self, config: Table1Config, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """:func:`report`."""
        return report(config, dict(doc), run.workers, run.dask)


HARNESS = Table1Harness()
