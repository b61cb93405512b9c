"""An integer option beyond a C int (``--option maxeval_static=99999999999999999999``) is refused
when parsed; it used to reach nlopt and fail every unit with an internal OverflowError."""

from __future__ import annotations

import pytest

from skincal.calib.options import INT_OPTION_MAX, parse_option_strings, parse_options
from skincal.calib.paper_opt import PaperOptions
from skincal.errors import ConfigError


@pytest.mark.adversarial
@pytest.mark.parametrize("value", ["99999999999999999999", str(INT_OPTION_MAX + 1), str(-INT_OPTION_MAX - 1)])
def test_an_integer_option_beyond_a_c_int_is_refused(value):
    with pytest.raises(ConfigError, match=rf"option maxeval_static must be at most {INT_OPTION_MAX} in magnitude"):
        parse_options(PaperOptions, parse_option_strings([f"maxeval_static={value}"]), "om")


def test_the_largest_c_int_is_taken():
    opts = parse_options(PaperOptions, parse_option_strings([f"maxeval_static={INT_OPTION_MAX}"]), "om")
    assert opts.maxeval_static == INT_OPTION_MAX
