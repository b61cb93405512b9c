"""Streaming calibration: :class:`OnlineCalibrator` follows samples as they arrive
(:mod:`~skincal.calib.online.estimator`, on the sufficient statistics of
:mod:`~skincal.calib.online.stats`); :func:`replay` feeds it a recorded dataset
(:mod:`~skincal.calib.online.feed`)."""

from skincal.calib.online.estimator import OnlineCalibrator, OnlineOptions, UnitStatus
from skincal.calib.online.feed import replay

__all__ = ["OnlineCalibrator", "OnlineOptions", "UnitStatus", "replay"]
