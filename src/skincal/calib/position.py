"""What a unit's data determine of its position, for every calibration method.

The accelerometer of a unit at ``p`` (link frame) on a link moving with origin acceleration ``a_o``,
angular velocity ``w`` and angular acceleration ``dw`` (all in the link frame) reads the specific force

    f = R^T (a_o + ([dw]x + [w]x^2) p - g)

so ``p`` shows only through the link's rotation: rests (``w = dw = 0``) hold none of it, a translation
none either, and a motion that barely turns the link little. :func:`judge_position` writes a rests-only
unit's position as undetermined; :func:`weak_position` names a position whose final std is large.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from skincal.data.result import POSITION_DETERMINED, UnitResult

POSITION_WEAK_STD_M = 0.1
"""A position whose std exceeds this on some link axis (m) is *weakly determined*: the unit's result
says so in a warning (the estimate and its std are kept). Beyond 0.1 m a proximity reading placed by
that pose lands anywhere on a link of a typical arm; the motion, not the estimator, is what is short
(a translation moves no lever arm: ``f = R^T (a_o + [dw]x p + [w]x^2 p - g)`` loses ``p`` when
``w = dw = 0``)."""


def judge_position(result: UnitResult, rests_only: bool, static_only: bool) -> UnitResult:
    """``result`` with what rests say of a position: nothing. From rests only (``rests_only``: no moving
    sample used) the accelerometer reads ``f = R^T (-g)``, which holds no ``p``: the position is **not
    determined**, whatever a fit's priors left, so it is written as ``null`` (``observable: false``, NaN
    std and covariance rows, ``position_determined: false``) with a warning; the rotation and link (from
    the rests) are kept. Otherwise ``result`` unchanged."""
    if not rests_only:
        return result
    said = "static poses only" if static_only else "no moving sample used: rests only"
    warning = f"position not determined ({said}): written as null; the rotation and link come from the rests"
    cov = result.pose_covariance
    if cov is not None:  # (x, y, z, rx, ry, rz): the position rows and columns undetermined
        cov = np.array(cov, dtype=float)
        cov[:3, :] = cov[:, :3] = np.nan
    # the fit's "unobservable: offset along ..." (positions only) says less than this and contradicts it
    kept = [w for w in result.warnings if not (w.startswith("unobservable: ") and _offsets_only(w))]
    return replace(
        result,
        observable=False,
        position_std_m=np.full(3, np.nan),
        pose_covariance=cov,
        warnings=(*kept, warning),
        extras={**result.extras, POSITION_DETERMINED: False},
    )


def _offsets_only(warning: str) -> bool:
    """Whether an ``unobservable: ...`` warning (:func:`skincal.calib.mle.account.describe_null`) names
    position offsets only (no rotation, no sensor parameter)."""
    parts = warning.removeprefix("unobservable: ").split(" (left at")[0].split(" and ")
    return all(part.startswith("offset along") for part in parts)


def is_weak(position_std_m: object) -> bool:
    """Whether a position std ``(3,)`` (m; NaN: undetermined) exceeds :data:`POSITION_WEAK_STD_M` on
    some axis: the rule :func:`weak_position` warns by."""
    if position_std_m is None:
        return False
    s = np.asarray(position_std_m, dtype=float)
    return bool(np.any(np.isfinite(s)) and np.nanmax(s) > POSITION_WEAK_STD_M)


def weak_position(result: UnitResult) -> UnitResult:
    """``result`` with a warning when its position std exceeds :data:`POSITION_WEAK_STD_M` on some link
    axis (*weakly determined*, naming the axis and the std: a linear move that barely turns the link, a
    rotation about the lever arm only); the estimate and its std are kept. Judged on the final std."""
    if not is_weak(result.position_std_m):
        return result
    s = np.asarray(result.position_std_m, dtype=float)
    axis = int(np.nanargmax(s))
    warning = (
        f"position weakly determined: std {1e3 * s[axis]:.0f} mm along the link's {'xyz'[axis]} axis (above "
        f"{1e3 * POSITION_WEAK_STD_M:.0f} mm): the motion barely turns this unit's link about the axes that show "
        "this lever arm (a translation shows none); a motion that rotates the link determines it"
    )
    return replace(result, warnings=(*result.warnings, warning))


