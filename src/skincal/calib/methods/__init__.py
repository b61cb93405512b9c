"""The registered calibration methods, one module per name in :data:`skincal.calib.api.METHODS`.

Each module holds one method's entry point and its ``register`` call, nothing else:
``mle`` (default; the engine is the package :mod:`skincal.calib.mle`), ``om`` and ``om_joint``
(the paper's method and its unseparated variant), ``mmm`` and ``mm`` (the paper's baselines; the
paper's model, optimiser and result wrapping are shared in :mod:`skincal.calib.paper_model` and
:mod:`skincal.calib.paper_opt`). A name with a hyphen lives in the module with an underscore
(``om-joint`` in ``om_joint``). Importing this package registers them all.
"""

from skincal.calib.methods import mle, mm, mmm, om, om_joint

__all__ = ["mle", "mm", "mmm", "om", "om_joint"]
