"""An avoidance run as a viewer :class:`~skincal.viz.model.Recording`: joint motion, ToF readings and
the obstacles as moving spheres.

The viewer draws each obstacle track as one sphere. A sphere primitive is one track; a capsule
(segment ``p0``-``p1``, radius ``r``, base frame) becomes ``ceil(|p1 - p0| / r) + 1`` spheres of radius
``r`` evenly spaced along its segment (their union is within ``r (1 - sqrt(3)/2)`` of the capsule);
boxes become their circumscribed sphere. Tracks are sampled every ``step_s`` (the scenes move
piecewise-linearly, the viewer interpolates linearly).
"""

from __future__ import annotations

import numpy as np

from skincal.sim.scene import Scene
from skincal.skin import tof
from skincal.viz.model import ObstacleTrack, Recording
from skincal.workflows.avoidance import RunLog


def obstacle_tracks(log: RunLog, step_s: float = 0.02) -> dict[str, ObstacleTrack]:
    """The run's obstacle solids as sphere tracks ``name -> ObstacleTrack`` (``name`` = obstacle/part)."""
    scene = log.scenario.scene
    if not scene.obstacles:
        return {}
    t = np.arange(float(log.t[0]), float(log.t[-1]) + step_s / 2, step_s)
    out: dict[str, ObstacleTrack] = {}
    for obs in scene.obstacles:
        prims = Scene((obs,)).tof_primitives(t)
        for j, p in enumerate(prims):
            name = f"{obs.name}/{j}"
            if isinstance(p, tof.Sphere):
                out[name] = ObstacleTrack(t, np.broadcast_to(p.center, (t.size, 3)).copy(), float(p.radius))
            elif isinstance(p, tof.Capsule):
                r = float(p.radius)
                a, b = np.broadcast_to(p.p0, (t.size, 3)), np.broadcast_to(p.p1, (t.size, 3))
                n = int(np.ceil(float(np.linalg.norm(b[0] - a[0])) / r)) + 1
                for i, s in enumerate(np.linspace(0.0, 1.0, n)):
                    out[f"{name}.{i}"] = ObstacleTrack(t, a + s * (b - a), r)
            elif isinstance(p, tof.Box):
                c = np.broadcast_to(p.center, (t.size, 3)).copy()
                out[name] = ObstacleTrack(t, c, float(np.linalg.norm(np.asarray(p.half_extents, dtype=float))))
    return out


def recording_from_run(log: RunLog, step_s: float = 0.02) -> Recording:
    """The viewer recording of a closed-loop run: ``q(t)`` at the control rate, each unit's readings
    (instants and ranges, NaN = none) and the obstacles as sphere tracks (:func:`obstacle_tracks`)."""
    tof_t, tof_range = {}, {}
    for u, name in enumerate(log.units):
        ok = np.isfinite(log.tof_t[:, u])
        tof_t[name] = log.tof_t[ok, u].copy()
        tof_range[name] = log.tof_range[ok, u].copy()
    return Recording(
        t=log.t.copy(), q=log.q.copy(), tof_t=tof_t, tof_range=tof_range, obstacles=obstacle_tracks(log, step_s)
    )
