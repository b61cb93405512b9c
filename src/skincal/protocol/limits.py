"""Joint-limit checks of a protocol and static-pose sampling with room for every excitation.

Position limits are applied shrunk by ``config.limit_margin`` (rad); velocity limits are the
chain's symmetric ``velocity_limit`` (rad/s). A chain without position limits is sampled in
``[-pi, pi]`` and not position-checked. The chains carry no acceleration limits, so none are checked.
"""

from __future__ import annotations

import numpy as np

from skincal.errors import ProtocolError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.motion import excitation_envelope

_TOL = 1e-9


def position_bounds(chain: SerialChain) -> tuple[FloatArray, FloatArray]:
    """``(lower, upper)`` position limits ``(n,)`` in rad; ``[-pi, pi]`` where the chain has none."""
    n = chain.n_joints
    if chain.joint_lower is None or chain.joint_upper is None:
        return np.full(n, -np.pi), np.full(n, np.pi)
    return np.array(chain.joint_lower), np.array(chain.joint_upper)


def check_amplitudes(chain: SerialChain, config: ProtocolConfig) -> None:
    """Raise :class:`ProtocolError` if an excited joint's amplitude ``A_j`` exceeds its velocity limit."""
    if chain.velocity_limit is None:
        return
    A = config.amplitude_per_joint(chain.n_joints)
    for j in config.joints_to_excite(chain.n_joints):
        if A[j] > chain.velocity_limit[j] + _TOL:
            raise ProtocolError(
                f"joint {j + 1}: excitation amplitude {A[j]:.3f} rad/s exceeds the velocity limit "
                f"{chain.velocity_limit[j]:.3f} rad/s (protocol '{config.name}')"
            )


VELOCITY_CAP_FRACTION = 0.95
""":func:`fit_to_limits` caps excitation amplitudes at this fraction of each joint's velocity limit."""


def fit_to_limits(
    chain: SerialChain, config: ProtocolConfig, fraction: float = VELOCITY_CAP_FRACTION
) -> ProtocolConfig:
    """``config`` for ``chain``: robot-relative settings resolved (:meth:`ProtocolConfig.for_chain`) and
    every amplitude above ``fraction`` of its joint's velocity limit capped there (the paper's 2 rad/s
    exceeds the Sawyer's joint 1-2 limits). Unchanged for a chain without velocity limits."""
    from dataclasses import replace

    config = config.for_chain(chain)
    if chain.velocity_limit is None:
        return config
    amp = np.minimum(config.amplitude_per_joint(chain.n_joints), fraction * np.asarray(chain.velocity_limit))
    return replace(config, amplitude=tuple(float(a) for a in amp))


def excursion_envelopes(chain: SerialChain, config: ProtocolConfig) -> tuple[FloatArray, FloatArray]:
    """Per joint, the lowest and highest offset from the pose reached while it is excited, ``(n,)`` rad.

    Joints that are not excited have ``(0, 0)``. See :func:`skincal.protocol.motion.excitation_envelope`.
    """
    n = chain.n_joints
    A, f = config.amplitude_per_joint(n), config.frequency_per_joint(n)
    lo, hi = np.zeros(n), np.zeros(n)
    for j in config.joints_to_excite(n):
        lo[j], hi[j] = excitation_envelope(A[j], f[j], config.excite_duration, j)
    return lo, hi


def pose_box(chain: SerialChain, config: ProtocolConfig) -> tuple[FloatArray, FloatArray]:
    """Per joint interval ``(n,)`` of static poses whose excitation stays within the margin-shrunk limits.

    ``q0 in [lower + margin - lo_j, upper - margin - hi_j]`` with ``(lo_j, hi_j)`` from
    :func:`excursion_envelopes`. Raises :class:`ProtocolError` naming a joint whose excursion does
    not fit at all.
    """
    lower, upper = position_bounds(chain)
    lo, hi = excursion_envelopes(chain, config)
    m = config.limit_margin
    box_lo, box_hi = lower + m - lo, upper - m - hi
    for j in range(chain.n_joints):
        if box_lo[j] > box_hi[j]:
            raise ProtocolError(
                f"joint {j + 1}: its excitation sweeps {hi[j] - lo[j]:.3f} rad but only "
                f"{upper[j] - lower[j] - 2 * m:.3f} rad lie within its limits [{lower[j]:.4f}, {upper[j]:.4f}] "
                f"with margin {m} rad (protocol '{config.name}': lower the amplitude or raise the frequency)"
            )
    return box_lo, box_hi


def sample_static_poses(
    chain: SerialChain, n_poses: int, rng: np.random.Generator, config: ProtocolConfig
) -> FloatArray:
    """``n_poses`` static poses ``(P, n)`` in rad, uniform in :func:`pose_box` (seeded by ``rng``).

    Every pose leaves room for the full excitation of every excited joint, ``q0 + A / (2 pi f)
    (1 - cos 2 pi f t)`` and its return, within the limits shrunk by ``config.limit_margin``.
    Self-collision is not considered.
    """
    if n_poses < 1:
        raise ProtocolError(f"n_poses must be at least 1, got {n_poses}")
    box_lo, box_hi = pose_box(chain, config)
    return rng.uniform(box_lo, box_hi, size=(int(n_poses), chain.n_joints))


def check_limits(
    chain: SerialChain, t: FloatArray, q: FloatArray, qd: FloatArray | None = None, margin: float = 0.0
) -> None:
    """Raise :class:`ProtocolError` at the first sample outside the position or velocity limits.

    ``t`` ``(N,)`` s, ``q`` and ``qd`` ``(N, n)``; positions must lie in ``[lower + margin,
    upper - margin]`` (rad), speeds within the chain's velocity limits (rad/s).
    """
    if chain.joint_lower is not None and chain.joint_upper is not None:
        lower, upper = chain.joint_lower + margin, chain.joint_upper - margin
        below = q < lower - _TOL
        above = q > upper + _TOL
        bad = below | above
        if bad.any():
            i, j = np.argwhere(bad)[0]
            limit = chain.joint_lower[j] if below[i, j] else chain.joint_upper[j]
            raise ProtocolError(
                f"joint {j + 1} would reach {q[i, j]:.4f} rad at t={t[i]:.3f} s "
                f"(limit {limit:.4f} rad, margin {margin} rad)"
            )
    if qd is not None and chain.velocity_limit is not None:
        bad = np.abs(qd) > chain.velocity_limit + _TOL
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise ProtocolError(
                f"joint {j + 1} would reach {qd[i, j]:.4f} rad/s at t={t[i]:.3f} s "
                f"(velocity limit {chain.velocity_limit[j]:.4f} rad/s)"
            )
