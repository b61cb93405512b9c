"""Does a calibration result belong to a dataset? The result records the SHA-256 of the dataset file
it was computed from (``dataset_sha256``) and the dataset's robot name; commands that put a result
next to a dataset (``evaluate``, ``report``, ``view``) check both before they compare or draw
anything: a result evaluated against another session's truth prints errors of centimetres that
mean nothing.
"""

from __future__ import annotations

from pathlib import Path

from skincal.data.dataset import Dataset
from skincal.data.names import printable
from skincal.data.result import CalibrationResult, sha256_file
from skincal.errors import DatasetError


def check_result_dataset(
    result: CalibrationResult,
    result_source: str | Path,
    dataset: Dataset,
    dataset_path: str | Path,
    *,
    allow_other: bool = False,
    same_file: bool = True,
    option: str = "--allow-other-dataset",
) -> tuple[str, list[str]]:
    """Check that ``result`` (read from ``result_source``) was computed from ``dataset`` (read from
    ``dataset_path``): the same robot name and, with ``same_file``, the same file digest. Returns the
    dataset file's SHA-256 (``""`` without ``same_file``) and the warnings to show.

    A mismatch raises a one-line :class:`DatasetError` naming both files and ``option`` (the way to
    accept it), unless ``allow_other``, when it becomes a warning. A result that records no digest is
    accepted with a warning (it cannot be checked). ``same_file=False`` checks the robot only (a
    dataset played back with a result, which may be another recording of the same robot).
    """
    warnings: list[str] = []

    def mismatch(problem: str) -> None:
        if not allow_other:
            raise DatasetError(f"{problem}; pass {option} to use them together anyway")
        warnings.append(f"{problem} (used anyway: {option})")

    res_name, ds_name = str(result_source), str(dataset_path)
    if result.robot != dataset.chain.name:
        mismatch(
            f"{res_name} is a result for robot '{printable(result.robot)}' but {ds_name} holds robot "
            f"'{printable(dataset.chain.name)}'"
        )
    if not same_file:
        return "", warnings
    digest = sha256_file(dataset_path)
    if not result.dataset_sha256:
        warnings.append(
            f"{res_name} does not record the SHA-256 of its dataset: cannot check that it comes from {ds_name}"
        )
    elif result.dataset_sha256.lower() != digest:
        mismatch(
            f"{res_name} was computed from another dataset than {ds_name} "
            f"(SHA-256 {result.dataset_sha256[:12]}... recorded, {digest[:12]}... found)"
        )
    return digest, warnings
