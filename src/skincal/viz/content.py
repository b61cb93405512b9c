"""Everything a report shows, computed once from a result and its dataset (HTML and markdown share it)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from skincal.calib.metrics import Evaluation, evaluate
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.residuals import PLOT_POINTS, UnitResiduals, unit_activity, unit_residuals
from skincal.data.dataset import Dataset, ImuStream
from skincal.data.result import CalibrationResult, has_position
from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.parallel import can_fork, imap

WORST_SHOWN = 10
"""Units whose residuals the HTML report plots: the worst by the report's key figure (:class:`Ranking`)."""

_UnitOutcome = tuple[float, "UnitResiduals | None", FloatArray]
"""One unit's residual RMS, its thinned residual trace (None: not plotted) and its activity row."""
@dataclass(frozen=True)
class UnitRow:
    """One line of the per-unit table (SI units; ``scale`` is the diagonal of the scale/misalignment
    matrix, ``None`` where the method did not estimate it; ``time_offset_s`` None likewise)."""

    name: str
    link: int
    position_m: FloatArray | None
    quaternion_wxyz: FloatArray
    observable: bool
    position_std_m: FloatArray | None
    rotation_std_deg: FloatArray | None
    bias_mps2: FloatArray | None
    scale: FloatArray | None
    time_offset_s: float | None
    residual_rms_mps2: float
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class Ranking:
    """The calibrated units from worst to best by the report's key figure: the position error against
    the truth (mm) when the dataset has truth for every unit, else the accelerometer residual RMS
    (m/s^2). Units whose figure is NaN come last.

    Attributes:
        figure: what ``values`` are, with their unit (a column heading).
        values: unit -> key figure, worst first.
    """

    figure: str
    values: dict[str, float]

    def worst(self, n: int) -> list[str]:
        """The ``n`` worst units."""
        return list(self.values)[: max(0, n)]


def rank_units(values: dict[str, float], figure: str) -> Ranking:
    """A :class:`Ranking` of ``values`` (larger is worse; NaN last; ties in the given order)."""
    order = sorted(values, key=lambda u: (not np.isfinite(values[u]), -np.nan_to_num(values[u], nan=0.0)))
    return Ranking(figure, {u: float(values[u]) for u in order})


@dataclass(frozen=True)
class ReportContent:
    """Inputs of a calibration report.

    Attributes:
        result: the calibration result.
        dataset: the dataset it was computed from.
        rows: per-unit table rows, in the result's unit order.
        residuals: accelerometer residuals (:func:`unit_residuals`, thinned for plotting with
            :meth:`UnitResiduals.thinned`) of the units the report plots: the worst ``shown`` units of
            ``ranking``, worst first. The full residual RMS of every unit is in ``rows``.
        activity: ``(units, n)`` data coverage (:func:`activity_matrix`), rows in ``rows`` order.
        evaluation: the ``skincal evaluate`` errors when the dataset has truth for every unit, else None.
        failed: units the method could not calibrate, with the reason.
        ranking: every calibrated unit, worst first by the key figure (:class:`Ranking`).
    """

    result: CalibrationResult
    dataset: Dataset
    rows: list[UnitRow]
    residuals: dict[str, UnitResiduals]
    activity: FloatArray
    evaluation: Evaluation | None
    failed: dict[str, str]
    ranking: Ranking = field(default_factory=lambda: Ranking("", {}))


def collect(
    result: CalibrationResult,
    dataset: Dataset,
    *,
    use_dataset_qdd: bool = False,
    shown: int = WORST_SHOWN,
    max_points: int = PLOT_POINTS,
    progress: Callable[[str], None] | None = None,
    workers: int = 1,
) -> ReportContent:
    """Recompute residuals and coverage for every unit of ``result`` on ``dataset``.

    ``use_dataset_qdd``: predict with the dataset's joint accelerations instead of estimating them
    from the velocities (as ``skincal calibrate --use-dataset-qdd`` does). ``shown``: how many of
    the worst units keep their residual traces (thinned to ``max_points`` samples) for plots; the
    others keep only their RMS figures, so memory does not grow with the recording times the units.
    ``progress``: called with a short message as each unit is done. ``workers``: units computed at
    once, in forked processes where the platform can fork (the results are the same as with one);
    the units' IMU streams are read from ``dataset.imu`` one at a time, in this process, so a dataset
    of :func:`skincal.data.hdf5.open_dataset` holds one unit's data at a time (a few per worker)."""
    missing = [u for u in result.units if u not in dataset.imu]
    if missing:
        raise DatasetError(f"dataset has no IMU data for unit(s) {', '.join(missing)} of the result")
    if result.robot and dataset.robot.name and result.robot != dataset.robot.name:
        raise DatasetError(f"result is for robot '{result.robot}' but the dataset is of '{dataset.robot.name}'")
    note = progress or (lambda _message: None)
    interp = JointInterpolator(dataset.joints, use_dataset_qdd=use_dataset_qdd)
    evaluation = evaluate(result, dataset) if dataset.truth and all(u in dataset.truth for u in result.units) else None
    ranking = None
    keep: set[str] = set()
    if evaluation is not None:  # the key figure is known before the residuals: keep only the shown units' traces
        ranking = rank_units({u: evaluation.units[u].position_error_mm for u in result.units},
                             "position error against the truth [mm]")
        keep = set(ranking.worst(shown))
    keep_all = ranking is None

    def one(name: str, imu: ImuStream) -> _UnitOutcome:
        single = replace(dataset, imu={name: imu})  # this unit alone: the others are not read
        r = unit_residuals(single, name, result.units[name], interp)
        trace = r.thinned(max_points) if keep_all or name in keep else None
        return r.rms, trace, unit_activity(single, name, interp)

    traces: dict[str, UnitResiduals] = {}
    rms: dict[str, float] = {}
    activity = np.full((len(result.units), dataset.robot.n_joints), np.nan)
    names = list(result.units)
    total = len(names)
    for i, (name, (unit_rms, trace, act)) in enumerate(
        zip(names, _per_unit(one, dataset, names, interp, workers), strict=True)
    ):
        rms[name] = unit_rms
        if trace is not None:
            traces[name] = trace
        activity[i] = act
        note(f"residuals and coverage {i + 1}/{total}: {name}")
    if ranking is None:
        ranking = rank_units(rms, "accelerometer residual RMS [m/s²]")
    residuals = {u: traces[u] for u in ranking.worst(shown)}
    rows = []
    for name, unit in result.units.items():
        imu = unit.imu
        scale = imu is not None and unit.extras.get("scale_estimated", imu.accel_scale_misalignment is not None)
        rows.append(
            UnitRow(
                name=name,
                link=unit.pose.link,
                position_m=unit.pose.p_link_su if has_position(unit) else None,  # None: not determined
                quaternion_wxyz=unit.pose.quaternion_wxyz,
                observable=unit.observable,
                position_std_m=unit.position_std_m,
                rotation_std_deg=unit.rotation_std_deg,
                bias_mps2=imu.bias if imu is not None and imu.accel_bias_mps2 is not None else None,
                scale=np.diag(imu.scale_matrix).copy() if imu is not None and scale else None,
                time_offset_s=imu.time_offset_s if imu is not None else None,
                residual_rms_mps2=rms[name],
                warnings=unit.warnings,
            )
        )
    return ReportContent(result, dataset, rows, residuals, activity, evaluation, dict(result.failed_units), ranking)


def _per_unit(
    one: Callable[[str, ImuStream], _UnitOutcome],
    dataset: Dataset,
    names: list[str],
    interp: JointInterpolator,
    workers: int,
) -> Iterator[_UnitOutcome]:
    """``one(name, dataset.imu[name])`` for each unit in order; with ``workers > 1`` (and ``fork``) in
    that many forked processes, at most two units per worker read ahead (bounded memory)."""
    n_workers = max(1, min(int(workers), len(names), os.cpu_count() or 1))
    if n_workers == 1 or not can_fork():
        for name in names:
            yield one(name, dataset.imu[name])
        return
    interp.warm()  # computed once here, inherited by every child
    items = ((name, dataset.imu[name]) for name in names)  # read by the parent alone, as the workers need them
    for _, outcome in imap(lambda item: one(*item), items, n_workers, fork=True, window=2 * n_workers):
        yield outcome
