"""Datasets: the in-memory form, HDF5 files, validation, result files."""

from skincal.data.dataset import DYNAMIC, STATIC, Dataset, ImuStream, JointStates, Segments, TofStream

__all__ = ["DYNAMIC", "STATIC", "Dataset", "ImuStream", "JointStates", "Segments", "TofStream"]
