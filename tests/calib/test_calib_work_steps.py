"""The progress of one calibration (issue 27, "silent long work": calibrate's bar sat at 0 % for 9 of 14 s,
then ran through the units; the split check's refits, most of the run, were not on it): the steps move with
the work, from the dataset's preparation through every unit of every check's part."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.calib.api import JOINT_RATE_FITS, WorkSteps
from skincal.calib.consistency import SPLITS
from skincal.workflows.session import simulate_dataset


@pytest.fixture(scope="module")
def small():
    """Panda, 2 random units, ``fast``, noise-free (simulated)."""
    return simulate_dataset("panda", "random", 2, "none", "fast", seed=3)


def test_the_steps_cover_preparation_units_and_the_split_checks_parts(small):
    calls, units_done = [], []
    calibrate(small, "mle", work=lambda d, t, s: calls.append((d, t, s)),
              progress=lambda _name: units_done.append(len(calls)))  # fmt: skip
    done = [c[0] for c in calls]
    total = {c[1] for c in calls}
    n = len(small.units)
    assert total == {1 + n + 2 * len(SPLITS) * n}  # planned once; this session's joint stream is not low-rate
    assert done == sorted(done) and done[0] == 0 and done[-1] == calls[-1][1]  # never back, ends full
    assert calls[0][2] == "preparing the dataset" and calls[1][:1] == (1,)  # the preparation is a step
    stages = [c[2] for c in calls]
    assert "checking independent parts of the recording" in stages
    # the units are a seventh of the plan: the bar does not sit at 100 % through the split check
    assert calls[units_done[-1]][0] == 1 + n
    assert sum(s == "checking independent parts of the recording" for s in stages) >= 2 * len(SPLITS) * n


def test_without_the_checks_the_units_fill_the_bar(small):
    calls = []
    calibrate(small, "mle", work=lambda d, t, s: calls.append((d, t)), consistency=False)
    n = len(small.units)
    assert [d for d, _ in calls] == [0, *range(1, n + 2), n + 1]  # preparation, each unit, the end
    assert {t for _, t in calls} == {1 + n}


def test_a_low_rate_joint_stream_plans_the_report_spacing_fits():
    opts = SimpleNamespace(consistency=True, joint_rate=True)
    low = SimpleNamespace(joints=SimpleNamespace(t=np.arange(0, 60, 0.05)))  # 20 Hz
    high = SimpleNamespace(joints=SimpleNamespace(t=np.arange(0, 60, 0.002)))  # 500 Hz
    n = 3
    base = 1 + n + 2 * len(SPLITS) * n
    assert WorkSteps.plan(None, n, opts, low).total == base + JOINT_RATE_FITS * n
    assert WorkSteps.plan(None, n, opts, high).total == base
    steps = WorkSteps.plan(None, n, SimpleNamespace(), high)
    assert steps.total == 1 + n
    for _ in range(10):  # more steps than planned never run past the end
        steps.advance("x")
    assert steps.done == steps.total
