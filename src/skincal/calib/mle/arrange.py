"""One unit's samples arranged for ``mle``'s fit on one candidate link: rest runs averaged, moving
samples kept one by one (the link signals they are evaluated with are :mod:`skincal.calib.signals`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.mle.solver import Rows
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.rest import JointRest, RestRuns, unit_rest_runs
from skincal.calib.signals import link_signals
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray


@dataclass(frozen=True)
class UnitData:
    """One unit's data arranged for the maximum-likelihood fit on link ``link``.

    Rest runs are averaged into ``rows.static_*`` (one row per run, weight = sample count); the
    moving samples are kept one by one with their stamps, to be re-evaluated at shifted instants.

    Attributes:
        link: the link assumed.
        rows: the solver's measurements (stamps relative to ``t_c``).
        t_c: reference instant of the clock model (middle of the unit's samples), s.
        static_q: ``(S, n)`` joint angles of each rest run.
        rest: the rest runs and the IMU cross-check (:class:`~skincal.calib.rest.RestRuns`).
    """

    link: int
    rows: Rows
    t_c: float
    static_q: FloatArray
    rest: RestRuns

    @property
    def moving_t(self) -> FloatArray:
        """``(M,)`` absolute stamps of the moving samples, s."""
        return self.rows.moving_t + self.t_c

    @property
    def n_static(self) -> int:
        return len(self.rows.static_u)


def arrange_unit_data(
    chain: SerialChain,
    link: int,
    t: FloatArray,
    accel: FloatArray,
    gyro: FloatArray | None,
    joint_rest: JointRest,
    interpolator: JointInterpolator,
    gravity: FloatArray,
) -> UnitData:
    """Split a unit's samples ``t`` ``(M,)`` (already shifted to the joint clock), ``accel``/``gyro``
    ``(M, 3)`` into averaged rest runs and individual moving samples.

    A sample is moving when some joint ``<= link`` moves at its instant (:mod:`skincal.calib.rest`);
    moving samples where the joint accelerations cannot be estimated (at a step of the motion's
    acceleration, :meth:`JointInterpolator.reliable`) and rest runs the unit's IMU contradicts are
    not used.
    """
    rest_mask = joint_rest.unit_rest(t, link)
    runs = unit_rest_runs(rest_mask, t, accel, gyro)
    t_c = 0.5 * (float(t[0]) + float(t[-1])) if t.size else 0.0
    S = len(runs.bounds)
    f_s, g_s, q_s = np.zeros((S, 3)), np.zeros((S, 3)), np.zeros((S, chain.n_joints))
    w_s, tm_s = np.zeros(S), np.zeros(S)
    for k, (a, b) in enumerate(runs.bounds):  # np.mean per run: its pairwise sums (a rests-only fit's null
        f_s[k] = accel[a:b].mean(axis=0)  # space is decided at round-off, so keep this arithmetic)
        if gyro is not None:  # the readings with a value (NaN at the gyroscope's rail; none: a NaN row)
            run = gyro[a:b]
            ok = np.all(np.isfinite(run), axis=1)
            g_s[k] = run.mean(axis=0) if ok.all() else run[ok].mean(axis=0) if ok.any() else np.nan
        w_s[k] = b - a
        tm_s[k] = 0.5 * (t[a] + t[b - 1])
        q_s[k] = interpolator.nearest(t[a:b])[0].mean(axis=0)
    zero = np.zeros_like(q_s)
    static_u = link_signals(chain, link, q_s, zero, zero, gravity).u if S else np.zeros((0, 3))
    moving = ~rest_mask & interpolator.reliable(t)
    for t0, t1 in runs.dropped:
        moving &= ~((t >= t0) & (t <= t1))
    rows = Rows(
        static_u=static_u,
        static_f=f_s,
        static_g=None if gyro is None else g_s,
        static_weight=w_s,
        static_t=tm_s - t_c,
        moving_t=t[moving] - t_c,
        moving_f=accel[moving],
        moving_g=None if gyro is None else gyro[moving],
    )
    return UnitData(link, rows, t_c, q_s, runs)
