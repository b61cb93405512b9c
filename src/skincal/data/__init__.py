"""Datasets: the in-memory form, HDF5 files, validation, result files."""

from skincal.data.dataset import DYNAMIC, STATIC, Dataset, ImuStream, JointStates, Segments, TofStream
from skincal.data.hdf5 import read_dataset, write_dataset
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
