"""The data exports: YAML and JSON documents of the poses with their 6x6 covariance, and CSV."""

from __future__ import annotations

import csv
import io
import json
import math

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


def to_yaml(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """YAML of :func:`export_document`."""
    return yaml.safe_dump(export_document(result, frames, frame), sort_keys=False, default_flow_style=None)


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
