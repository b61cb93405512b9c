"""The one assembly of the avoidance experiment (skincal.workflows.experiment): config checks and the
caller-owned cache of stopping models."""

from __future__ import annotations

import pytest

from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.sim.scenarios import get_scenario
from skincal.workflows import avoidance
from skincal.workflows.experiment import ExperimentConfig, StoppingModels, separation_for

pytest.importorskip("mujoco")


@pytest.mark.parametrize(("field", "value"), [("margin", "huge"), ("mode", "flying")])
def test_a_bad_margin_or_mode_is_a_one_line_config_error(field, value):
    chain = panda()
    sc = get_scenario("none", chain, 0.1)
    with pytest.raises(ConfigError, match=f"unknown {field} '{value}'"):
        ExperimentConfig(chain, sc, {}, {}, **{field: value})


def test_stopping_models_are_measured_once_per_cache_and_kept_nowhere_else():
    chain = panda()
    models = StoppingModels()
    first = models(chain)
    assert models(panda()) is first  # the same robot, measured once for this cache
    sc = get_scenario("hand", chain, 0.1)
    assert separation_for(chain, sc, stopping=models).stopping is first
    assert not any(isinstance(v, dict) and k.isupper() for k, v in vars(avoidance).items())  # no module cache
