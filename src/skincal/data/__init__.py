"""Datasets: the in-memory form, HDF5 files, validation, result files.

``read_dataset`` and ``write_dataset`` (:mod:`skincal.data.hdf5`) are loaded on first use, so a layer that
needs only the dataclasses or result files (``control``, ``perception``) does not load ``h5py``.
"""

from typing import TYPE_CHECKING, Any

from skincal.data.dataset import DYNAMIC, STATIC, Dataset, ImuStream, JointStates, Segments, TofStream
from skincal.data.result import (
    CalibrationResult,
    UnitResult,
    read_result,
    result_from_dict,
    result_to_dict,
    sha256_file,
    write_result,
)
from skincal.data.validate import validate_dataset

if TYPE_CHECKING:
    from skincal.data.hdf5 import read_dataset, write_dataset


def __getattr__(name: str) -> Any:
    """``read_dataset`` / ``write_dataset`` from :mod:`skincal.data.hdf5`, imported when first asked for."""
    if name in ("read_dataset", "write_dataset"):
        from skincal.data import hdf5

        return getattr(hdf5, name)
    raise AttributeError(f"module 'skincal.data' has no attribute {name!r}")

__all__ = [
    "DYNAMIC",
    "STATIC",
    "CalibrationResult",
    "Dataset",
    "ImuStream",
    "JointStates",
    "Segments",
    "TofStream",
    "UnitResult",
    "read_dataset",
    "read_result",
    "result_from_dict",
    "result_to_dict",
    "sha256_file",
    "validate_dataset",
    "write_dataset",
    "write_result",
]
