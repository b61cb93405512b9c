"""Shared fixtures: fixed seeds and the preset chains; the test processes' SIGINT as a terminal's."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from skincal.kinematics import panda, sawyer, ur5e


def pytest_configure(config: pytest.Config) -> None:
    """A pytest started in the background of a non-interactive shell (``cmd &``, some CI runners) inherits
    SIGINT ignored, and every command a test starts would too: Ctrl-C and ``send_signal(SIGINT)`` would do
    nothing and the tests of interruption fail. Restore Python's handler here (in every xdist worker too):
    an exec'ed child then starts with SIGINT at its default, as when run from a terminal."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(params=["panda", "sawyer", "ur5e"])
def chain(request):
    return {"panda": panda, "sawyer": sawyer, "ur5e": ur5e}[request.param]()
