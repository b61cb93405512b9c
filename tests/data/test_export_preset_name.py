"""A result of a URDF robot that bears a preset's name (example-robot-data's UR5 is ``<robot name="ur5">``)
is not exported onto the preset's DH frames without ``--robot`` (found by the new-user review: the
units landed on ``ur5_dh_link2..`` with poses measured in ``upper_arm_link..``, silently wrong)."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.data.export import export_result
from skincal.data.result import CalibrationResult, UnitResult
from skincal.errors import ConfigError
from skincal.skin.pose import SkinUnitPose

from registry_robots import registry_urdf

UR5_URDF_LINKS = {2: "upper_arm_link", 3: "forearm_link"}


def _result(link_names: dict[int, str]) -> CalibrationResult:
    units = {
        f"su{link}": UnitResult(
            pose=SkinUnitPose.from_quaternion(link, np.array([0.05, 0.0, 0.06]), np.array([1.0, 0.0, 0.0, 0.0])),
            extras={"link_name": name},
        )
        for link, name in link_names.items()
    }
    return CalibrationResult(method="mle", robot="ur5", dataset_sha256="", runtime_s=0.1, units=units)


@pytest.mark.parametrize("fmt", ["urdf", "yaml", "tf"])
def test_a_urdf_result_named_like_a_preset_needs_its_robot(tmp_path, fmt):
    out = tmp_path / f"skin.{fmt}"
    with pytest.raises(ConfigError, match="is on link 'upper_arm_link', which preset 'ur5' calls 'link2'.*--robot"):
        export_result(_result(UR5_URDF_LINKS), fmt, out)
    assert not out.exists()


def test_the_same_result_exports_onto_its_urdf(tmp_path):
    frames = export_result(_result(UR5_URDF_LINKS), "yaml", tmp_path / "skin.yaml", robot=str(registry_urdf("ur5")))
    assert sorted(f.parent for f in frames) == ["forearm_link", "upper_arm_link"]


def test_a_preset_result_still_exports_without_robot(tmp_path):
    frames = export_result(_result({2: "link2", 3: "link3"}), "yaml", tmp_path / "skin.yaml")
    assert sorted(f.parent for f in frames) == ["ur5_dh_link2", "ur5_dh_link3"]


def test_a_urdf_result_onto_another_robots_urdf_is_a_one_line_refusal(tmp_path):
    """A Z1 result (link names of the Z1's URDF) onto the UR5's URDF: refused naming both robots and the
    links, never exported (it used to end in an internal error: the message's own variable shadowed
    the escaping function it called)."""
    result = CalibrationResult(
        method="mle", robot="z1", dataset_sha256="", runtime_s=0.1,
        units={"su1": UnitResult(pose=SkinUnitPose.from_quaternion(2, np.array([0.05, 0.0, 0.06]),
                                                                     np.array([1.0, 0.0, 0.0, 0.0])),
                                 extras={"link_name": "link02"})},
    )  # fmt: skip
    out = tmp_path / "skin.urdf"
    with pytest.raises(ConfigError, match=r"the result is for robot 'z1' \(units on link02\), not for robot"):
        export_result(result, "urdf", out, robot=str(registry_urdf("ur5")))
    assert not out.exists()
