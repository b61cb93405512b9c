"""The hostile inputs every table in this folder refers to, built once per session (real files: a simulated
HDF5 dataset, its result, a URDF, a FIFO, a decompression bomb and results whose figures overflow)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from skincal.cli import main


@pytest.fixture(scope="session")
def hostile(tmp_path_factory) -> dict[str, Path]:
    """Named input files (``{name}`` in a case's arguments). Every one of them is hashed before and after each
    case: an input is never changed, whatever the case asks for."""
    import h5py

    root = tmp_path_factory.mktemp("hostile")
    data = root / "data.h5"
    assert main(f"simulate --robot panda --placement random --units 2 --protocol fast --seed 4 -o {data}".split()) == 0
    result = root / "result.json"
    assert main(["calibrate", str(data), "-o", str(result), "--workers", "1"]) == 0
    files = {"data": data, "result": result}

    links = root / "links.yaml"
    links.write_text("su1: 3\nsu2: 5\n")
    files["links"] = links

    from registry_robots import registry_urdf

    urdf = root / "arm.urdf"  # the maker's Panda URDF of example-robot-data, copied: a test never edits a package
    shutil.copyfile(registry_urdf("panda"), urdf)
    files["urdf"] = urdf
    text = urdf.read_text()
    start = text.index('<link name="panda_link3"')
    end = text.index("</link>", start) + len("</link>")
    files["dup_link_urdf"] = root / "dup.urdf"  # panda_link3 twice
    files["dup_link_urdf"].write_text(text[:end] + "\n  " + text[start:end] + text[end:])

    doc = json.loads(result.read_text())
    unit = next(iter(doc["units"]))
    overflow = json.loads(json.dumps(doc))
    overflow["units"][unit]["pose_covariance"] = (np.full((6, 6), 1e308)).tolist()
    files["overflow_result"] = root / "overflow.json"
    files["overflow_result"].write_text(json.dumps(overflow))

    bomb = root / "bomb.h5"  # declares 2**28 x 3 float64 (6 GiB) of accelerometer readings, stores none
    shutil.copyfile(data, bomb)
    with h5py.File(bomb, "r+") as f:
        group = next(iter(f["imu"].values()))
        del group["accel"]
        group.create_dataset("accel", shape=(2**28, 3), dtype="f8", chunks=(2**16, 3), compression="gzip")
    files["bomb"] = bomb

    milli_g = root / "milli_g.h5"  # accelerometers in milli-g declared as m/s^2
    shutil.copyfile(data, milli_g)
    with h5py.File(milli_g, "r+") as f:
        for group in f["imu"].values():
            group["accel"][...] = group["accel"][...] * (1000.0 / 9.80665)
    files["milli_g"] = milli_g

    (root / "empty").write_bytes(b"")
    files["empty"] = root / "empty"
    if os.name == "posix":
        for name in ("fifo", "fifo.h5", "fifo.json", "fifo.html", "fifo.png"):
            os.mkfifo(root / name)
            files[name.replace(".", "_")] = root / name
    return files
