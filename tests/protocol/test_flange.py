"""Flange tasks: the circle and the pick-and-place cycle (skincal.protocol.flange)."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.protocol.flange import Circle, PickPlace, make_task


def test_pick_place_cycle_is_smooth_periodic_and_its_velocity_is_the_derivative():
    task = PickPlace.around([0.5, 0.0, 0.5])
    t = np.linspace(0, 2 * task.period, 20001)
    x, v = task.at(t)
    np.testing.assert_allclose(x[0], [0.5, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(task.at(task.period)[0][0], [0.5, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(np.gradient(x, t, axis=0)[1:-1], v[1:-1], atol=2e-3)
    assert np.abs(np.diff(x, axis=0)).max() < 1e-3  # continuous
    assert x[:, 2].min() == pytest.approx(0.4) and x[:, 1].min() == pytest.approx(-0.15)
    assert np.linalg.norm(v, axis=1).max() == pytest.approx(0.25, rel=1e-3)


def test_circle_starts_at_its_point_and_its_velocity_is_the_derivative():
    task = Circle.through([0.5, 0.0, 0.5], radius=0.1, period=5.0)
    t = np.linspace(0, 5.0, 50001)
    x, v = task.at(t)
    np.testing.assert_allclose(x[0], [0.5, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(np.gradient(x, t, axis=0)[1:-1], v[1:-1], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 2 * np.pi * 0.1 / 5.0, rtol=1e-12)


@pytest.mark.parametrize("kind", ["circle", "pick-place"])
def test_make_task_starts_at_the_given_point(kind):
    np.testing.assert_allclose(make_task(kind, [0.4, 0.1, 0.3]).at(0.0)[0][0], [0.4, 0.1, 0.3], atol=1e-12)


def test_unknown_task_is_a_one_line_config_error():
    with pytest.raises(ConfigError, match="unknown task 'square'"):
        make_task("square", [0, 0, 0])
