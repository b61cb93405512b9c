"""Method options are typed and checked in one place (:mod:`skincal.calib.options`), for every method."""

from __future__ import annotations

import pytest

from skincal.calib import METHODS
from skincal.calib.mle.method import MleOptions
from skincal.calib.options import INT_OPTION_MAX, NoOptions, parse_option_strings, parse_options
from skincal.calib.paper_opt import PaperOptions
from skincal.errors import ConfigError


def test_every_method_declares_a_frozen_options_dataclass():
    for name, spec in METHODS.items():
        assert spec.options is NoOptions or spec.options.__dataclass_params__.frozen, name
        parse_options(spec.options, {}, name)  # the defaults always parse


@pytest.mark.parametrize("method", sorted(METHODS))
def test_a_misspelt_option_is_refused_by_every_method(method):
    with pytest.raises(ConfigError, match=rf"unknown option\(s\) scael for method '{method}'"):
        parse_options(METHODS[method].options, {"scael": False}, method)


def test_cli_strings_become_typed_values():
    opts = parse_options(MleOptions, parse_option_strings(["scale=false", "gyro=Yes"]), "mle")
    assert opts.scale is False and opts.gyro is True and opts.time_offset is True
    paper = parse_options(PaperOptions, parse_option_strings(["maxeval_static=300", "xtol=1e-4"]), "om")
    assert paper.maxeval_static == 300 and isinstance(paper.maxeval_static, int) and paper.xtol == 1e-4


@pytest.mark.parametrize(
    ("cls", "options", "message"),
    [
        (MleOptions, {"scale": "maybe"}, "option scale expects true or false"),
        (MleOptions, {"scale": 0}, "option scale expects true or false"),  # not silently bool(0)
        (PaperOptions, {"maxeval_static": -1}, "option maxeval_static must be non-negative"),
        (PaperOptions, {"maxeval_static": 1.5}, "option maxeval_static expects an integer"),
        (PaperOptions, {"maxeval_static": True}, "option maxeval_static expects a number"),
        (PaperOptions, {"xtol": "nan"}, "option xtol must be finite"),
        (PaperOptions, {"xtol": "abc"}, "option xtol expects a number"),
    ],
)
def test_mistyped_values_are_refused(cls, options, message):
    with pytest.raises(ConfigError, match=message):
        parse_options(cls, options, "m")


@pytest.mark.parametrize("item", ["scale", "=1", ""])
def test_malformed_option_strings_are_refused(item):
    with pytest.raises(ConfigError, match="--option expects name=value"):
        parse_option_strings([item])


def test_an_option_given_twice_is_refused():
    with pytest.raises(ConfigError, match="given twice"):
        parse_option_strings(["scale=1", "scale=0"])


# an integer option beyond a C int is refused when parsed (it used to reach nlopt and fail every unit
# with an internal OverflowError)


@pytest.mark.adversarial
@pytest.mark.parametrize("value", ["99999999999999999999", str(INT_OPTION_MAX + 1), str(-INT_OPTION_MAX - 1)])
def test_an_integer_option_beyond_a_c_int_is_refused(value):
    with pytest.raises(ConfigError, match=rf"option maxeval_static must be at most {INT_OPTION_MAX} in magnitude"):
        parse_options(PaperOptions, parse_option_strings([f"maxeval_static={value}"]), "om")


def test_the_largest_c_int_is_taken():
    opts = parse_options(PaperOptions, parse_option_strings([f"maxeval_static={INT_OPTION_MAX}"]), "om")
    assert opts.maxeval_static == INT_OPTION_MAX


def test_the_examples_of_calibrate_help_are_accepted_by_the_methods_they_name():
    """Issue 27: ``calibrate --help`` gave ``--option maxeval_static=500`` as an example, which the default
    method refuses; each example now names its method, and that method takes it."""
    import inspect
    import re

    from skincal.cli.calibrate import calibrate as calibrate_cmd

    help_text = inspect.signature(calibrate_cmd).parameters["option"].default.help
    examples = re.findall(r"(\w+=\w+) \((?:with --method )?(\w+)\)", help_text.split("e.g.")[1])
    assert len(examples) == 2, help_text
    for item, method in examples:
        parse_options(METHODS[method].options, parse_option_strings([item]), method)
    with pytest.raises(ConfigError, match="unknown option"):
        parse_options(MleOptions, parse_option_strings(["maxeval_static=500"]), "mle")
