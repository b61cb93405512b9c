"""Calibrate many datasets at once (a fleet of robots, a day of recordings), on the sweep runner.

Each dataset is one job (:func:`calibrate_file`): read it, calibrate every unit with one worker,
write its result file atomically, return a summary record. The jobs run in local processes or on an
existing Dask cluster (:func:`skincal.workflows.sweep.map_jobs`); one dataset that cannot be read or
calibrated is reported in its record (``error``) and never stops the others.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skincal.errors import ConfigError, SkincalError


@dataclass(frozen=True)
class FleetJob:
    """One dataset to calibrate into ``out`` (see :func:`skincal.calib.calibrate` for the rest)."""

    dataset: Path
    out: Path
    method: str = "mle"
    seed: int = 0
    links: Mapping[str, int] | None = None
    use_truth_links: bool = False
    use_dataset_qdd: bool = False
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class FleetRecord:
    """What became of one dataset: ``error`` is one line when nothing was written."""

    dataset: str
    out: str
    units: int = 0
    failed: int = 0
    runtime_s: float = 0.0
    error: str | None = None


def calibrate_file(job: FleetJob) -> FleetRecord:
    """Calibrate one dataset file into its result file (module docstring)."""
    from skincal.calib import calibrate
    from skincal.data.hdf5 import read_dataset
    from skincal.data.result import sha256_file, write_result

    try:
        ds = read_dataset(job.dataset)
        result = calibrate(
            ds, job.method, seed=job.seed, links=job.links, use_truth_links=job.use_truth_links,
            use_dataset_qdd=job.use_dataset_qdd, dataset_sha256=sha256_file(job.dataset), workers=1,
            **dict(job.options),
        )  # fmt: skip
        write_result(result, job.out)
    except SkincalError as exc:
        return FleetRecord(str(job.dataset), str(job.out), error=str(exc))
    failed = len([u for u in result.failed_units if u not in result.units])
    return FleetRecord(str(job.dataset), str(job.out), len(result.units), failed, result.runtime_s)


def fleet_jobs(datasets: Sequence[Path], out_dir: Path, **settings: Any) -> list[FleetJob]:
    """One job per dataset, its result ``out_dir/<dataset stem>.json``; two datasets with one stem
    would write one file: refused."""
    if not out_dir.is_dir():
        raise ConfigError(f"{out_dir}: with several datasets, --out is a folder that exists")
    stems: dict[str, Path] = {}
    for path in datasets:
        other = stems.setdefault(path.stem, path)
        if other == path and datasets.count(path) > 1:
            raise ConfigError(f"{path} is given twice")
        if other != path:
            raise ConfigError(f"{other} and {path} would both write {out_dir / (path.stem + '.json')}")
    return [FleetJob(Path(p), out_dir / f"{Path(p).stem}.json", **settings) for p in datasets]


def calibrate_fleet(
    jobs: Sequence[FleetJob],
    *,
    workers: int = 1,
    dask: Any = None,
    progress: Callable[[FleetRecord], None] | None = None,
) -> list[FleetRecord]:
    """Run the jobs ``workers`` at a time (or on a Dask cluster); records in the order of ``jobs``."""
    from skincal.workflows.sweep import map_jobs

    return map_jobs(calibrate_file, list(jobs), workers=workers, dask=dask, progress=progress)
