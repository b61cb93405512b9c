"""Named protocols of the paper (Watanabe et al., Sec. IV, "Protocol").

* ``paper-sim``: A = 2 rad/s, f = 1 Hz, 3 s per joint, 2 s rest, P = 16. The paper sampled at
  100 Hz (its IMU rate); our robot stream defaults to 1 kHz (``rate_hz``).
* ``paper-real``: A = 2.0 rad/s, f = [0.75, 0.25, 0.35, 0.55, 0.75, 0.9, 0.9] Hz per joint (a
  7-joint robot), 3 s, 10 s rest, P = 12.

* ``fast``: skincal's short protocol for the ``mle`` calibrator (under 2 minutes of motion on the
  Panda and the Sawyer): 6 poses, every joint excited for two periods of a 2 Hz sine at 90 % of its
  velocity limit, 0.4 s rests. Why: the position information of the model ``f = R^T (u + K p)``
  grows with ``|K|^2`` (angular acceleration and squared rate), which a short, fast sine maximises
  within the velocity limits while keeping the excursion small (``A / (pi f)``); rotation, bias and
  scale need gravity in several link-frame directions, which the 6 poses and the motion itself
  provide; the time offset needs jerk, which a 2 Hz sine has 8x more of than the paper's 1 Hz. The
  selection was made from the model's covariance (``benchmarks/bench_mle.py --protocols``).

Robots: every preset runs on any chain once fitted to it (:func:`skincal.protocol.limits.fit_to_limits`:
amplitudes scaled into the velocity, acceleration and position limits, per-joint lists adapted to
the number of joints, each change in ``config.notes``). ``paper-real`` and ``fast`` are meant for a
real robot: the whole motion is collision-free (``collision_check``, :mod:`skincal.protocol.collision`);
``paper-real`` chooses its static poses for diverse gravity directions in every link frame, ``fast``
keeps the uniform draw (only colliding poses redrawn), so that its simulated sessions (benchmarks,
robustness) stay as they were wherever they were collision-free. ``paper-sim`` keeps its plain
uniform poses without collision check, exactly as the simulation benchmarks were made.
``skincal protocol`` (the motion handed to a real robot) always checks collisions and chooses
diverse poses unless told otherwise (``--poses uniform``): on the Panda with 4 random units,
realistic noise and ``mle``, diverse ``fast`` poses gave 0.106 mm / 0.0064 deg mean error against
0.116 mm / 0.0071 deg for uniform ones (seeds 0-5).

The static window (not given in the paper) is 1 s of the 2 s rest in ``paper-sim`` and 2 s of the
10 s rest in ``paper-real``.
"""

from __future__ import annotations

from skincal.errors import ConfigError
from skincal.protocol.config import ProtocolConfig

PROTOCOLS: dict[str, ProtocolConfig] = {
    "paper-sim": ProtocolConfig(
        name="paper-sim",
        n_poses=16,
        amplitude=2.0,
        frequency=1.0,
        excite_duration=3.0,
        rest_duration=2.0,
        static_duration=1.0,
    ),
    "paper-real": ProtocolConfig(
        name="paper-real",
        n_poses=12,
        amplitude=2.0,
        frequency=(0.75, 0.25, 0.35, 0.55, 0.75, 0.9, 0.9),
        excite_duration=3.0,
        rest_duration=10.0,
        static_duration=2.0,
        collision_check=True,
        pose_selection="diverse",
    ),
    "fast": ProtocolConfig(
        name="fast",
        n_poses=6,
        velocity_fraction=0.9,
        frequency=2.0,
        excite_duration=1.0,
        rest_duration=0.4,
        static_duration=0.3,
        move_speed=1.5,
        min_move_duration=0.8,
        collision_check=True,
        pose_selection="uniform",
    ),
}
"""Preset protocols by name (frozen configs; derive variants with ``dataclasses.replace``)."""


def get_protocol(name: str) -> ProtocolConfig:
    """The preset protocol ``name``; unknown names raise :class:`ConfigError` listing the presets."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ConfigError(f"unknown protocol '{name}' (presets: {', '.join(PROTOCOLS)})") from None
