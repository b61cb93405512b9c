"""Time-of-flight range sensor of a skin unit (VL53L1X class): exact ray casting in a cone.

Scene: solid primitives in the base frame {0}, lengths in m: :class:`Sphere`, :class:`Capsule`,
:class:`Plane` (a half-space) and :class:`Box`. Every array field broadcasts against the sample
axis: a centre of shape ``(3,)`` is fixed, ``(M, 3)`` moves with the samples (e.g. link capsules
of the robot along a trajectory, :func:`capsules_in_base`).

Sensor (:func:`tof_range`): the VL53L1X reports the distance to the nearest target in its field of
view. We cast rays from the SU origin inside a cone of full angle ``fov_deg`` around the unit's +z
axis (a central ray plus rings, :func:`cone_directions`), take the nearest hit over all rays and
report that *distance along its ray* (for ``n_rays = 1`` it is the range along +z, as MuJoCo's
rangefinder). The reading of that true distance is :meth:`TofModel.measure` (the one measurement
model, also used by the MuJoCo simulator and the avoidance loop): range limits on the true distance,
then range-dependent Gaussian noise ``std = noise_std + noise_std_per_m * d`` and rounding to
``resolution_m``. NaN means no target within ``[min_range, max_range]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics import geometry
from skincal.kinematics.transforms import FloatArray


def finite_array(value: ArrayLike, what: str, shape: tuple = (..., 3)) -> FloatArray:
    """``value`` as a new read-only float array, checked finite and of ``shape``; else a
    :class:`ConfigError` naming ``what``. The one validation of the vectors of scenes and solids.

    ``shape``: exact sizes, ``None`` for any size on that axis, and a leading ``...`` for any number
    (>= 0) of leading axes: the default ``(..., 3)`` takes ``(3,)``, ``(M, 3)``, ...
    """
    any_lead = shape[:1] == (...,)
    tail = shape[1:] if any_lead else shape
    dims = ["..." if d is ... else "N" if d is None else str(d) for d in shape]
    text = f"({dims[0]},)" if len(dims) == 1 else f"({', '.join(dims)})"
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be finite with shape {text}, got ?") from None
    ok = arr.ndim >= len(tail) if any_lead else arr.ndim == len(tail)
    ok = ok and all(w is None or g == w for g, w in zip(arr.shape[arr.ndim - len(tail) :], tail, strict=True))
    if not ok or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{what} must be finite with shape {text}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


def _positive(name: str, value: ArrayLike, allow_zero: bool = False) -> FloatArray:
    arr = np.array(value, dtype=float)
    bad = (arr < 0) if allow_zero else (arr <= 0)
    if not np.all(np.isfinite(arr)) or np.any(bad):
        raise ConfigError(f"{name} must be finite and {'non-negative' if allow_zero else 'positive'} (m)")
    arr.setflags(write=False)
    return arr


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.sum(a * b, axis=-1)


def _near_root(b: FloatArray, c: FloatArray, disc: FloatArray) -> FloatArray:
    """Smaller root of ``t^2 + 2 b t + c = 0`` (scaled) when ``c > 0, b < 0``: ``c / (-b + sqrt(disc))``.

    The quotient form avoids cancellation when the origin is close to the surface.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return c / (-b + np.sqrt(np.maximum(disc, 0.0)))


@dataclass(frozen=True)
class Sphere:
    """Solid ball: ``|x - center| <= radius``; ``center`` ``(3,)`` or ``(M, 3)``, m."""

    center: FloatArray
    radius: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", finite_array(self.center, "Sphere.center (m)"))
        object.__setattr__(self, "radius", _positive("Sphere.radius", self.radius))

    def ray_distance(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """``|o + t d - c|^2 = r^2`` with unit ``d``: ``t^2 + 2 b t + c = 0``, ``b = d.(o - c)``."""
        oc = o - self.center
        b = _dot(oc, d)
        c = _dot(oc, oc) - self.radius**2
        disc = b * b - c
        hit = (c > 0) & (b < 0) & (disc >= 0)
        return np.where(c <= 0, 0.0, np.where(hit, _near_root(b, c, disc), np.inf))


@dataclass(frozen=True)
class Capsule:
    """Solid capsule: points within ``radius`` of the segment ``p0``-``p1`` (base frame, m)."""

    p0: FloatArray
    p1: FloatArray
    radius: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "p0", finite_array(self.p0, "Capsule.p0 (m)"))
        object.__setattr__(self, "p1", finite_array(self.p1, "Capsule.p1 (m)"))
        object.__setattr__(self, "radius", _positive("Capsule.radius", self.radius))

    def ray_distance(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """Nearest of the two end spheres and the finite cylinder side.

        Side: with axis ``u``, ``w = o - p0`` and ``x_perp = x - (x.u) u``, solve
        ``|w_perp + t d_perp|^2 = r^2`` and keep the hit if ``0 <= (w + t d).u <= L``.
        """
        axis = self.p1 - self.p0
        length = np.linalg.norm(axis, axis=-1)
        u = axis / np.maximum(length, 1e-300)[..., None]
        w = o - self.p0
        wu, du = _dot(w, u), _dot(d, u)
        # inside: distance from o to the segment
        s = np.clip(wu, 0.0, length)
        inside = _dot(w - s[..., None] * u, w - s[..., None] * u) <= self.radius**2
        w_perp = w - wu[..., None] * u
        d_perp = d - du[..., None] * u
        a = _dot(d_perp, d_perp)
        b = _dot(d_perp, w_perp)
        c = _dot(w_perp, w_perp) - self.radius**2
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = _near_root(b, c, disc)
            along = wu + t_side * du
        side_hit = (length > 0) & (c > 0) & (b < 0) & (disc >= 0) & (along >= 0) & (along <= length)
        t = np.where(side_hit, t_side, np.inf)
        for end in (self.p0, self.p1):
            t = np.minimum(t, Sphere(end, self.radius).ray_distance(o, d))
        return np.where(inside, 0.0, t)


@dataclass(frozen=True)
class Plane:
    """Solid half-space behind a plane: ``normal . (x - point) <= 0`` (e.g. a floor or a wall).

    ``point`` ``(3,)`` or ``(M, 3)``, m; ``normal`` is normalised here and points out of the solid.
    """

    point: FloatArray
    normal: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", finite_array(self.point, "Plane.point (m)"))
        n = finite_array(self.normal, "Plane.normal")
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        if np.any(norm < 1e-12):
            raise ConfigError("Plane.normal must be a non-zero vector")
        n = n / norm
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)

    def ray_distance(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """``t = h / (-n.d)`` with height ``h = n.(o - point) > 0`` when the ray heads down (``n.d < 0``)."""
        h = _dot(self.normal, o - self.point)
        down = _dot(self.normal, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(down < 0, h / -down, np.inf)
        return np.where(h <= 0, 0.0, t)


@dataclass(frozen=True)
class Box:
    """Solid oriented box: ``|R^T (x - center)|_i <= half_extents_i``.

    ``center`` ``(3,)``/``(M, 3)`` m, ``half_extents`` ``(3,)`` m, ``R`` ``(3, 3)``/``(M, 3, 3)``: the box axes
    in the base frame (identity when not given).
    """

    center: FloatArray
    half_extents: FloatArray
    R: FloatArray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", finite_array(self.center, "Box.center (m)"))
        h = _positive("Box.half_extents", self.half_extents)
        if h.shape[-1:] != (3,):
            raise ConfigError(f"Box.half_extents must have shape (3,) in m, got {h.shape}")
        object.__setattr__(self, "half_extents", h)
        R = np.eye(3) if self.R is None else np.array(self.R, dtype=float)
        if R.shape[-2:] != (3, 3) or not np.allclose(np.einsum("...ji,...jk->...ik", R, R), np.eye(3), atol=1e-6):
            raise ConfigError("Box.R must be rotation matrices of shape (3, 3) or (M, 3, 3)")
        R.setflags(write=False)
        object.__setattr__(self, "R", R)

    def ray_distance(self, o: FloatArray, d: FloatArray) -> FloatArray:
        """Slab method in the box frame: entry ``max_i t_lo,i``, exit ``min_i t_hi,i``."""
        o_box = np.einsum("...ji,...j->...i", self.R, o - self.center)
        d_box = np.einsum("...ji,...j->...i", self.R, d)
        h = self.half_extents
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-h - o_box) / d_box
            t2 = (h - o_box) / d_box
        parallel = d_box == 0
        within = np.abs(o_box) <= h
        t_lo = np.where(parallel, np.where(within, -np.inf, np.inf), np.minimum(t1, t2))
        t_hi = np.where(parallel, np.where(within, np.inf, -np.inf), np.maximum(t1, t2))
        t_near, t_far = t_lo.max(axis=-1), t_hi.min(axis=-1)
        hit = (t_near <= t_far) & (t_far >= 0)
        return np.where(np.all(within, axis=-1), 0.0, np.where(hit, t_near, np.inf))


Primitive = Sphere | Capsule | Plane | Box
"""A solid of the ToF scene, in the base frame."""


def ray_distance(origins: ArrayLike, dirs: ArrayLike, primitive: Primitive) -> FloatArray:
    """Distance along each ray to the first intersection with a solid primitive, m.

    Args:
        origins: ``(..., 3)`` ray origins in the base frame, m.
        dirs: ``(..., 3)`` ray directions (normalised here).
        primitive: a :class:`Sphere`, :class:`Capsule`, :class:`Plane` or :class:`Box`; its arrays
            broadcast against ``origins`` from the right (``(M, 3)`` against ``(K, M, 3)``).

    Returns:
        ``(...)`` distances: exact closed form; ``inf`` when missed or behind the origin; ``0`` when
        the origin lies inside (or on) the solid.
    """
    o = np.asarray(origins, dtype=float)
    d = np.asarray(dirs, dtype=float)
    if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
        raise ConfigError(f"ray origins and directions need a last axis of 3, got {o.shape} and {d.shape}")
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise ConfigError("ray directions must be finite and non-zero")
    if not isinstance(primitive, Sphere | Capsule | Plane | Box):
        raise ConfigError(f"unknown ToF scene primitive {type(primitive).__name__}")
    return primitive.ray_distance(o, d / norm)


def capsules_in_base(
    link_capsules: Sequence[geometry.Capsule], T_base_link: ArrayLike, exclude_links: Sequence[int] = ()
) -> list[Capsule]:
    """Robot link capsules (each in its link frame) moved to the base frame along a trajectory.

    ``T_base_link``: ``(M, n + 1, 4, 4)`` from ``SerialChain.link_frames``; returns capsules with
    ``(M, 3)`` end points. ``exclude_links``: links to leave out (e.g. the one a unit sits on).
    """
    T = np.asarray(T_base_link, dtype=float)
    out = []
    for cap in link_capsules:
        if cap.link in exclude_links:
            continue
        T_l = T[:, cap.link]
        ends = [T_l[:, :3, :3] @ p + T_l[:, :3, 3] for p in (cap.p0, cap.p1)]
        out.append(Capsule(ends[0], ends[1], cap.radius))
    return out


@dataclass(frozen=True)
class TofModel:
    """A time-of-flight sensor type (VL53L1X defaults); SI units.

    Attributes:
        rate_hz: ranging rate, Hz.
        fov_deg: full cone angle of the field of view, deg.
        min_range, max_range: reported window, m; nearest targets outside it give NaN.
        noise_std: constant part of the Gaussian range noise std, m.
        noise_std_per_m: range-proportional part (std grows by this many m per m of range).
        resolution_m: output rounding step, m (0 = none).
        n_rays: rays cast per sample: a central ray plus rings (1 = central ray only).
    """

    rate_hz: float = 50.0
    fov_deg: float = 27.0
    min_range: float = 0.0
    max_range: float = 4.0
    noise_std: float = 0.0
    noise_std_per_m: float = 0.0
    resolution_m: float = 0.0
    n_rays: int = 37

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float, np.number)) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"TofModel.{f.name} must be a finite non-negative number, got {value!r}")
        if self.rate_hz <= 0 or not (0 < self.fov_deg < 180):
            raise ConfigError(f"TofModel needs rate_hz > 0 and 0 < fov_deg < 180, got {self.rate_hz}, {self.fov_deg}")
        if self.max_range <= self.min_range:
            raise ConfigError(f"TofModel.max_range ({self.max_range} m) must exceed min_range ({self.min_range} m)")
        if int(self.n_rays) != self.n_rays or self.n_rays < 1:
            raise ConfigError(f"TofModel.n_rays must be a positive integer, got {self.n_rays}")
        object.__setattr__(self, "n_rays", int(self.n_rays))

    def noise_std_at(self, distance: ArrayLike) -> FloatArray:
        """Range noise std at the true distance, m: ``noise_std + noise_std_per_m * d``."""
        return self.noise_std + self.noise_std_per_m * np.asarray(distance, dtype=float)

    @property
    def noisy(self) -> bool:
        """The model adds range noise (so :meth:`measure` needs an rng)."""
        return self.noise_std > 0 or self.noise_std_per_m > 0

    def measure(self, true_distance: ArrayLike, rng: np.random.Generator | None = None) -> FloatArray:
        """The sensor's readings of true nearest-target distances: THE ToF measurement model.

        Every ToF reading of skincal goes through here (:func:`tof_range`, the MuJoCo simulator, the
        avoidance loop): window ``[min_range, max_range]`` on the true distance (outside it, ``inf``
        or NaN: NaN), Gaussian noise of std :meth:`noise_std_at` the true distance, rounding to
        ``resolution_m``.

        Random stream (the contract the simulators' draw-for-draw equality rests on): a noisy model
        draws exactly ``rng.normal(size=true_distance.shape)``, one standard normal per sample in C
        order, invalid samples included (their draw is spent and discarded); a noise-free model draws
        nothing, so ``rng`` may then be ``None``.

        Args:
            true_distance: ``(...)`` distances to the nearest target, m (``inf`` = nothing hit).
            rng: random generator; required when :attr:`noisy`.

        Returns:
            ``(...)`` readings, m; NaN = no target in the window.
        """
        d = np.asarray(true_distance, dtype=float)
        valid = (d >= self.min_range) & (d <= self.max_range)
        measured = np.where(valid, d, np.nan)
        if self.noisy:
            if rng is None:
                raise ConfigError("the ToF model has noise: measuring needs an rng")
            measured = measured + rng.normal(size=measured.shape) * self.noise_std_at(np.where(valid, d, 0.0))
        if self.resolution_m > 0:
            measured = np.round(measured / self.resolution_m) * self.resolution_m
        return measured


TOF_PRESETS: dict[str, TofModel] = {
    # VL53L1X long mode: 4 m, 27 deg; ~5 mm + 0.5 % of range (1 sigma), 1 mm output resolution.
    "vl53l1x": TofModel(noise_std=0.005, noise_std_per_m=0.005, resolution_m=0.001),
    # The paper authors' firmware reported only 0.01-1.0 m.
    "roboskin-firmware": TofModel(
        min_range=0.01, max_range=1.0, noise_std=0.005, noise_std_per_m=0.005, resolution_m=0.001
    ),
    # Noise-free cone, and the central ray alone (comparable with MuJoCo's rangefinder).
    "ideal": TofModel(),
    "ideal-ray": TofModel(n_rays=1),
}
"""ToF presets by name: ``vl53l1x``, ``roboskin-firmware``, ``ideal``, ``ideal-ray``."""


def get_tof_model(name: str) -> TofModel:
    """The preset ``name``; an unknown name raises :class:`ConfigError` listing the known ones."""
    try:
        return TOF_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown ToF model '{name}'; known: {', '.join(TOF_PRESETS)}") from None


def cone_directions(fov_deg: float, n_rays: int) -> FloatArray:
    """``(n_rays, 3)`` unit ray directions in the SU frame, symmetric about +z.

    Ray 0 is +z. The others lie on ``n`` rings at polar angles ``j / n * fov / 2`` (j = 1..n, the
    outer ring on the cone's edge) with ``6 j`` rays each, equally spaced in azimuth starting on the
    SU's +x axis; ``n`` is the largest with ``1 + 3 n (n + 1) <= n_rays`` and any remaining rays
    go to the outer ring (so 7, 19, 37, 61 rays give 1, 2, 3, 4 full rings).
    """
    if n_rays == 1:
        return np.array([[0.0, 0.0, 1.0]])
    n = max(1, int(math.floor((-3 + math.sqrt(9 + 12 * (n_rays - 1))) / 6)))
    counts = [6 * j for j in range(1, n + 1)]
    counts[-1] += (n_rays - 1) - sum(counts)
    half = math.radians(fov_deg) / 2
    polar = np.concatenate([[0.0]] + [np.full(c, half * j / n) for j, c in enumerate(counts, start=1)])
    azimuth = np.concatenate([[0.0]] + [2 * np.pi * np.arange(c) / c for c in counts])
    return np.stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)],
        axis=-1,
    )


def _frames_from_axes(axes: FloatArray) -> FloatArray:
    """Rotations ``(M, 3, 3)`` whose z column is each given +z axis (x, y arbitrary but fixed)."""
    z = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = helper - _dot(helper, z)[:, None] * z
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def tof_range(
    origins: ArrayLike,
    R_base_su: ArrayLike,
    scene: Sequence[Primitive],
    model: TofModel,
    rng: np.random.Generator | None = None,
) -> FloatArray:
    """Simulated ToF readings: :meth:`TofModel.measure` of :func:`nearest_in_cone`.

    Args:
        origins: ``(M, 3)`` SU origins in the base frame, m.
        R_base_su: ``(M, 3, 3)`` SU orientations, or ``(M, 3)`` SU +z axes in the base frame.
        scene: solids in the base frame (arrays ``(3,)`` fixed or ``(M, 3)`` per sample).
        model: sensor type.
        rng: random generator; required when the model has noise.

    Returns:
        ``(M,)`` range, m: ``min`` over cone rays of the distance along each ray, plus noise;
        NaN when the nearest target is outside ``[min_range, max_range]`` or nothing is hit.
    """
    if model.noisy and rng is None:
        raise ConfigError("tof_range needs an rng: the ToF model has noise")
    return model.measure(nearest_in_cone(origins, R_base_su, scene, model), rng)


def nearest_in_cone(
    origins: ArrayLike, R_base_su: ArrayLike, scene: Sequence[Primitive], model: TofModel
) -> FloatArray:
    """True distance ``(M,)`` m to the nearest target over the model's cone rays (``inf``: none).

    Arguments as :func:`tof_range`; no limits, no noise.
    """
    o = np.asarray(origins, dtype=float)
    if o.ndim != 2 or o.shape[1] != 3:
        raise ConfigError(f"ToF origins must have shape (M, 3) in m, got {o.shape}")
    R = np.asarray(R_base_su, dtype=float)
    if R.shape == (o.shape[0], 3):
        R = _frames_from_axes(R)
    elif R.shape != (o.shape[0], 3, 3):
        raise ConfigError(f"R_base_su must be ({o.shape[0]}, 3, 3) rotations or ({o.shape[0]}, 3) axes, got {R.shape}")
    dirs = np.einsum("mij,kj->kmi", R, cone_directions(model.fov_deg, model.n_rays))  # (K, M, 3)
    nearest = np.full(o.shape[0], np.inf)
    for primitive in scene:
        nearest = np.minimum(nearest, ray_distance(o[None], dirs, primitive).min(axis=0))
    return nearest
