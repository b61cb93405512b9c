"""The calibration report: ONE self-contained HTML file (inline CSS, plots as base64 PNG, no scripts,
no external resources), built from :class:`skincal.viz.content.ReportContent`.

Sections: summary; the worst units by the key figure (:class:`skincal.viz.content.Ranking`);
per-unit table (link, position in the link frame, quaternion (w, x, y, z),
1-sigma std, warnings); errors against the truth (simulated datasets); sensor parameters (bias,
scale, time offset; true values beside them when the dataset has them); data coverage (activity
heatmap); accelerometer residuals per unit and segment, plotted for the worst units only (at most
:data:`~skincal.viz.content.WORST_SHOWN`; thinned to a few thousand points) so that the page and
the time to build it do not grow with the number of units times the recording length.
"""

from __future__ import annotations

import html
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skincal.calib.metrics import error_text
from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult
from skincal.io.atomic import write_bytes_atomic
from skincal.names import printable
from skincal.viz.content import WORST_SHOWN, ReportContent, UnitRow, collect

_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'Liberation Sans',sans-serif;margin:2em auto;
max-width:1150px;color:#222;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.25em;border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:1.8em}
table{border-collapse:collapse;font-size:.86em;margin:.6em 0}
th,td{border:1px solid #ddd;padding:.25em .55em;text-align:right;vertical-align:top}
th{background:#f3f4f6}td.l,th.l{text-align:left}
tr.bad td{background:#fff4e5}.muted{color:#777}.warn{color:#b45309}.ok{color:#15803d}
img{max-width:100%;height:auto;display:block;margin:.4em 0}
code{background:#f3f4f6;padding:0 .25em}
"""


def _e(text: object) -> str:
    """Free text (names, warnings, the description) for HTML: control characters shown as escapes
    (:func:`skincal.names.printable`: an ESC or BEL is never written raw), then HTML-escaped."""
    return html.escape(printable(str(text)), quote=True)


def _vec(values, fmt: str, scale: float = 1.0) -> str:
    if values is None:
        return '<span class="muted">-</span>'
    return " ".join("n/a" if not np.isfinite(v) else format(scale * v, fmt) for v in np.asarray(values, dtype=float))


def _table(
    header: list[str], rows: list[list[str]], left: int | set[int] = 1, classes: list[str] | None = None
) -> str:
    """An HTML table; ``left``: the first ``left`` columns, or these column indices, are left-aligned."""
    lefts = set(range(left)) if isinstance(left, int) else left
    head = "".join(f'<th class="l">{h}</th>' if i in lefts else f"<th>{h}</th>" for i, h in enumerate(header))
    body = []
    for r, row in enumerate(rows):
        cls = f' class="{classes[r]}"' if classes and classes[r] else ""
        cells = "".join(f'<td class="l">{c}</td>' if i in lefts else f"<td>{c}</td>" for i, c in enumerate(row))
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _unit_table(rows: list[UnitRow]) -> str:
    header = ["unit", "link", "position [m]", "quaternion (w, x, y, z)", "pos. std [mm]", "rot. std [deg]",
              "residual RMS [m/s²]", "warnings"]
    body, classes = [], []
    for r in rows:
        notes = ([] if r.observable else ['<b class="warn">unobservable</b>']) + [_e(w) for w in r.warnings]
        body.append([
            _e(r.name), str(r.link), _vec(r.position_m, "+.4f"), _vec(r.quaternion_wxyz, "+.4f"),
            _vec(r.position_std_m, ".3f", 1e3), _vec(r.rotation_std_deg, ".3f"), f"{r.residual_rms_mps2:.4f}",
            "<br>".join(notes) or '<span class="ok">none</span>',
        ])
        classes.append("" if r.observable and not r.warnings else "bad")
    head = "".join(f'<th class="l">{h}</th>' if i in (0, 7) else f"<th>{h}</th>" for i, h in enumerate(header))
    trs = "".join(
        f'<tr class="{c}">' + "".join(f'<td class="l">{v}</td>' if i in (0, 7) else f"<td>{v}</td>"
                                      for i, v in enumerate(row)) + "</tr>"
        for row, c in zip(body, classes, strict=True)
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{trs}</tbody></table>"


def _worst_section(content: ReportContent, n: int) -> str:
    """The ``n`` worst units by the key figure, with their link, errors (truth) or std, residual RMS, warnings."""
    ranking, ev = content.ranking, content.evaluation
    worst = ranking.worst(n)
    if not worst:
        return ""
    by_name = {r.name: r for r in content.rows}
    header = ["#", "unit", ranking.figure, "link"]
    header += ["rotation error [deg]"] if ev is not None else []
    header += ["pos. std [mm]", "rot. std [deg]", "residual RMS [m/s²]", "warnings"]
    rows, classes = [], []
    for i, name in enumerate(worst):
        r = by_name[name]
        value = ranking.values[name]
        notes = ([] if r.observable else ['<b class="warn">unobservable</b>']) + [_e(w) for w in r.warnings]
        link = str(r.link)
        if ev is not None:
            u = ev.units[name]
            if u.link_true != u.link_estimated:
                link += f' <b class="warn">(true {u.link_true})</b>'
            extra = [f"{u.rotation_error_deg:.4f}"]
        else:
            extra = []
        extra += [_vec(r.position_std_m, ".3f", 1e3), _vec(r.rotation_std_deg, ".3f")]
        rows.append([str(i + 1), _e(name), "n/a" if not np.isfinite(value) else f"{value:.4g}", link, *extra,
                     f"{r.residual_rms_mps2:.4f}", "<br>".join(notes) or '<span class="ok">none</span>'])
        classes.append("" if r.observable and not r.warnings else "bad")
    total = len(ranking.values)
    what = f"The {len(worst)} worst of {total} unit(s)" if len(worst) < total else f"All {total} unit(s)"
    return (f'<h2>Worst units</h2><p class="muted">{what} by {_e(ranking.figure)}, worst first; every unit is in '
            "the tables below.</p>" + _table(header, rows, left={0, 1, len(header) - 1}, classes=classes))


def _residual_section(content: ReportContent, n_joints: int, note: Callable[[str], None]) -> str:
    """Residual figures of the units in ``content.residuals`` (the worst ones), one figure at a time."""
    from skincal.viz import plots
    ds, total, shown = content.dataset, len(content.ranking.values) or len(content.rows), len(content.residuals)
    intro = ("<h2>Accelerometer residuals</h2><p class=\"muted\">Measured minus predicted specific force "
             "f = A R<sup>T</sup>(u + K p) + b at t &minus; time offset, in the unit frame. ")
    if shown < total:
        intro += (f"Shown for the {shown} worst of {total} units by {_e(content.ranking.figure)}; the residual "
                  "RMS of every unit is in the units table.")
    parts = [intro + "</p>"]
    for i, (name, r) in enumerate(content.residuals.items()):
        note(f"residual plot {i + 1}/{shown}: {name}")
        uri = plots.png_data_uri(plots.residual_figure(r, ds.segments, n_joints), dpi=80)
        parts.append(f'<h3>{_e(name)}</h3><img alt="residuals of {_e(name)}" src="{uri}">')
    return "".join(parts)


def _errors_section(content: ReportContent) -> str:
    from skincal.viz import plots

    ev = content.evaluation
    if ev is None:
        return '<p class="muted">The dataset has no truth (a real recording): no errors to show.</p>'
    rows = []
    for name, u in ev.units.items():
        link = f"{u.link_true}" + ("" if u.link_true == u.link_estimated else
                                      f' <b class="warn">(est. {u.link_estimated})</b>')
        mark = "" if u.observable else ' <span class="muted">(unobservable)</span>'
        rows.append([_e(name) + mark, link, error_text(u.position_error_mm), f"{u.rotation_error_deg:.4f}",
                     f"{u.quaternion_distance:.5f}"])
    if ev.mean_position_error_mm is not None:
        rows.append(["<b>mean (observable)</b>", f"{ev.links_correct}/{ev.units_total} links ok",
                     f"<b>{ev.mean_position_error_mm:.3f}</b>", f"<b>{ev.mean_rotation_error_deg:.4f}</b>",
                     f"<b>{ev.mean_quaternion_distance:.5f}</b>"])
    table = _table(["unit", "true link", "position error [mm]", "rotation error [deg]", "quaternion distance"], rows)
    return table + f'<img alt="pose errors" src="{plots.png_data_uri(plots.error_figure(ev))}">'


def _sensor_section(content: ReportContent) -> str:
    from skincal.viz import plots

    truth = content.dataset.truth_sensor
    rows = []
    for r in content.rows:
        t = truth.get(r.name, {})
        tb, ts, tt = t.get("accel_bias"), t.get("accel_scale"), t.get("time_offset_s")
        rows.append([
            _e(r.name), _vec(r.bias_mps2, "+.4f"), _vec(tb, "+.4f"),
            _vec(None if r.scale is None else (r.scale - 1.0), "+.0f", 1e6),
            _vec(None if ts is None else np.asarray(ts, dtype=float) - 1.0, "+.0f", 1e6),
            "-" if r.time_offset_s is None else f"{1e3 * r.time_offset_s:+.2f}",
            "-" if tt is None else f"{1e3 * float(tt):+.2f}",
        ])
    table = _table(["unit", "bias [m/s²]", "true bias", "scale - 1 [ppm]", "true scale - 1", "time offset [ms]",
                    "true offset"], rows)
    biased = [r for r in content.rows if r.bias_mps2 is not None]
    if not biased:
        return table
    true_b = None
    if all("accel_bias" in truth.get(r.name, {}) for r in biased):
        true_b = np.array([np.asarray(truth[r.name]["accel_bias"], dtype=float) for r in biased])
    fig = plots.bias_figure([r.name for r in biased], np.array([r.bias_mps2 for r in biased]), true_b)
    return table + f'<img alt="accelerometer biases" src="{plots.png_data_uri(fig)}">'


def render_html(
    content: ReportContent,
    dataset_sha256: str | None = None,
    *,
    worst: int = WORST_SHOWN,
    progress: Callable[[str], None] | None = None,
) -> str:
    """The report page as one HTML string (no external resources). ``dataset_sha256``: digest of the
    dataset file, compared with the one the result records; ``worst``: rows of the worst-units table;
    ``progress``: called with a short message before each figure."""
    # matplotlib is imported here, after the residuals: not in memory while they are computed (issue 19)
    from skincal.viz import plots

    with plots.style():
        return _render_html(content, dataset_sha256, worst, progress or (lambda _message: None))


def _render_html(content: ReportContent, dataset_sha256: str | None, worst: int, note: Callable[[str], None]) -> str:
    res, ds = content.result, content.dataset
    n_joints = ds.robot.n_joints
    check = ""
    if dataset_sha256 and res.dataset_sha256:
        same = dataset_sha256 == res.dataset_sha256
        check = (' <span class="ok">(dataset file matches the result)</span>' if same else
                 ' <b class="warn">(the dataset file differs from the one the result was computed from)</b>')
    summary = [
        f"method <code>{_e(res.method)}</code> on robot <code>{_e(res.robot)}</code>, "
        f"{len(res.units)} unit(s), runtime {res.runtime_s:.2f} s{check}",
        f"dataset: {_e(ds.description or '(no description)')}; {ds.duration:.1f} s, "
        f"{len(ds.segments) if ds.segments is not None else 0} segments",
    ]
    if content.evaluation is not None and content.evaluation.mean_position_error_mm is not None:
        ev = content.evaluation
        summary.append(f"mean error against truth: <b>{ev.mean_position_error_mm:.3f} mm</b>, "
                       f"<b>{ev.mean_rotation_error_deg:.4f} deg</b>; links {ev.links_correct}/"
                       f"{ev.units_total} correct")
    failed = "".join(f"<li><b>{_e(k)}</b>: {_e(v)}</li>" for k, v in content.failed.items())
    from skincal.viz import plots

    note("plot: data coverage")
    coverage = plots.png_data_uri(plots.activity_figure(content.activity, [r.name for r in content.rows]))
    note("plot: errors against the truth")
    errors = _errors_section(content)
    note("plot: sensor parameters")
    sensors = _sensor_section(content)
    residual_imgs = _residual_section(content, n_joints, note)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>skincal report: {_e(res.method)} on {_e(res.robot)}</title><style>{_CSS}</style></head><body>",
        f"<h1>Calibration report: {_e(res.method)} on {_e(res.robot)}</h1>",
        "<p>" + "<br>".join(summary) + "</p>",
        _worst_section(content, worst),
        f"<h2>Units</h2><p class=\"muted\">Poses in their link frame (DH frame {{link}}); std = 1 sigma.</p>"
        f"{_unit_table(content.rows)}",
        f"<h2>Units not calibrated</h2><ul>{failed}</ul>" if failed else "",
        f"<h2>Errors against the truth</h2>{errors}",
        f"<h2>Sensor parameters</h2>{sensors}",
        '<h2>Data coverage</h2><p class="muted">Which joints excited which unit (activity matrix of the link '
        f'discovery).</p><img alt="data coverage" src="{coverage}">',
        residual_imgs,
        "</body></html>",
    ]
    return "\n".join(p for p in parts if p)


def write_report(
    result: CalibrationResult,
    dataset: Dataset,
    out: str | Path,
    fmt: str = "html",
    *,
    dataset_sha256: str | None = None,
    use_dataset_qdd: bool = False,
    worst: int = WORST_SHOWN,
    progress: Callable[[str], None] | None = None,
    workers: int = 1,
) -> ReportContent:
    """Write the HTML report (``fmt="html"``) or the markdown summary (``"md"``) to ``out`` atomically
    (``use_dataset_qdd``: see :func:`skincal.viz.content.collect`; ``worst``: units in the worst-units
    table and with residual plots; ``progress``: called with a short message at each step; ``workers``:
    units computed at once, see :func:`~skincal.viz.content.collect`)."""
    from skincal.errors import ConfigError
    from skincal.viz.summary import render_markdown

    if fmt not in ("html", "md"):
        raise ConfigError(f"report format must be 'html' or 'md', got '{fmt}'")
    shown = worst if fmt == "html" else 0
    content = collect(result, dataset, use_dataset_qdd=use_dataset_qdd, shown=shown, progress=progress, workers=workers)
    if fmt == "html":
        text = render_html(content, dataset_sha256, worst=worst, progress=progress)
    else:
        text = render_markdown(content, worst=worst)
    if progress is not None:
        progress(f"writing {out}")
    write_bytes_atomic(Path(out), text.encode("utf-8"))
    return content
