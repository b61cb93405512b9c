"""Markdown summary of a calibration for terminals and CI logs (GitHub-flavoured tables, no images)."""

from __future__ import annotations

import numpy as np

from skincal.calib.metrics import error_text
from skincal.names import printable
from skincal.viz.content import WORST_SHOWN, ReportContent


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _vec(values, fmt: str, scale: float = 1.0) -> str:
    if values is None:
        return "-"
    return " ".join("n/a" if not np.isfinite(v) else format(scale * v, fmt) for v in np.asarray(values, dtype=float))


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines


def _worst(content: ReportContent, n: int) -> list[str]:
    """The ``n`` worst units by the report's key figure (empty when there is no ranking or ``n`` is 0)."""
    ranking = content.ranking
    worst = ranking.worst(n)
    if not worst:
        return []
    by_name = {r.name: r for r in content.rows}
    total = len(ranking.values)
    what = f"The {len(worst)} worst of {total} unit(s)" if len(worst) < total else f"All {total} unit(s)"
    rows = []
    for i, name in enumerate(worst):
        r, value = by_name[name], ranking.values[name]
        notes = ([] if r.observable else ["UNOBSERVABLE"]) + list(r.warnings)
        rows.append([str(i + 1), name, "n/a" if not np.isfinite(value) else f"{value:.4g}", str(r.link),
                     f"{r.residual_rms_mps2:.4f}", "; ".join(notes) or "-"])
    return ["", "## Worst units", "", f"{what} by {ranking.figure}, worst first.", "",
            *_table(["#", "unit", ranking.figure, "link", "resid RMS [m/s2]", "warnings"], rows)]


def render_markdown(content: ReportContent, worst: int = WORST_SHOWN) -> str:
    """The summary: header line, the ``worst`` worst units by the key figure, per-unit table (pose,
    std, residual, sensor parameters, warnings), errors against the truth when available, data
    coverage (joints that moved each unit). Control characters in its free text are shown as escapes."""
    res, ds = content.result, content.dataset
    out = [f"# skincal calibration: {res.method} on {res.robot}", ""]
    out.append(f"{len(res.units)} unit(s), runtime {res.runtime_s:.2f} s; dataset {ds.duration:.1f} s"
               + (f" ({ds.description})" if ds.description else ""))
    out += _worst(content, worst)
    out += ["", "## Units", ""]
    rows = []
    for r in content.rows:
        notes = ([] if r.observable else ["UNOBSERVABLE"]) + list(r.warnings)
        rows.append([
            r.name, str(r.link), _vec(r.position_m, "+.4f"), _vec(r.quaternion_wxyz, "+.4f"),
            _vec(r.position_std_m, ".3f", 1e3), _vec(r.rotation_std_deg, ".3f"), f"{r.residual_rms_mps2:.4f}",
            _vec(r.bias_mps2, "+.4f"), _vec(None if r.scale is None else r.scale - 1.0, "+.0f", 1e6),
            "-" if r.time_offset_s is None else f"{1e3 * r.time_offset_s:+.2f}",
            "; ".join(notes) or "-",
        ])
    out += _table(["unit", "link", "position [m]", "quaternion wxyz", "pos std [mm]", "rot std [deg]",
                   "resid RMS [m/s2]", "bias [m/s2]", "scale-1 [ppm]", "offset [ms]", "warnings"], rows)
    if content.failed:
        out += ["", "## Not calibrated", ""] + [f"- {k}: {v}" for k, v in content.failed.items()]
    ev = content.evaluation
    if ev is not None:
        out += ["", "## Errors against truth", ""]
        erows = [[name, f"{u.link_true}/{u.link_estimated}", error_text(u.position_error_mm),
                  f"{u.rotation_error_deg:.4f}", f"{u.quaternion_distance:.5f}"]
                 for name, u in ev.units.items()]
        if ev.mean_position_error_mm is not None:
            erows.append(["**mean**", f"{ev.links_correct}/{ev.units_total} ok",
                          f"**{ev.mean_position_error_mm:.3f}**", f"**{ev.mean_rotation_error_deg:.4f}**",
                          f"**{ev.mean_quaternion_distance:.5f}**"])
        out += _table(["unit", "link true/est", "position error [mm]", "rotation error [deg]", "quat. distance"], erows)
    out += ["", "## Data coverage", "", "Joints whose motion moved each unit (activity >= threshold; `.` = no, "
            "`?` = joint never excited).", ""]
    n = ds.robot.n_joints
    crow = [[r.name] + ["?" if not np.isfinite(a) else ("x" if a >= 1 else ".") for a in content.activity[i]]
            for i, r in enumerate(content.rows)]
    out += _table(["unit"] + [f"j{j + 1}" for j in range(n)], crow)
    # free text (warnings, reasons, the description) reaches a terminal: every control character in
    # a line (ESC, BEL, CR, a newline inside a piece of text) is shown as an escape, never sent raw
    return "\n".join(printable(line) for line in out) + "\n"
