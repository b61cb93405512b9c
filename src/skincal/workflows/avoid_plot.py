"""A figure like the paper's Fig. 4: proximity readings per unit over time against the flange error.

Left axis: each unit's range readings (m) with the avoidance threshold dashed; intervals where a unit
reads below the threshold are shaded in its colour. Right axis: the end-effector tracking error (mm).
With ``body`` (the true robot geometry) a second panel draws what ISO/TS 15066 asks about: the true
clearance between robot and person and the protective separation ``S_p`` the controller used, the
steps in protective stop shaded, and the task clock's lag behind time when it paused (right axis).
Written with matplotlib's Agg backend (no display needed) as PNG and/or SVG, chosen by suffix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skincal.errors import ConfigError
from skincal.perception.body import RobotBody
from skincal.workflows.avoidance import RunLog


def below_intervals(t: np.ndarray, r: np.ndarray, threshold: float) -> list[tuple[float, float]]:
    """Intervals ``[(t_start, t_end)]`` (s) over which readings ``r`` ``(M,)`` at ``t`` are below ``threshold`` m."""
    below = np.isfinite(r) & (r < threshold)
    edges = np.diff(np.concatenate([[0], below.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def plot_run(
    log: RunLog, path: str | Path, threshold: float = 1.0, title: str = "", body: RobotBody | None = None
) -> list[Path]:
    """Draw the figure of ``log`` to ``path`` (``.png`` or ``.svg``; ``.png`` also writes the ``.svg`` twin).

    Returns the files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    if path.suffix.lower() not in (".png", ".svg"):
        raise ConfigError(f"{path}: plot file must end in .png or .svg")
    if body is None:
        fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    else:
        fig, (ax, sep_ax) = plt.subplots(2, 1, figsize=(9, 7), sharex=True, constrained_layout=True)
        _separation_panel(sep_ax, log, body)
    colours = plt.get_cmap("tab10")
    for u, name in enumerate(log.units):
        t, r = log.tof_t[:, u], log.tof_range[:, u]
        ok = np.isfinite(t)
        if not np.any(np.isfinite(r[ok])):
            continue
        ax.plot(t[ok], r[ok], ".", ms=2.5, color=colours(u % 10), label=name)
        for a, b in below_intervals(t[ok], r[ok], threshold):
            ax.axvspan(a, b, color=colours(u % 10), alpha=0.15, lw=0)
    ax.axhline(threshold, ls="--", color="0.3", lw=1, label=f"threshold {threshold:g} m")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("proximity reading [m]")
    ax.set_ylim(0, max(1.5 * threshold, 0.1))
    ax.set_xlim(log.t[0], log.t[-1])
    err_ax = ax.twinx()
    err_ax.plot(log.t, 1e3 * log.tracking_error, color="k", lw=1.2, label="EE error")
    err_ax.set_ylabel("end-effector error [mm]")
    err_ax.set_ylim(bottom=0)
    lines = ax.get_legend_handles_labels()
    more = err_ax.get_legend_handles_labels()
    ax.legend(lines[0] + more[0], lines[1] + more[1], loc="upper right", fontsize=8, markerscale=3)
    ax.set_title(title or f"scenario '{log.scenario.name}': {log.scenario.description}", fontsize=9)
    from skincal.data.atomic import atomic_path

    written = [path] + ([path.with_suffix(".svg")] if path.suffix.lower() == ".png" else [])
    try:
        for target in written:  # each written whole or not at all
            with atomic_path(target) as tmp:
                fig.savefig(tmp, dpi=130, format=target.suffix.lower()[1:])
    finally:
        plt.close(fig)
    return written


def _separation_panel(ax, log: RunLog, body: RobotBody) -> None:
    from skincal.workflows.experiment import clearance, margin_of

    clear = clearance(log, body)
    sp = margin_of(log)
    ax.plot(log.t, np.where(np.isfinite(clear), clear, np.nan), color="C0", lw=1.2, label="clearance (true)")
    ax.plot(log.t, sp, color="C3", lw=1.0, ls="--", label="$S_p$ used")
    ax.fill_between(log.t, 0, sp, color="C3", alpha=0.08, lw=0)
    stop = log.protective_stop if log.protective_stop is not None else ~log.feasible
    for a, b in below_intervals(log.t, np.where(stop, 0.0, 1.0), 0.5):
        ax.axvspan(a, b, color="0.5", alpha=0.25, lw=0)
    ax.axhline(0.0, color="k", lw=0.6)
    top = np.nanmax(np.concatenate([sp[np.isfinite(sp)], clear[np.isfinite(clear)], [0.5]]))
    ax.set_ylim(min(-0.02, float(np.nanmin(np.where(np.isfinite(clear), clear, 0.0)))), min(1.5, 1.1 * top))
    ax.set_xlabel("time [s]")
    ax.set_ylabel("distance [m]")
    handles, labels = ax.get_legend_handles_labels()
    if log.task_time is not None and not np.array_equal(log.task_time, log.t):
        lag_ax = ax.twinx()
        lag_ax.plot(log.t, log.t - log.task_time, color="C2", lw=1.0, label="task clock lag")
        lag_ax.set_ylabel("task clock lag [s]")
        lag_ax.set_ylim(bottom=0)
        more = lag_ax.get_legend_handles_labels()
        handles, labels = handles + more[0], labels + more[1]
    ax.legend(handles, labels, loc="upper right", fontsize=8)
