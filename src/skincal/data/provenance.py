"""Does a calibration result belong to a dataset? The result records the SHA-256 of the dataset file
it was computed from (``dataset_sha256``) and the dataset's robot name; commands that put a result
next to a dataset (``evaluate``, ``report``, ``view``) check both before they compare or draw
anything: a result evaluated against another session's truth prints errors of centimetres that
mean nothing.
"""

from __future__ import annotations

from pathlib import Path

from skincal.data.dataset import Dataset
from skincal.data.result import CalibrationResult, check_links, sha256_file
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.chain import SerialChain
from skincal.names import printable


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


def result_robot(
    result: CalibrationResult, robot: str | None = None, *, base_link: str | None = None, tip_link: str | None = None
) -> SerialChain | None:
    """The robot a result is drawn or exported on: ``robot`` (a preset, a ``.urdf`` with ``base_link``/``tip_link``,
    or a DH chain file), else the result's robot when it is a preset, else None. Refuses (one-line
    :class:`DatasetError`) a result with units on links the robot does not have."""
    from skincal.kinematics import get_robot
    from skincal.kinematics.presets import PRESETS

    if robot is None:
        if base_link is not None or tip_link is not None:
            raise ConfigError("--base-link and --tip-link apply to a URDF robot given with --robot")
        if result.robot not in PRESETS:
            return None
        chain = get_robot(result.robot)
        check_links(result, chain, "result")
        for name, unit in result.units.items():  # a URDF robot may bear a preset's name (example-robot-data's UR5)
            recorded, preset = unit.extras.get("link_name"), chain.link_name(unit.pose.link)
            if isinstance(recorded, str) and recorded != preset:
                raise ConfigError(
                    f"result: unit '{printable(name)}' is on link '{printable(recorded)}', which preset '{chain.name}' "
                    f"calls '{printable(preset)}': the result is of another robot of that name (a URDF?); give it with "
                    "--robot, or the dataset the result was computed from (export --dataset)"
                )
        return chain
    chain = get_robot(robot, base_link=base_link, tip_link=tip_link)
    check_links(result, chain, "result")
    return chain
