"""One door to every calibration method: ``calibrate(dataset, method=...)``.

A method is a per-unit function registered in :data:`METHODS` with the signature of
:class:`UnitMethod`; adding a method touches one new module and one line in ``calib/__init__``.
The link each unit sits on comes from ``links`` (user-given), from the dataset truth when
``use_truth_links`` is set, and otherwise from the data (:func:`skincal.calib.links.discover_link`,
or the method's own discovery when it has one).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Generator, Iterator, Mapping
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from skincal.calib.links import LinkAssignment, discover_link
from skincal.calib.options import NoOptions, parse_options
from skincal.calib.position import judge_position, weak_position
from skincal.calib.preprocess import (
    DEFAULT_QDD_WINDOW_S,
    JointInterpolator,
    UnitSamples,
    joint_noise,
    screen_readings,
    unit_samples,
)
from skincal.data.dataset import NO_JOINTS_MESSAGE, STATIC, Dataset
from skincal.data.result import CalibrationResult, UnitResult
from skincal.errors import CalibrationError, ConfigError, DatasetError, SkincalError
from skincal.kinematics.chain import SerialChain
from skincal.parallel import can_fork, imap, one_blas_thread


@dataclass(frozen=True)
class UnitProblem:
    """Everything a method needs to calibrate one unit.

    Attributes:
        chain: the robot.
        gravity: ``(3,)`` gravity in the base frame, m/s^2.
        samples: the unit's tagged samples (joint states interpolated to its IMU instants).
        link: 1-based link the unit is on (given or discovered).
        link_assignment: the discovery result, or ``None`` when the link was given.
        rng: this unit's random generator (seeded from the run's seed and the unit's index).
        interpolator: the dataset's joint interpolator (to re-evaluate joint states at shifted
            instants, e.g. when estimating a time offset).
        shared: what the method's ``prepare`` computed once for the whole dataset, or ``None``.
        options: the method's options (an instance of its ``MethodSpec.options`` dataclass).
        time_offset_s: the coarse IMU time offset already removed from ``samples.t`` (methods
            with an ``align`` step), s.
        alignment: that step's outcome (method-specific), or ``None``.
        diagnostics: ``False`` when the caller keeps only the pose, its std and the link (the
            consistency check's parts): a method may then skip what only adds warnings and extras.
    """

    chain: SerialChain
    gravity: np.ndarray
    samples: UnitSamples
    link: int
    link_assignment: LinkAssignment | None
    rng: np.random.Generator
    interpolator: JointInterpolator | None = None
    shared: Any = None
    options: Any = field(default_factory=NoOptions)
    time_offset_s: float = 0.0
    alignment: Any = None
    diagnostics: bool = True


class UnitMethod(Protocol):
    def __call__(self, problem: UnitProblem) -> UnitResult: ...


@dataclass(frozen=True)
class MethodSpec:
    """A registered method: its per-unit function, a one-line description, whether it uses the
    gyroscope for link discovery and takes care of link discovery itself, and an optional
    ``prepare(dataset, interpolator)`` run once per dataset whose result reaches every unit as
    ``UnitProblem.shared``; ``exact_joint_states=False`` when the method only needs the joint
    states of the samples to find rest periods (see :func:`unit_samples`); ``align(shared, imu)``, when
    given, returns the unit's coarse time alignment (an object with ``offset_s`` and, when its
    stamps had to be corrected, ``stamps``) applied before the samples are gathered;
    ``needs_segments=False`` when the method finds rests itself (a
    dataset without ``/segments`` is then segmented automatically only to tag samples, and a
    failure to do so is not fatal)."""

    run_unit: UnitMethod
    description: str
    discovers_links: bool = False
    use_gyro_for_links: bool = False
    prepare: Callable[[Dataset, JointInterpolator], Any] | None = None
    exact_joint_states: bool = True
    align: Callable[[Any, Any], Any] | None = None
    needs_segments: bool = True
    options: type = NoOptions
    """The method's options: a frozen dataclass parsed by :func:`~skincal.calib.options.parse_options`
    from ``calibrate(..., **options)`` (unknown names and mistyped values are refused there, for
    every method alike); the instance reaches the method as ``UnitProblem.options``."""


METHODS: dict[str, MethodSpec] = {}


def register(name: str, spec: MethodSpec) -> None:
    """Add a method to :data:`METHODS` (called once by each method module)."""
    METHODS[name] = spec


def _resolve_links(
    dataset: Dataset, links: Mapping[str, int] | None, use_truth_links: bool
) -> dict[str, int]:
    if links is not None and use_truth_links:
        raise ConfigError("give either links or use_truth_links, not both")
    if use_truth_links:
        missing = [u for u in dataset.units if u not in dataset.truth]
        if missing:
            raise ConfigError(f"use_truth_links: dataset has no truth for unit(s) {', '.join(missing)}")
        return {u: dataset.truth[u].link for u in dataset.units}
    if links is None:
        return {}
    unknown = [u for u in links if u not in dataset.imu]
    if unknown:
        raise ConfigError(f"links given for unknown unit(s) {', '.join(unknown)}")
    for link in links.values():
        dataset.chain.check_link(link)
    return dict(links)


class UnitDataError(CalibrationError):
    """A unit's data cannot be used at all (no samples; stamps on another clock than the joints'): that
    unit fails alone, but when every unit fails so, the run is a data error (raised: exit 2, nothing
    written) rather than a calibration that found nothing."""


_Outcome = tuple[str, UnitResult | None, CalibrationError | None]
"""A unit's outcome in :func:`calibrate`: name, result or None, and its failure (a
:class:`UnitDataError` when its data could not be used at all)."""


@one_blas_thread
def calibrate(
    dataset: Dataset,
    method: str = "mle",
    *,
    seed: int = 0,
    links: Mapping[str, int] | None = None,
    use_truth_links: bool = False,
    use_dataset_qdd: bool = False,
    qdd_window_s: float | None = None,
    units: list[str] | None = None,
    dataset_sha256: str = "",
    progress: Callable[[str], None] | None = None,
    workers: int = 1,
    work: Callable[[int, int, str], None] | None = None,
    **options: Any,
) -> CalibrationResult:
    """Calibrate the units of ``dataset`` with ``method``; units that fail are reported in
    ``result.failed_units`` (name -> reason) while the others are calibrated. When every
    unit fails the result is still returned (``units`` empty, every unit in ``failed_units``): a
    calibration that ran and could determine nothing is an answer, not an error (usage and data
    errors that concern every unit still raise, and so does a run in which every unit's data was
    unusable: :class:`UnitDataError`).

    A foreign exception raised in the method (its ``prepare``, ``align`` or ``run_unit``: a bug, not
    bad input) is a :class:`CalibrationError` naming its type, with the exception as its cause
    (:func:`method_errors`): in one unit, that unit's failure; in ``prepare`` or in every unit, raised.

    Args:
        dataset: a validated dataset with segments.
        method: a name in :data:`METHODS`.
        seed: seed of the run; unit ``k`` gets ``np.random.default_rng([seed, k])``.
        links: user-given 1-based link per unit (others are discovered).
        use_truth_links: take links from the dataset truth (simulation).
        use_dataset_qdd: use the dataset's ``/joints/qdd`` instead of estimating it.
        qdd_window_s: Savitzky-Golay window of the qdd estimate (default
            :data:`~skincal.calib.preprocess.DEFAULT_QDD_WINDOW_S`).
        units: calibrate only these units (default: all).
        dataset_sha256: recorded in the result.
        progress: called with each unit's name when it is done.
        work: called with ``(steps done, steps planned, stage)`` as the run advances (:class:`WorkSteps`:
            the dataset's preparation, each unit, each unit of every part of the split check and of every
            fit of the report-spacing check), for a progress bar that moves with the work.
        workers: units calibrated at once. Where the platform can ``fork`` (Linux) these are
            forked processes that inherit the prepared joint interpolation and shared tables (no
            copy, no pickling of the dataset; only the unit results come back); elsewhere threads.
            Results do not depend on it.
        options: method-specific options.
    """
    if dataset.joints is None:
        raise DatasetError(f"{NO_JOINTS_MESSAGE}: calibrate it unit-to-unit with --reference UNIT")
    if method not in METHODS:
        raise ConfigError(f"unknown method '{method}' (available: {', '.join(sorted(METHODS))})")
    spec = METHODS[method]
    parsed = parse_options(spec.options, options, method)
    given = _resolve_links(dataset, links, use_truth_links)
    names = dataset.units if units is None else list(units)
    for u in names:
        if u not in dataset.imu:
            raise ConfigError(f"unknown unit '{u}' (dataset has: {', '.join(dataset.units)})")
    check_joint_range(dataset)
    start = time.perf_counter()
    steps = WorkSteps.plan(work, len(names), parsed, dataset)
    tagged, notes = dataset, []
    if dataset.segments is None or len(dataset.segments) == 0:
        tagged, notes = segment_automatically(dataset, spec)
    interpolator = JointInterpolator(
        dataset.joints, use_dataset_qdd=use_dataset_qdd, qdd_window_s=qdd_window_s or DEFAULT_QDD_WINDOW_S
    )
    shared = None
    if spec.prepare is not None:
        with method_errors(f"method '{method}', preparing the dataset: "):
            shared = spec.prepare(dataset, interpolator)
    steps.advance("calibrating the units")
    results: dict[str, UnitResult] = {}
    failed: dict[str, str] = {}
    errors: list[CalibrationError] = []

    alignments: dict[str, Any] = {}  # each unit's clock alignment on its whole stream (in this process), for its parts

    def one(k: int, name: str) -> _Outcome:
        try:  # a usage or data error (another SkincalError) concerns every unit: it propagates
            unit = calibrate_unit(
                tagged, name, spec, link=given.get(name), rng=np.random.default_rng([seed, k]),
                interpolator=interpolator, shared=shared, options=parsed, record=alignments,
            )
            return name, unit, None
        except CalibrationError as exc:  # a foreign error in one unit too: it never stops the others
            return name, None, exc

    n_workers = max(1, min(int(workers), len(names), os.cpu_count() or 1))  # more would only oversubscribe
    pool: Executor | None = None
    forked: Generator[tuple[int, _Outcome], None, None] | None = None
    if n_workers == 1:  # one BLAS thread (the decorator), as in the worker processes: results are identical
        outcomes: Iterator[_Outcome] = (one(k, name) for k, name in enumerate(names))
    elif can_fork():
        interpolator.warm()  # computed once here, inherited by every child
        warm = getattr(shared, "warm", None)
        if warm is not None:
            warm()
        forked = imap(lambda pair: one(*pair), enumerate(names), n_workers, fork=True, one_blas_thread=True)
        outcomes = (outcome for _, outcome in forked)
    else:  # NumPy releases the GIL in much of the array work
        pool = ThreadPoolExecutor(max_workers=n_workers)
        outcomes = pool.map(one, range(len(names)), names)
    unusable = 0  # units whose data could not be used at all (UnitDataError)
    try:
        for name, unit, error in outcomes:
            if unit is not None:
                results[name] = unit
            else:
                failed[name] = str(error)
                errors.append(error)
                unusable += int(isinstance(error, UnitDataError))
            if progress is not None:
                progress(name)
            steps.advance("calibrating the units")
    finally:
        if pool is not None:
            pool.shutdown()
        if forked is not None:
            forked.close()  # the worker processes end with the run
    results = {name: results[name] for name in names if name in results}
    failed = {name: failed[name] for name in names if name in failed}
    internal = bool(errors) and all(str(e).startswith("internal error (") for e in errors)  # a bug, every unit
    if not results and (unusable == len(names) or internal):  # the data or the method, not the calibration
        reasons = "; ".join(f"{u}: {m}" for u, m in failed.items())
        raise CalibrationError(f"no unit could be calibrated ({reasons})") from (errors[0] if errors else None)
    # every unit failed otherwise: still a result (each unit listed with its reason, observable: false)
    result = CalibrationResult(
        method=method,
        robot=dataset.chain.name,
        dataset_sha256=dataset_sha256,
        runtime_s=time.perf_counter() - start,
        units=results,
        extras={"seed": seed},
        failed_units=failed,
        notes=tuple(notes),
    )
    if getattr(parsed, "consistency", False):  # the split check (skincal.calib.consistency)
        from skincal.calib.consistency import check

        part_options = dataclasses.replace(parsed, consistency=False)

        def refit(part: Dataset, part_links: dict[str, int]) -> CalibrationResult:
            """The method on a part of the recording: the same joint conditioning and shared tables (they do
            not depend on the IMU samples) and each unit's clock alignment on its whole stream (found in the
            full run when it ran in this process, else here), the units on their links; only their poses,
            std and links are kept (no diagnostics)."""
            units: dict[str, UnitResult] = {}
            part_failed: dict[str, str] = {}
            for k, name in enumerate(part_links):
                if spec.align is not None and name not in alignments:  # the whole stream's, found once
                    alignments[name] = spec.align(shared, tagged.imu[name])
                try:
                    units[name] = calibrate_unit(
                        part, name, spec, link=part_links[name], rng=np.random.default_rng([seed, k]),
                        interpolator=interpolator, shared=shared, options=part_options,
                        alignment=alignments.get(name), diagnostics=False,
                    )  # fmt: skip
                except CalibrationError as exc:
                    part_failed[name] = str(exc)
            return CalibrationResult(method, dataset.chain.name, "", 0.0, units, failed_units=part_failed)

        if spec.align is not None and n_workers > 1:  # found here once, before the parts' processes fork
            for name in result.units:
                if name not in alignments:
                    alignments[name] = spec.align(shared, tagged.imu[name])

        stage = "checking independent parts of the recording"
        result = check(tagged, result, refit, workers=n_workers, done=lambda: steps.advance(stage))
        steps.reach(steps.consistency_end, stage)
    if getattr(parsed, "joint_rate", False):  # the report-spacing check (skincal.calib.joint_rate)
        from skincal.calib.joint_rate import check as joint_rate_check

        thinned_options = dataclasses.asdict(dataclasses.replace(parsed, consistency=False, joint_rate=False))

        def refit_thinned(thinned: Dataset, thinned_links: dict[str, int]) -> CalibrationResult:
            """The method from scratch on a dataset whose joint stream is thinned (its conditioning and
            tables are its own), the units on their links, without the checks."""
            return calibrate(
                thinned, method, seed=seed, links=thinned_links, use_dataset_qdd=use_dataset_qdd,
                qdd_window_s=qdd_window_s, units=list(thinned_links),
                progress=lambda _name: steps.advance("checking the joint stream's report spacing"), **thinned_options,
            )  # fmt: skip

        result = joint_rate_check(tagged, result, refit_thinned)
    steps.reach(steps.total, "done")
    # on the final std (after every inflation above); the run's time with its checks
    judged = {name: weak_position(u) for name, u in result.units.items()}
    return replace(result, units=judged, runtime_s=time.perf_counter() - start)


@dataclass
class WorkSteps:
    """The steps of one :func:`calibrate` run for a progress bar, planned at its start: 1 for the dataset's
    preparation (segments, joint conditioning, the method's shared tables), 1 per unit, ``len(SPLITS) * 2``
    parts x the units of the split check (when on), and :data:`JOINT_RATE_FITS` fits x the units of the
    report-spacing check (when on and the joint stream is low-rate). A check that runs fewer (units that
    failed, a short stream) jumps to its end; ``callback(done, total, stage)`` is called at every step."""

    callback: Callable[[int, int, str], None] | None
    total: int
    consistency_end: int
    done: int = 0

    @classmethod
    def plan(cls, callback: Callable[[int, int, str], None] | None, n_units: int, parsed: Any,
             dataset: Dataset) -> WorkSteps:  # fmt: skip
        units_end = 1 + n_units
        consistency_end = units_end
        if getattr(parsed, "consistency", False):
            from skincal.calib.consistency import SPLITS

            consistency_end += 2 * len(SPLITS) * n_units
        total = consistency_end
        if getattr(parsed, "joint_rate", False) and dataset.joints is not None:
            from skincal.calib.preprocess import is_low_rate

            if is_low_rate(dataset.joints.t):
                total += JOINT_RATE_FITS * n_units
        steps = cls(callback, total, consistency_end)
        steps.reach(0, "preparing the dataset")
        return steps

    def advance(self, stage: str) -> None:
        self.reach(min(self.done + 1, self.total), stage)

    def reach(self, done: int, stage: str) -> None:
        self.done = max(self.done, done)
        if self.callback is not None:
            self.callback(self.done, self.total, stage)


JOINT_RATE_FITS = 5
"""Fits of the report-spacing check (``skincal.calib.joint_rate``: every second report, 2 phases; every
third, 3), for :class:`WorkSteps`."""


@contextmanager
def method_errors(context: str = "") -> Iterator[None]:
    """Run a calibration method's code: skincal's own errors pass; a foreign exception (a bug in the
    method, or a library failing inside it) becomes a :class:`CalibrationError` ``"<context>internal
    error (<type>: <message>)"`` raised from it (``__cause__``), so callers see one error family and
    the traceback is kept."""
    try:
        yield
    except SkincalError:
        raise
    except Exception as exc:
        raise CalibrationError(f"{context}internal error ({type(exc).__name__}: {exc})") from exc


JOINT_LIMIT_MARGIN_RAD = 0.25
"""How far a joint position may lie beyond the robot's stated limits before :func:`check_joint_range`
refuses the dataset, rad (encoder offsets and a controller's overshoot stay well inside it)."""
JOINT_ABS_MAX_RAD = 1000.0
"""Largest joint position accepted for a joint without stated limits, rad (160 turns)."""


def check_joint_range(dataset: Dataset, margin_rad: float = JOINT_LIMIT_MARGIN_RAD) -> None:
    """Refuse joint positions beyond the robot's limits by more than ``margin_rad`` (beyond
    +-:data:`JOINT_ABS_MAX_RAD` for a joint without limits) with a one-line :class:`DatasetError`
    naming the joint, the sample and its time: a glitch such as ``1e30`` would otherwise be
    differentiated into huge velocities and accelerations and silently skew every unit."""
    from skincal.errors import DatasetError

    chain = dataset.chain
    q = np.asarray(dataset.joint_states.q, dtype=float)
    n = q.shape[1]
    lower = np.full(n, -JOINT_ABS_MAX_RAD) if chain.joint_lower is None else chain.joint_lower - margin_rad
    upper = np.full(n, JOINT_ABS_MAX_RAD) if chain.joint_upper is None else chain.joint_upper + margin_rad
    bad = (q < lower) | (q > upper)
    if not bad.any():
        return
    i, j = (int(x) for x in np.argwhere(bad)[0])
    if chain.joint_lower is None or chain.joint_upper is None:
        beyond = f"+-{JOINT_ABS_MAX_RAD:g} rad"
    else:
        limits = f"{chain.joint_lower[j]:.4g}..{chain.joint_upper[j]:.4g}"
        beyond = f"the robot's limits {limits} rad by more than {margin_rad:g} rad"
    raise DatasetError(
        f"/joints/q: joint {j + 1} at sample {i} (t = {dataset.joint_states.t[i]:.3f} s) is {q[i, j]:.6g} rad, beyond "
        f"{beyond} ({int(bad.sum())} such value(s)): a glitch in the joint stream, or limits of another robot"
    )


MIN_OVERLAP_S = 2.0
"""Least time a unit's stamps must share with the joint stream, s: less cannot hold a rest and a move,
and a coarse clock alignment (up to 0.5 s) could shift the rest off the joint stream."""


def _check_overlap(dataset: Dataset, unit: str, min_overlap_s: float = MIN_OVERLAP_S) -> None:
    """A unit's stamps must overlap the joint stream for at least ``min_overlap_s`` (and 10 samples):
    stamps on another clock (Unix time, a device's boot time) would otherwise fail deep inside a method."""
    t = np.asarray(dataset.imu[unit].t, dtype=float)
    tj = np.asarray(dataset.joint_states.t, dtype=float)
    if t.size == 0:
        raise UnitDataError(f"unit '{unit}': no IMU samples")
    inside = t[(t >= tj[0]) & (t <= tj[-1])]
    overlap = float(inside[-1] - inside[0]) if inside.size else 0.0
    if inside.size < 10 or overlap < min(min_overlap_s, 0.5 * float(tj[-1] - tj[0])):
        raise UnitDataError(
            f"unit '{unit}': its stamps {t[0]:.3f}..{t[-1]:.3f} s do not overlap the joint stream "
            f"{tj[0]:.3f}..{tj[-1]:.3f} s enough ({overlap:.3g} s, {inside.size} samples; at least {min_overlap_s:g} s "
            f"needed): stamped by another clock? put both on one clock first"
        )


def segment_automatically(dataset: Dataset, spec: MethodSpec) -> tuple[Dataset, list[str]]:
    """Segments for a dataset without ``/segments``, from its joint stream, with the rest speed
    threshold raised above the stream's own velocity noise (six standard deviations)."""
    from skincal.data.segment import SegmentationConfig, segment_dataset
    from skincal.errors import DatasetError

    sigma = float(np.max(joint_noise(dataset.joint_states.q, dataset.joint_states.qd)[1]))
    config = SegmentationConfig(rest_velocity=max(SegmentationConfig.rest_velocity, 6.0 * sigma))
    try:
        tagged, report = segment_dataset(dataset, config)
    except DatasetError as exc:
        if spec.needs_segments:
            raise CalibrationError(f"dataset has no segments and none could be found: {exc}") from None
        return dataset, [f"no segments in the dataset and none found automatically ({exc}); rests from the joint data"]
    return tagged, [
        f"no segments in the dataset: {report.n_static} static and {report.n_dynamic} dynamic found automatically "
        f"(rest below {config.rest_velocity:.3g} rad/s)"
    ]


def calibrate_unit(
    dataset: Dataset,
    unit: str,
    spec: MethodSpec,
    *,
    link: int | None,
    rng: np.random.Generator,
    interpolator: JointInterpolator | None = None,
    shared: Any = None,
    options: Any = None,
    alignment: Any = None,
    record: dict[str, Any] | None = None,
    diagnostics: bool = True,
) -> UnitResult:
    """Calibrate one unit (see :func:`calibrate`); ``options``: the method's parsed options
    (default: the method's defaults); ``alignment``: the unit's clock alignment found on its whole
    stream (``spec.align``), applied to this dataset's stream (a part of it) with its ``for_stream``
    instead of searching again; ``record``: where the alignment this call found (``spec.align``) is
    kept under the unit's name; ``diagnostics``: :attr:`UnitProblem.diagnostics`."""
    with method_errors():  # a foreign exception: this unit's CalibrationError, raised from it
        if interpolator is None:
            interpolator = JointInterpolator(dataset.joints)
        if shared is None and spec.prepare is not None:
            shared = spec.prepare(dataset, interpolator)
        options = parse_options(spec.options, {}, "") if options is None else options
        given_alignment, alignment, offset = alignment, None, 0.0
        _check_overlap(dataset, unit)
        motion = sees_motion(dataset, unit)
        skipped = None  # why the coarse clock search did not run
        if spec.align is not None and not getattr(options, "time_offset", True):
            skipped = "time offset not estimated (time_offset=false): no clock search, the stamps taken as they are"
        elif spec.align is not None and not motion:
            skipped = (
                "coarse clock search skipped: the unit's samples hold no motion (static poses only), so nothing "
                "determines the clock offset; the stamps taken as they are"
            )
        if spec.align is not None and skipped is None:
            if given_alignment is None:
                alignment = spec.align(shared, dataset.imu[unit])
                if record is not None:
                    record[unit] = alignment
            else:
                alignment = given_alignment.for_stream(dataset.imu[unit])
            offset = float(alignment.offset_s)
            stamps = getattr(alignment, "stamps", None)  # the unit's stamps corrected by the alignment
            if stamps is not None:
                dataset = replace(dataset, imu={**dataset.imu, unit: replace(dataset.imu[unit], t=stamps)})
        samples = unit_samples(
            dataset, unit, time_offset_s=offset, interpolator=interpolator, exact_joint_states=spec.exact_joint_states
        )
        if spec.needs_segments and not np.any(samples.kind == 0):
            raise CalibrationError(f"unit '{unit}': no samples in static segments")
        assignment = None
        if link is None and not spec.discovers_links:
            assignment = discover_link(samples, dataset.chain.n_joints, use_gyro=spec.use_gyro_for_links)
            if assignment.link == 0:
                raise CalibrationError(f"unit '{unit}': {'; '.join(assignment.warnings)}")
            link = assignment.link
        problem = UnitProblem(
            chain=dataset.robot,
            gravity=np.asarray(dataset.gravity, dtype=float),
            samples=samples,
            link=0 if link is None else int(link),
            link_assignment=assignment,
            rng=rng,
            interpolator=interpolator,
            shared=shared,
            options=options,
            time_offset_s=offset,
            alignment=alignment,
            diagnostics=diagnostics,
        )
        result = spec.run_unit(problem)
        _, screening = screen_readings(unit, dataset.imu[unit].accel, dataset.imu[unit].t)
        # the unit check (a stream 20x gravity's magnitude: a wrong unit or scale) on every method's result
        unit_check = () if samples.account is None else samples.account.unit_warnings
        screening = [w for w in unit_check if w not in result.warnings] + list(screening)
        if screening:
            result = replace(result, warnings=tuple(screening) + tuple(result.warnings))
        extras = dict(result.extras)
        if skipped is not None:
            result = replace(result, notes=(*result.notes, skipped))
        rests_only = not motion or result.extras.get("n_moving_samples") == 0  # rests never tell a position
        result = judge_position(replace(result, extras=extras), rests_only, static_only=not motion)
        # the link by name as well as index (a URDF robot's own link name; link<i> for a DH robot)
        link_name = dataset.chain.link_name(result.pose.link)
        return replace(result, extras={**result.extras, "link_name": link_name})


def sees_motion(dataset: Dataset, unit: str) -> bool:
    """Whether any of ``unit``'s samples (inside the joint stream) lies outside the dataset's rests
    (its static segments): ``False`` for a static-only session (samples in the rests only), where
    neither the accelerometer nor a gyroscope can tell a clock offset; ``True`` when the dataset has
    no segments (nothing tells)."""
    segments = dataset.segments
    if segments is None or len(segments) == 0:
        return True
    t = np.asarray(dataset.imu[unit].t, dtype=float)
    tj = np.asarray(dataset.joint_states.t, dtype=float)
    t = t[(t >= tj[0]) & (t <= tj[-1])]
    rest = np.zeros(t.shape, dtype=bool)
    for t0, t1, kind in zip(segments.t_start, segments.t_end, segments.kind, strict=True):
        if kind == STATIC:
            rest |= (t >= t0) & (t <= t1)
    return bool(t.size) and not bool(np.all(rest))
