"""skincal.viz: seeing a calibration. Imports every other package; nothing imports it.

* :mod:`~skincal.viz.viewer`: browser 3D viewer (viser, the ``[viz]`` extra), loopback by default:
  :func:`~skincal.viz.viewer.start_viewer`.
* :mod:`~skincal.viz.report`: one self-contained HTML report, :func:`~skincal.viz.report.write_report`;
  :mod:`~skincal.viz.summary`: the markdown summary, :func:`~skincal.viz.summary.render_markdown`.
* :mod:`~skincal.viz.content`, :mod:`~skincal.viz.plots`: what the reports show (residuals from
  :mod:`skincal.calib.residuals`, coverage, errors) and the matplotlib figures.
* :mod:`~skincal.viz.model`: what the viewer draws, as numbers (no viser).
* :mod:`~skincal.viz.browser`: headless Chromium screenshots and console errors (tests, docs).

Submodules are imported on first use, so ``import skincal.viz`` needs neither viser nor matplotlib.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "start_viewer": "viewer",
    "Viewer": "viewer",
    "Recording": "model",
    "ObstacleTrack": "model",
    "write_report": "report",
    "render_html": "report",
    "render_markdown": "summary",
    "collect": "content",
    "ReportContent": "content",
    "unit_residuals": "residuals",
    "activity_matrix": "residuals",
    "capture_page": "browser",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"skincal.viz.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'skincal.viz' has no attribute {name!r}")
