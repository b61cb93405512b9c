"""The default calibrator ``mle`` (see :mod:`skincal.calib.mle.method`)."""

from skincal.calib.mle.discovery import choose_link
from skincal.calib.mle.method import run_unit

__all__ = ["choose_link", "run_unit"]
