"""Matplotlib figures of a calibration (Agg, no pyplot state) and their inline PNG encoding.

Every function returns a :class:`matplotlib.figure.Figure`; :func:`png_data_uri` turns one into a
``data:image/png;base64,...`` string for a self-contained HTML page.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from skincal.calib.metrics import Evaluation
from skincal.calib.residuals import PLOT_POINTS, UnitResiduals
from skincal.data.dataset import Segments
from skincal.kinematics.transforms import FloatArray

MAX_PLOT_POINTS = PLOT_POINTS
"""Residual traces are thinned to at most this many points (a picture, not the data)."""
LABELLED_UNITS = 40
"""Up to this many units, per-unit figures name every unit; beyond, units are numbered in table order."""
AXIS_COLORS = ("#d62728", "#2ca02c", "#1f77b4")
_RC = {"text.usetex": False}


def plain(text: object) -> str:
    """``text`` for a matplotlib label, shown as written: ``$`` escaped so that a user's string
    (a unit named ``$\\frac{$``) is never parsed as mathtext."""
    return str(text).replace("$", r"\$")


@contextmanager
def style() -> Iterator[None]:
    """Matplotlib settings of the report's figures whatever the user's matplotlibrc says (no LaTeX)."""
    from matplotlib import rc_context

    with rc_context(_RC):
        yield


def png_data_uri(fig: Figure, dpi: int = 90, *, close: bool = True) -> str:
    """The figure as an inline ``data:image/png;base64,...`` URI; ``close``: clear the figure
    afterwards (its artists are freed at once instead of when the garbage collector runs)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    if close:
        fig.clear()
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _joint_colors(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(j % 10) for j in range(n)]


def residual_figure(res: UnitResiduals, segments: Segments | None, n_joints: int) -> Figure:
    """Residual ``f_meas - f_pred`` (unit frame, m/s^2) of one unit: components over time with the
    dynamic segments shaded by excited joint (top), RMS residual norm per segment (bottom). Traces
    longer than :data:`MAX_PLOT_POINTS` are thinned first (:meth:`UnitResiduals.thinned`)."""
    if len(res.t) > MAX_PLOT_POINTS:
        res = res.thinned(MAX_PLOT_POINTS)
    fig = Figure(figsize=(10, 4.2), layout="constrained")
    ax_t, ax_s = fig.subplots(2, 1, height_ratios=[3, 2])
    colors = _joint_colors(n_joints)
    if segments is not None:
        t0, t1 = np.asarray(segments.t_start), np.asarray(segments.t_end)
        kind, joint = np.asarray(segments.kind), np.asarray(segments.joint)
        for j in range(n_joints):
            m = (kind == 1) & (joint == j)
            if np.any(m):
                ax_t.broken_barh(list(zip(t0[m], t1[m] - t0[m], strict=True)), (0, 1), color=colors[j], alpha=0.12,
                                 lw=0, transform=ax_t.get_xaxis_transform())
    for k, axis in enumerate("xyz"):
        ax_t.plot(res.t, res.residual[:, k], lw=0.6, color=AXIS_COLORS[k], label=axis)
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("residual [m/s²]")
    n = res.n_samples if res.n_samples is not None else len(res.t)
    thin = "" if n == len(res.t) else f", {len(res.t)} of {n} samples drawn (envelope)"
    ax_t.set_title(f"{plain(res.unit)}: accelerometer residual, RMS {res.rms:.3g} m/s² (shading: excited joint{thin})",
                   fontsize=10)
    ax_t.legend(loc="upper right", ncol=3, fontsize=8)
    ax_t.grid(alpha=0.3)
    if segments is not None and len(segments):
        joint = np.asarray(segments.joint)
        bar_colors = ["0.6" if j < 0 else colors[j] for j in joint]
        ax_s.bar(np.arange(len(segments)), np.nan_to_num(res.segment_rms), color=bar_colors, width=0.9)
        ax_s.set_xlim(-0.5, len(segments) - 0.5)
        handles = [Patch(color=colors[j], label=f"j{j + 1}") for j in sorted(set(joint[joint >= 0]))]
        handles.append(Patch(color="0.6", label="static"))
        ax_s.legend(handles=handles, loc="upper right", ncol=min(8, len(handles)), fontsize=7)
    ax_s.set_xlabel("segment")
    ax_s.set_ylabel("RMS [m/s²]")
    ax_s.grid(alpha=0.3, axis="y")
    return fig


def activity_figure(activity: FloatArray, units: list[str]) -> Figure:
    """Data coverage heatmap: activity of each joint on each unit as a multiple of the motion
    threshold, log colour scale; cells >= 1 mean that joint moved the unit. Up to
    :data:`LABELLED_UNITS` units: one named row per unit with the values written in; beyond: one
    column per unit numbered in table order (joints as rows), no values."""
    n_units, n = activity.shape
    data = np.clip(np.nan_to_num(activity, nan=1e-3), 1e-3, None)
    norm = LogNorm(vmin=1e-2, vmax=max(10.0, float(data.max()) if data.size else 10.0))
    title = "data coverage: joint activity / threshold (>= 1: moved the unit)"
    if n_units > LABELLED_UNITS:
        fig = Figure(figsize=(10, 1.4 + 0.3 * n), layout="constrained")
        ax = fig.subplots()
        im = ax.imshow(data.T, cmap="viridis", norm=norm, aspect="auto", interpolation="nearest",
                       extent=(0.5, n_units + 0.5, n - 0.5, -0.5))
        ax.set_yticks(range(n), [f"j{j + 1}" for j in range(n)])
        ax.set_xlabel("unit (row of the units table)")
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.05)
        return fig
    fig = Figure(figsize=(1.2 + 0.8 * n, 0.9 + 0.42 * n_units), layout="constrained")
    ax = fig.subplots()
    im = ax.imshow(data, cmap="viridis", norm=norm, aspect="auto")
    for i in range(n_units):
        for j in range(n):
            v = activity[i, j]
            text = "-" if not np.isfinite(v) else (f"{v:.2g}" if v < 100 else f"{v:.0f}")
            ax.text(j, i, text, ha="center", va="center", fontsize=7, color="w" if data[i, j] < 1 else "k")
    ax.set_xticks(range(n), [f"j{j + 1}" for j in range(n)])
    ax.set_yticks(range(n_units), [plain(u) for u in units])
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.05)
    return fig


def _unit_axis(ax, units: list[str]) -> None:
    """Name the units on the x axis, or number them (table order) when there are many."""
    if len(units) <= LABELLED_UNITS:
        ax.set_xticks(range(len(units)), [plain(u) for u in units])
        ax.tick_params(axis="x", labelrotation=45)
    else:
        ax.set_xlabel("unit (row of the units table)")


def bias_figure(units: list[str], bias_mps2: FloatArray, bias_true_mps2: FloatArray | None = None) -> Figure:
    """Estimated accelerometer bias per unit and axis (m/s^2), with the true bias as markers when
    given; bars up to :data:`LABELLED_UNITS` units, markers beyond."""
    many = len(units) > LABELLED_UNITS
    fig = Figure(figsize=(10 if many else 1.5 + 0.9 * len(units), 2.8), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(units)) + (1 if many else 0)
    for k, axis in enumerate("xyz"):
        if many:
            ax.plot(x, bias_mps2[:, k], ".", ms=4, color=AXIS_COLORS[k], label=f"{axis} est.")
            if bias_true_mps2 is not None:
                ax.plot(x, bias_true_mps2[:, k], "k_", ms=4, mew=1)
        else:
            ax.bar(x + (k - 1) * 0.27, bias_mps2[:, k], width=0.26, color=AXIS_COLORS[k], label=f"{axis} est.")
            if bias_true_mps2 is not None:
                ax.plot(x + (k - 1) * 0.27, bias_true_mps2[:, k], "k_", ms=12, mew=2)
    if bias_true_mps2 is not None:
        ax.plot([], [], "k_", ms=12, mew=2, label="true")
    ax.axhline(0, color="k", lw=0.5)
    _unit_axis(ax, units)
    ax.set_ylabel("bias [m/s²]")
    ax.legend(fontsize=7, ncol=4)
    ax.grid(alpha=0.3, axis="y")
    return fig


def error_figure(evaluation: Evaluation) -> Figure:
    """Position error (mm) and rotation error (deg) per unit of an evaluation (grey: unobservable
    units); bars up to :data:`LABELLED_UNITS` units, markers beyond."""
    names = list(evaluation.units)
    pos = [evaluation.units[u].position_error_mm for u in names]
    rot = [evaluation.units[u].rotation_error_deg for u in names]
    many = len(names) > LABELLED_UNITS
    fig = Figure(figsize=(10 if many else 1.5 + 1.6 * len(names), 2.6), layout="constrained")
    ax_p, ax_r = fig.subplots(1, 2)
    x = np.arange(len(names)) + (1 if many else 0)
    for ax, vals, label, color in ((ax_p, pos, "position error [mm]", "#1f77b4"), (ax_r, rot, "rotation error [deg]",
                                                                                 "#ff7f0e")):
        colors = [color if evaluation.units[u].observable else "0.6" for u in names]
        if many:
            ax.scatter(x, vals, s=6, c=colors)
        else:
            ax.bar(x, vals, color=colors)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
        _unit_axis(ax, names)
    return fig
