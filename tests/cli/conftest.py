"""Fixtures shared by the command-line tests."""

from __future__ import annotations

import pytest

from skincal.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small simulated session (Panda, 2 random units, ``fast``) and its ``mle`` result: ``(folder, data.h5,
    result.json)``, made once per test file."""
    root = tmp_path_factory.mktemp("cli")
    data = root / "data.h5"
    assert main(["simulate", "--robot", "panda", "--placement", "random", "--units", "2", "--protocol", "fast",
                 "--out", str(data)]) == 0
    result = root / "result.json"
    assert main(["calibrate", str(data), "--out", str(result)]) == 0
    return root, data, result
