"""The data exports: YAML and JSON documents of the poses with their 6x6 covariance, and CSV."""

from __future__ import annotations

import contextlib
import csv
import gc
import io
import json
import math
from collections.abc import Iterator

import yaml

from skincal.data.export.escape import csv_cell, plain_float
from skincal.data.export.frames import COVARIANCE_ORDER, UnitFrame, check_names
from skincal.data.result import CalibrationResult
from skincal.kinematics.transforms import FloatArray


def _std(values: FloatArray | None) -> list[float | None] | None:
    return None if values is None else [None if not math.isfinite(v) else float(v) for v in values]


def export_document(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> dict:
    """The YAML/JSON document: per unit parent, child, link, xyz (m), quaternion_wxyz, observable,
    the result's per-axis std, and the 6x6 covariance in the parent frame with its source."""
    check_names(result, frames)
    return {
        "format": "skincal-skin-frames",
        "version": 1,
        "robot": result.robot,
        "method": result.method,
        "frame": frame,
        "covariance_order": list(COVARIANCE_ORDER),
        "units": {
            f.unit: {
                "parent": f.parent,
                "child": f.child,
                "link": f.link,
                "xyz": [plain_float(v) for v in f.p_parent_child],
                "quaternion_wxyz": [plain_float(v) for v in f.quaternion_wxyz],
                "observable": f.observable,
                "position_std_m": _std(f.position_std_m),
                "rotation_std_deg": _std(f.rotation_std_deg),
                "covariance": [[plain_float(v) for v in row] for row in f.covariance],
                "covariance_source": f.covariance_source,
            }
            for f in frames
        },
    }


_SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
"""libyaml's emitter with PyYAML's safe representer when PyYAML was built with libyaml: the same text
as :func:`yaml.safe_dump` (tested byte for byte), about 4x faster; else the pure-Python one (also for
a text libyaml cannot encode: a lone surrogate)."""


@contextlib.contextmanager
def _no_cyclic_gc() -> Iterator[None]:
    """The cyclic garbage collector paused (restored on exit): a document of 10,000 units makes about a
    million representer nodes, none in a cycle, and the collector's passes over them cost more than the
    dump itself (10,000 units: 5.1 -> 2.4 CPU s with libyaml, simulated)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def to_yaml(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """YAML of :func:`export_document`: :func:`yaml.safe_dump`'s text (block mappings, flow lists of
    scalars, keys in document order) through :data:`_SAFE_DUMPER`."""
    doc = export_document(result, frames, frame)
    with _no_cyclic_gc():
        try:
            return yaml.dump(doc, Dumper=_SAFE_DUMPER, sort_keys=False, default_flow_style=None)
        except UnicodeEncodeError:  # a lone surrogate in free text (the method): libyaml cannot encode it,
            # PyYAML's own emitter escapes it ("\ud800")
            return yaml.dump(doc, Dumper=yaml.SafeDumper, sort_keys=False, default_flow_style=None)


def to_json(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """JSON of :func:`export_document`."""
    return json.dumps(export_document(result, frames, frame), indent=2, allow_nan=False) + "\n"


CSV_COLUMNS = ("unit", "parent", "child", "link", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz", "observable")


def to_csv(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """CSV with header :data:`CSV_COLUMNS` (quaternion columns ``qw, qx, qy, qz``); text cells are
    formula-neutralised (:func:`csv_cell`), numbers written as numbers."""
    check_names(result, frames)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for f in frames:
        writer.writerow(
            [
                csv_cell(f.unit),
                csv_cell(f.parent),
                csv_cell(f.child),
                int(f.link),
                *(float(v) for v in f.p_parent_child),
                *(float(v) for v in f.quaternion_wxyz),
                str(f.observable).lower(),
            ]
        )
    return buf.getvalue()
