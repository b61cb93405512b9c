"""The conditioned joint stream interpolated to any instants (:class:`JointInterpolator`;
:func:`joint_states_at`)."""

from __future__ import annotations

import threading

import numpy as np
from scipy.signal import savgol_coeffs

from skincal.calib.hermite import hermite
from skincal.calib.preprocess.conditioning import (
    DEFAULT_QDD_WINDOW_S,
    JointConditioning,
    condition_joint_stream,
    estimate_qdd,
    with_spline_error,
)
from skincal.data.dataset import JointStates
from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray


class JointInterpolator:
    """Joint position, velocity and acceleration at arbitrary instants, built once per dataset.

    ``q`` is a cubic Hermite interpolant of the reported ``(q, qd)``; ``qd`` a cubic Hermite
    interpolant of ``(qd, qdd)``; ``qdd`` linear in the estimated (or, when ``use_dataset_qdd`` and
    the dataset has it, the reported) accelerations. Instants outside the joint stream are an error.

    Real joint streams are conditioned first (:func:`condition_joint_stream`): stamps that jitter
    around a regular grid are put back on it when that makes the positions smoother, and when the
    encoder positions are less noisy than the reported velocities (the usual case: an encoder
    resolves micro-radians, a velocity estimate carries mrad/s of noise), ``qd`` and ``qdd`` are
    the Savitzky-Golay first and second derivatives of the positions instead of the velocities'.
    ``conditioning`` says what was done; ``outputs_from`` (s): only the instants from then on are asked for
    (the stream before it decides the conditioning, :func:`condition_joint_stream`).
    """

    def __init__(
        self, joints: JointStates, *, use_dataset_qdd: bool = False, qdd_window_s: float = DEFAULT_QDD_WINDOW_S,
        outputs_from: float | None = None,
    ) -> None:
        if np.asarray(joints.t).shape[0] < 7:
            raise CalibrationError(
                f"joint stream has {np.asarray(joints.t).shape[0]} samples; at least 7 are needed to estimate qdd"
            )
        use_reported = use_dataset_qdd and joints.qdd is not None
        self._reported = joints
        joints, self.conditioning = (joints, JointConditioning()) if use_reported else condition_joint_stream(
            joints, qdd_window_s, outputs_from
        )
        tj = np.asarray(joints.t, dtype=float)
        self.t_start, self.t_end = float(tj[0]), float(tj[-1])
        self._tj, self._q, self._qd_j = tj, np.asarray(joints.q, dtype=float), np.asarray(joints.qd, dtype=float)
        self._joints, self._window_s = joints, qdd_window_s
        self._qdd_full: FloatArray | None = None
        self._sg: FloatArray | None = None
        self._qdd_fit: FloatArray | None = None
        self._lock = threading.Lock()
        dt = float(np.median(np.diff(tj)))
        if use_reported or joints.qdd is not None and self.conditioning.source in ("positions", "spline"):
            self._t_acc, self._qd, self._qdd_full = tj, self._qd_j, np.asarray(joints.qdd, dtype=float)
        elif np.max(np.abs(np.diff(tj) - dt)) > 0.01 * dt:  # uneven: resample, estimate everything now
            self._t_acc, self._qd, self._qdd_full = estimate_qdd(joints, qdd_window_s)
        else:
            self._t_acc, self._qd = tj, self._qd_j
            window = min(max(5, int(round(qdd_window_s / dt)) | 1), tj.shape[0] - (1 - tj.shape[0] % 2))
            self._sg = savgol_coeffs(window, 3, deriv=1, delta=dt, use="dot")
        self._uniform = self._t_acc is tj

    @property
    def _qdd(self) -> FloatArray:
        """Full-rate acceleration estimate on the uniform grid (computed once, on first use)."""
        if self._qdd_full is None:
            self._qdd_full = estimate_qdd(self._joints, self._window_s)[2]
        return self._qdd_full

    def warm(self) -> None:
        """Compute the lazily built acceleration estimate now (e.g. before forking workers that share it)."""
        self._qdd_at(np.zeros(1, dtype=np.intp))

    def _qdd_at(self, i: np.ndarray) -> FloatArray:
        """Acceleration estimate at grid indices ``i`` only (the same local fit as :attr:`_qdd`)."""
        if self._qdd_full is not None or self._sg is None:
            return self._qdd[i]
        half = self._sg.size // 2
        with self._lock:  # once per dataset, shared by the units (and their worker threads)
            if self._qdd_fit is None:
                # the local fit at every full window's centre (samples half..N-1-half): a valid-mode
                # convolution per joint, ~0.1 s for ten minutes at 1 kHz
                kernel = self._sg[::-1]
                self._qdd_fit = np.stack([np.convolve(qd, kernel, mode="valid") for qd in self._qd.T], axis=1)
        return self._qdd_fit[np.clip(i, half, self._qd.shape[0] - 1 - half) - half]

    def __call__(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)`` at instants ``t`` (M,), each ``(M, n)``."""
        t = np.asarray(t, dtype=float)
        if t.size and (t.min() < self.t_start - 1e-9 or t.max() > self.t_end + 1e-9):
            raise CalibrationError(
                f"instants {t.min():.3f}..{t.max():.3f} s fall outside the joint stream "
                f"{self.t_start:.3f}..{self.t_end:.3f} s"
            )
        q = hermite(self._tj, self._q, self._qd_j, t)[0]
        qd, qdd, _ = hermite(self._t_acc, self._qd, self._qdd, t)  # qdd: linear in the accelerations
        return q, qd, qdd


    def reliable(self, t: FloatArray) -> np.ndarray:
        """``(M,)`` False at instants whose acceleration estimate is unreliable (near a kink of the
        joint stream, :func:`condition_joint_stream`); True everywhere for reported accelerations."""
        bad = self.conditioning.unreliable
        t = np.asarray(t, dtype=float)
        if bad is None:
            return np.ones(t.shape, dtype=bool)
        i = np.clip(np.searchsorted(self._tj, t), 0, self._tj.size - 1)
        return ~(bad[i] | bad[np.maximum(i - 1, 0)])

    def qdd_variance(self, t: FloatArray) -> FloatArray | None:
        """``(M, n)`` variance of the joint accelerations at instants ``t`` (M,) (linear in the
        conditioned stream's :attr:`JointConditioning.qdd_variance`), rad^2/s^4; ``None`` when the
        conditioning did not estimate one (a stream that resolves its motion)."""
        if self.conditioning.source == "spline" and self.conditioning.qdd_variance is None:
            with self._lock:  # the error estimate's fits, once, on first use
                if self.conditioning.qdd_variance is None:
                    self.conditioning = with_spline_error(self.conditioning, self._reported, self._joints)
        var = self.conditioning.qdd_variance
        if var is None:
            return None
        t = np.asarray(t, dtype=float)
        return np.column_stack([np.interp(t, self._tj, c) for c in var.T])

    @property
    def dt(self) -> float:
        """Period of the uniform joint grid, s."""
        return float(self._t_acc[1] - self._t_acc[0])

    def nearest(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)`` of the joint sample nearest to each instant (no interpolation).

        Good enough to tell whether the robot is at rest and where; exact kinematics need
        :meth:`__call__`. Falls back to interpolation for unevenly sampled joint streams.
        """
        if not self._uniform:
            return self(t)
        g = self._t_acc
        i = np.clip(np.rint((np.asarray(t, dtype=float) - g[0]) / self.dt).astype(np.intp), 0, g.size - 1)
        return self._q[i], self._qd_j[i], self._qdd_at(i)

    def on_grid(self, step: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Every ``step``-th sample of the (uniform) joint grid: ``(t, q, qd, qdd)``."""
        t = self._t_acc[::step]
        if self._uniform:
            return t, self._q[::step], self._qd_j[::step], self._qdd_at(np.arange(0, t.size * step, step))
        return (t, *self(t))


def joint_states_at(
    joints: JointStates,
    t: FloatArray,
    *,
    use_dataset_qdd: bool = False,
    qdd_window_s: float = DEFAULT_QDD_WINDOW_S,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One-off :class:`JointInterpolator` evaluation at instants ``t`` (M,)."""
    return JointInterpolator(joints, use_dataset_qdd=use_dataset_qdd, qdd_window_s=qdd_window_s)(t)
