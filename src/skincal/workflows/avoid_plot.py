"""A figure like the paper's Fig. 4: proximity readings per unit over time against the flange error.

Left axis: each unit's range readings (m) with the avoidance threshold dashed; intervals where a unit
reads below the threshold are shaded in its colour. Right axis: the end-effector tracking error (mm).
Written with matplotlib's Agg backend (no display needed) as PNG and/or SVG, chosen by suffix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skincal.errors import ConfigError
from skincal.workflows.avoidance import RunLog


def below_intervals(t: np.ndarray, r: np.ndarray, threshold: float) -> list[tuple[float, float]]:
    """Intervals ``[(t_start, t_end)]`` (s) over which readings ``r`` ``(M,)`` at ``t`` are below ``threshold`` m."""
    below = np.isfinite(r) & (r < threshold)
    edges = np.diff(np.concatenate([[0], below.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def plot_run(log: RunLog, path: str | Path, threshold: float = 1.0, title: str = "") -> list[Path]:
    """Draw the figure of ``log`` to ``path`` (``.png`` or ``.svg``; ``.png`` also writes the ``.svg`` twin).

    Returns the files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    if path.suffix.lower() not in (".png", ".svg"):
        raise ConfigError(f"{path}: plot file must end in .png or .svg")
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
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
    written = [path]
    fig.savefig(path, dpi=130)
    if path.suffix.lower() == ".png":
        svg = path.with_suffix(".svg")
        fig.savefig(svg)
        written.append(svg)
    plt.close(fig)
    return written
