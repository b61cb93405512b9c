"""The robustness benchmark (``skincal benchmark robustness``): the default calibrator under faults of
real robots and real IMUs, one at a time and all together.

**Session.** Per robot (``panda``, ``sawyer``, ``ur5e``) and seed: 6 units at random places on links
2..n (:func:`skincal.skin.placement.random_placement`), the protocol (``paper-sim``; ``--quick``:
``fast``) with amplitudes capped at 95 % of the velocity limits, simulated by a backend
(``analytic``, ``mujoco`` = MuJoCo kinematic mode, ``mujoco-dynamic`` = MuJoCo with velocity servos).
The base session of every fault has ``realistic`` IMUs, ``controller`` joint states (500 Hz,
encoder steps, no qdd) with 3e-3 rad/s velocity noise, ideal unit clocks and ``|g| = 9.81``.

**Faults** (:data:`FAULTS`; the stream faults are :mod:`skincal.sim.faults`): joint-velocity noise
1e-3 / 3e-3 (the base session itself) / 1e-2 rad/s; the ``real`` IMU preset; unit clocks ``wifi``
(offsets up to 0.5 s, 100 ppm std free-running drift, 1 ms jitter), a fixed 0.4 s offset, a
100 ppm free-running drift, ``driver`` (440 ppm slow clock re-synced every 2.51 s: stamp steps);
saturation (a +-2 g accelerometer with brisk motion: the protocol's frequencies x 1.5);
an accelerometer axis stuck from mid-session; a 0.05 m/s^2 bias drift over the session; a unit
knocked 3 cm / 10 deg at 2/3 of the session; gravity 9.796 m/s^2 simulated while the dataset says
9.81; and ``all`` of them at once (velocity noise 1e-2, ``real`` IMUs, ``wifi-resync`` clocks,
brisk +-2 g, stuck axis, bias drift, knock, gravity). Placements, trajectories and sensor draws are
the same for every fault of a ``(robot, seed)`` (paired comparison); the unit with the stuck axis
and the knocked unit are two different units drawn from the seed.

The faults of real recordings (issue 24): ``report14`` joint states, ``host`` and ``host-gaps``
unit clocks (the clock cells' 1 mm target), gyroscope scale and misalignment, the three unit
mistakes of :func:`skincal.sim.faults.misstate_units` and ``real-recording`` (``real-consumer`` IMUs
with ``report14`` joints and ``host-gaps`` clocks); those but the clock cells have no mean target yet.

**Truth.** Each unit's simulated pose; for the knocked unit the pose before the knock, held for
2/3 of the session (:func:`skincal.sim.faults.splice_knock`).

**Per cell** ``(robot, backend, fault)``, over its seeds' units (:func:`summarise_cell`): mean and
max position error (mm) and rotation error (deg) of the calibrated units (as
:func:`skincal.calib.evaluate`), links right, RMS of ``z = e_i / sigma_i`` (position error per
link axis over the reported std), units calibrated, units with any warning, and silent errors
(:data:`SILENT_RULE`). Targets (:func:`targets`): mean <= 0.3 mm for the joint-noise cells
(``controller`` joints, ``realistic`` IMUs), <= 1 mm for the ``real`` IMU and clock cells; in
every cell all links right and no silent error.

One job is one ``(robot, backend, fault, seed)`` (:func:`run_job`): a pure function of a picklable
:class:`Job`, run in local processes or on Dask by :mod:`skincal.workflows.sweep`.

The faults are :mod:`~skincal.bench.robustness.faults`, a job :mod:`~skincal.bench.robustness.job`, the cells'
summary and table :mod:`~skincal.bench.robustness.summary`; this module runs them as a harness.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict
from typing import Any

from skincal.bench.harness import RunInfo
from skincal.bench.options import ROBUSTNESS
from skincal.bench.robustness.faults import BASE_VELOCITY_NOISE, FAULTS, KNOCK_AT
from skincal.bench.robustness.job import (
    SILENT_RULE,
    Job,
    RobustnessConfig,
    build_dataset,
    jobs,
    judge_unit,
    run_job,
    silent_chi2,
)
from skincal.bench.robustness.summary import report, summarise, where

__all__ = [
    "FAULTS",
    "Job",
    "RobustnessConfig",
    "build_dataset",
    "jobs",
    "judge_unit",
    "run_job",
    "silent_chi2",
    "where",
    "RobustnessHarness",
    "config_dict",
    "config_from_options",
    "fault_lines",
    "names",
    "run",
]


def run(
    config: RobustnessConfig,
    workers: int = 1,
    dask: Any = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every job's record (in :func:`jobs` order), in local processes or on a Dask cluster."""
    from skincal.workflows.sweep import map_jobs

    return map_jobs(run_job, jobs(config), workers=workers, dask=dask, progress=progress)


def config_dict(config: RobustnessConfig) -> dict[str, Any]:
    """JSON-ready description of the configuration, the faults and the definitions."""
    return {
        **asdict(config),
        "faults_run": {name: asdict(FAULTS[name]) for name in config.faults},
        "base_session": "realistic IMUs, controller joint states (500 Hz, encoder steps, no qdd) with "
        f"{BASE_VELOCITY_NOISE} rad/s velocity noise, ideal unit clocks, |g| = 9.81",
        "truth": "each unit's simulated pose; for the knocked unit the pose before the knock "
        f"(held for {KNOCK_AT:.0%} of the session)",
        "silent_error": SILENT_RULE,
        "z": "e_i / sigma_i: position error on link axis i over the reported std (link right, finite std)",
        "warned": "calibrated units with at least one warning",
        "beyond_3sigma": "calibrated units wrong beyond their reported uncertainty by the silent-error rule, "
        "warned or not",
    }


# --------------------------------------------------------------------------- the benchmark as run and shown
def names(text: str | None) -> tuple[str, ...] | None:
    """``"a, b"`` -> ``("a", "b")``; ``None`` stays ``None`` (the default)."""
    if text is None:
        return None
    return tuple(x.strip() for x in text.split(",") if x.strip())


def config_from_options(
    robots: str | None = None,
    backends: str | None = None,
    faults: str | None = None,
    seeds: int | None = None,
    quick: bool = False,
    protocol: str | None = None,
    seed: int = 0,
) -> RobustnessConfig:
    """The configuration of the command's options (comma-separated lists; ``None``: the default)."""
    overrides: dict[str, Any] = {"seed": seed}
    for key, value in (("robots", names(robots)), ("backends", names(backends)), ("faults", names(faults))):
        if value is not None:
            overrides[key] = value
    if seeds is not None:
        overrides["seeds"] = seeds
    if protocol is not None:
        overrides["protocol"] = protocol
    return RobustnessConfig.quick(**overrides) if quick else RobustnessConfig(**overrides)


def fault_lines() -> list[str]:
    """One line per fault: name, description and target (``--list``)."""
    out = []
    for f in FAULTS.values():
        target = f"mean <= {f.target_mean_mm:g} mm" if f.target_mean_mm is not None else "no mean target"
        out.append(f"{f.name:14s} {f.description} ({target})")
    return out


class RobustnessHarness:
    """The robustness benchmark as a :class:`~skincal.bench.harness.Harness`."""

    options = ROBUSTNESS
    jobs = staticmethod(jobs)
    run_job = staticmethod(run_job)

    def config(self, values: Mapping[str, Any]) -> RobustnessConfig:
        """:func:`config_from_options` of the parsed options."""
        v = values
        return config_from_options(v["robots"], v["backends"], v["faults"], v["placements"], v["quick"], v["protocol"],
                                   v["seed"])  # fmt: skip

    def summary(self, config: RobustnessConfig, records: list[dict[str, Any]], run: RunInfo) -> dict[str, Any]:
        """The ``--out`` document: ``{"config", "cells", "records", "wall_time_s", "workers", "dask"}``."""
        return {
            "config": config_dict(config),
            "cells": summarise(config, records),
            "records": records,
            "wall_time_s": run.wall_time_s,
            "workers": None if run.dask else run.workers,
            "dask": run.dask,
        }

    def report(self, config: RobustnessConfig, doc: Mapping[str, Any], run: RunInfo) -> list[Any]:
        """:func:`report`."""
        return report(config, doc)


HARNESS = RobustnessHarness()
