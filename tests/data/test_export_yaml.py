"""``export -f yaml`` through libyaml (issue 27, "no size bounds": a 10,000-unit result took 17.6 s, over
60 s before; the speed target is in ``benchmarks/bench_export.py``): the same text as
:func:`yaml.safe_dump` byte for byte, crafted names included, without PyYAML's pure-Python emitter."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import yaml
from test_export_names import METHODS, ROBOT, UNIT_NAMES

from skincal.data.export import documents, export_text
from skincal.data.result import CalibrationResult, UnitResult
from skincal.skin.pose import SkinUnitPose

pytestmark = pytest.mark.adversarial


def _result(names, method: str = "mle", robot: str = "panda") -> CalibrationResult:
    """Units on the Panda's links with random poses; every third without std, every fifth with a NaN."""
    rng = np.random.default_rng(7)
    units = {}
    for k, name in enumerate(names):
        q = rng.normal(size=4)
        pose = SkinUnitPose.from_quaternion(k % 7 + 1, rng.uniform(-0.1, 0.1, 3), q / np.linalg.norm(q))
        std = None if k % 3 == 0 else rng.uniform(1e-6, 1e-2, 3)
        if std is not None and k % 5 == 0:
            std[1] = np.nan
        units[name] = UnitResult(pose=pose, observable=k % 2 == 1, position_std_m=std, rotation_std_deg=std)
    return CalibrationResult(method=method, robot=robot, dataset_sha256="", runtime_s=0.1, units=units)


def _panda_map(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text("links: {" + ", ".join(f"{i}: panda_link{i}" for i in range(1, 8)) + "}\n")
    return path


@pytest.mark.parametrize("method", METHODS, ids=range(len(METHODS)))
def test_yaml_is_safe_dumps_text_byte_for_byte(tmp_path, method):
    result = _result(UNIT_NAMES + [f"su{k}" for k in range(40)], method=method, robot=ROBOT)
    text, frames = export_text(result, "yaml", link_map=_panda_map(tmp_path), prefix="=-")
    doc = documents.export_document(result, frames)
    assert text == yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    assert yaml.safe_load(text) == doc  # and it reads back as the document (names unchanged)


@pytest.mark.skipif(not hasattr(yaml, "CSafeDumper"), reason="PyYAML built without libyaml")
def test_yaml_does_not_use_the_pure_python_emitter(tmp_path, monkeypatch):
    """The pure-Python emitter was 2/3 of the time of a 10,000-unit export."""

    def refuse(*args, **kwargs):
        raise AssertionError("PyYAML's pure-Python emitter used")

    link_map = _panda_map(tmp_path)
    monkeypatch.setattr(yaml.emitter.Emitter, "emit", refuse)
    text, _ = export_text(_result(["su1", "su2"]), "yaml", link_map=link_map)
    assert text.startswith("format: skincal-skin-frames\n")


def test_the_garbage_collector_is_restored_after_a_dump(tmp_path, monkeypatch):
    assert gc.isenabled()
    export_text(_result(["su1"]), "yaml", link_map=_panda_map(tmp_path))
    assert gc.isenabled()

    def broken(*args, **kwargs):
        raise RuntimeError("emitter failed")

    monkeypatch.setattr(documents.yaml, "dump", broken)
    with pytest.raises(RuntimeError):
        export_text(_result(["su1"]), "yaml", link_map=_panda_map(tmp_path))
    assert gc.isenabled()
    gc.disable()
    try:  # a caller's paused collector stays paused
        monkeypatch.undo()
        export_text(_result(["su1"]), "yaml", link_map=_panda_map(tmp_path))
        assert not gc.isenabled()
    finally:
        gc.enable()
