"""The calibration door refuses what it cannot honour: misspelt options, stamps on another clock;
and a segment table with no static segment does not mislead the default method."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib import calibrate, evaluate
from skincal.data.dataset import DYNAMIC, Segments
from skincal.errors import CalibrationError, ConfigError
from skincal.workflows.session import simulate_dataset


@pytest.fixture(scope="module")
def session():
    return simulate_dataset("panda", "random", 3, "realistic", "fast", seed=8)


def test_a_misspelt_option_is_refused(session):
    with pytest.raises(ConfigError, match=r"unknown option\(s\) scael for method 'mle'.*known: scale"):
        calibrate(session, "mle", scael=False)


def test_stamps_on_another_clock_are_named(session):
    imu = {k: replace(v, t=v.t + 1.7e9) for k, v in session.imu.items()}
    with pytest.raises(CalibrationError, match="do not overlap the joint stream"):
        calibrate(replace(session, imu=imu), "mle")


def test_segments_without_a_static_one_fall_back_to_the_joint_data(session):
    """A segmentation that found only dynamic segments (too short rests rejected) must not be taken
    as "the robot never rests": rests come from the joint data and the links stay right."""
    seg = session.segments
    dyn = np.asarray(seg.kind) == DYNAMIC
    only_dynamic = Segments(
        np.asarray(seg.t_start)[dyn], np.asarray(seg.t_end)[dyn], np.asarray(seg.kind)[dyn],
        np.asarray(seg.pose)[dyn], np.asarray(seg.joint)[dyn],
    )
    result = calibrate(replace(session, segments=only_dynamic), "mle")
    ev = evaluate(result, session)
    assert ev.links_correct == 3
    assert ev.mean_position_error_mm < 1.0
    assert all(u.extras["rest_source"] == "joint positions" for u in result.units.values())


def test_a_foreign_error_in_one_unit_is_that_units_failure(session, monkeypatch):
    """A method's unexpected exception (here a KeyError) fails only the unit it happened in, named
    with its type; the other units are calibrated as before."""
    from skincal.calib import api

    spec = api.METHODS["mle"]

    def flaky(problem):
        if problem.samples.unit == session.units[0]:
            raise KeyError("boom")
        return spec.run_unit(problem)

    monkeypatch.setitem(api.METHODS, "flaky", replace(spec, run_unit=flaky))
    result = calibrate(session, "flaky", workers=1)
    assert sorted(result.units) == sorted(session.units[1:])
    assert result.failed_units == {session.units[0]: "internal error (KeyError: 'boom')"}


@pytest.mark.parametrize("workers", [1, 2])
def test_a_foreign_error_in_every_unit_is_a_calibration_error_from_it(session, monkeypatch, workers):
    """Every unit failing with a foreign exception: one CalibrationError out of the door, raised from the
    first unit's, which is raised from the method's own exception where it ran in this process."""
    from skincal.calib import api

    def broken(problem):
        return {}[problem.samples.unit]  # a KeyError, a bug of the method

    monkeypatch.setitem(api.METHODS, "broken", replace(api.METHODS["mle"], run_unit=broken))
    with pytest.raises(CalibrationError, match=r"^no unit could be calibrated \(.*internal error \(KeyError: ") as info:
        calibrate(session, "broken", workers=workers)
    first = info.value.__cause__
    assert isinstance(first, CalibrationError) and str(first) == f"internal error (KeyError: '{session.units[0]}')"
    if workers == 1:  # a forked worker sends back the CalibrationError, not the traceback it came from
        assert isinstance(first.__cause__, KeyError)


def test_a_foreign_error_preparing_the_dataset_is_a_calibration_error_from_it(session, monkeypatch):
    from skincal.calib import api

    def prepare(dataset, interpolator):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setitem(api.METHODS, "broken", replace(api.METHODS["mle"], prepare=prepare))
    with pytest.raises(CalibrationError) as info:
        calibrate(session, "broken")
    assert str(info.value) == (
        "method 'broken', preparing the dataset: internal error (ZeroDivisionError: float division by zero)"
    )
    assert isinstance(info.value.__cause__, ZeroDivisionError)


def test_skincal_errors_in_a_method_pass_unwrapped(session, monkeypatch):
    """A usage or data error raised inside a method concerns every unit: it leaves the door as it is."""
    from skincal.calib import api

    def refuses(problem):
        raise ConfigError("bad option value")

    monkeypatch.setitem(api.METHODS, "refuses", replace(api.METHODS["mle"], run_unit=refuses))
    with pytest.raises(ConfigError, match="^bad option value$"):
        calibrate(session, "refuses", workers=1)
