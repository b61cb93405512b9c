"""Shared fixtures: fixed seeds and the preset chains."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.kinematics import panda, sawyer, ur5e


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(params=["panda", "sawyer", "ur5e"])
def chain(request):
    return {"panda": panda, "sawyer": sawyer, "ur5e": ur5e}[request.param]()
