"""Streaming calibration: :class:`OnlineCalibrator` follows samples as they arrive
(:mod:`~skincal.calib.online.estimator`, on the sufficient statistics of
:mod:`~skincal.calib.online.stats`)."""

from skincal.calib.online.estimator import OnlineCalibrator, OnlineOptions, UnitStatus, replay

__all__ = ["OnlineCalibrator", "OnlineOptions", "UnitStatus", "replay"]
