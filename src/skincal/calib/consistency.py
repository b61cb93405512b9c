"""Honest uncertainty by the data's own testimony: split a recording, calibrate each part, compare.

A calibrator's reported std is only as good as its noise model. Real recordings carry errors no model
names (a low-rate joint stream's interpolation, an IMU's unmodelled scale, a clock that steps); what
they do to the estimate shows when two independent parts of the same recording disagree more than
their std allow. Each unit's samples are split two ways:

* ``time``: the first and the second half of the recording (catches what changes over time: clocks,
  drifts, a unit that slipped);
* ``interleaved``: alternate windows of :data:`WINDOW_S` (both parts span the whole recording and
  see the same kinds of motion: catches model errors and residuals correlated beyond the model).

Each part is calibrated with the same method on the unit's link (the full result's), and for each
split the pose difference ``d = x_A - x_B`` (position in the link frame, m; rotation
``rotvec(R_B R_A^T)`` about the link axes, rad) is compared with the parts' std::

    z_i = d_i / sqrt(s_A,i^2 + s_B,i^2),   chi2 = sum z_i^2   (~ chi-square with as many dof, if honest)

separately for the position and the rotation components of both splits (6 dof each). When a block's
chi2 exceeds its :data:`QUANTILE` quantile the data disagree with the reported std: the full result's
std of that block is inflated by ``sqrt(chi2 / dof)`` (the parts' observed excess) and the unit is
warned; honest data are left alone (a false inflation in 1 % of units). The result carries a
``consistency`` block per unit (``docs/interfaces.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist

from skincal.data.dataset import Dataset, ImuStream, TofStream
from skincal.data.result import CalibrationResult, UnitResult
from skincal.kinematics.transforms import FloatArray

WINDOW_S = 4.0
"""Length of the alternate windows of the ``interleaved`` split, s."""
QUANTILE = 0.99
"""A block's chi-square beyond this quantile of its distribution counts as disagreement."""
Z_NAMED = 3.0
"""Components whose split difference exceeds this many std are named."""
SPLITS = ("time", "interleaved")
AXES = ("x", "y", "z")

Refit = Callable[[Dataset, dict[str, int]], CalibrationResult]
"""``refit(part, links)``: the method run on a part dataset with the units' links given."""


@dataclass(frozen=True)
class Consistency:
    """One unit's split check (module docstring).

    Attributes:
        chi2_position, chi2_rotation: chi-square of the position / rotation components over both splits.
        dof_position, dof_rotation: their degrees of freedom (finite components compared).
        inflation_position, inflation_rotation: factor the full result's std of the block was multiplied
            by (1: consistent).
        disagrees: what disagrees, e.g. ``"time: position z 12.3 mm (4.1 std)"``.
        failed: splits whose parts could not be calibrated, with why.
    """

    chi2_position: float
    chi2_rotation: float
    dof_position: int
    dof_rotation: int
    inflation_position: float
    inflation_rotation: float
    disagrees: tuple[str, ...]
    failed: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "splits": list(SPLITS),
            "chi2_position": self.chi2_position,
            "dof_position": self.dof_position,
            "chi2_rotation": self.chi2_rotation,
            "dof_rotation": self.dof_rotation,
            "inflation_position": self.inflation_position,
            "inflation_rotation": self.inflation_rotation,
            "disagrees": list(self.disagrees),
            "failed": list(self.failed),
        }


def part_masks(t: FloatArray, t0: float, t1: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{split: (mask_A, mask_B)}`` over stamps ``t`` ``(M,)`` for a recording spanning ``[t0, t1]`` s."""
    mid = 0.5 * (t0 + t1)
    window = np.floor((t - t0) / WINDOW_S).astype(int) % 2 == 0
    return {"time": (t < mid, t >= mid), "interleaved": (window, ~window)}


def _part(dataset: Dataset, split: str, side: int) -> Dataset:
    """``dataset`` with every unit's IMU (and ToF) samples restricted to one part of ``split``."""
    j = dataset.joints
    assert j is not None
    t0, t1 = float(j.t[0]), float(j.t[-1])
    imu: dict[str, ImuStream] = {}
    for name, s in dataset.imu.items():
        m = part_masks(np.asarray(s.t, dtype=float), t0, t1)[split][side]
        imu[name] = ImuStream(s.t[m], s.accel[m], None if s.gyro is None else s.gyro[m])
    tof: dict[str, TofStream] = {}
    for name, r in dataset.tof.items():
        m = part_masks(np.asarray(r.t, dtype=float), t0, t1)[split][side]
        tof[name] = TofStream(r.t[m], r.range[m])
    return replace(dataset, imu=imu, tof=tof)


def _pose_vector(unit: UnitResult) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position (m), rotation matrix, and the 6 std (m, rad; NaN: undetermined) of a unit result."""
    def std(x: FloatArray | None, scale: float) -> FloatArray:
        return np.full(3, np.nan) if x is None else np.asarray(x, dtype=float) * scale

    s = np.r_[std(unit.position_std_m, 1.0), std(unit.rotation_std_deg, np.pi / 180.0)]
    s[~np.isfinite(s) | (s <= 0)] = np.nan
    return np.asarray(unit.pose.p_link_su, dtype=float), np.asarray(unit.pose.R_link_su, dtype=float), s


def compare(parts: dict[str, tuple[UnitResult, UnitResult]]) -> tuple[FloatArray, list[str]]:
    """``(2, 6)`` normalised differences ``z`` per split (rows in :data:`SPLITS` order; NaN where not
    determined) and the components beyond :data:`Z_NAMED` std, named."""
    z = np.full((len(SPLITS), 6), np.nan)
    named: list[str] = []
    for k, split in enumerate(SPLITS):
        if split not in parts:
            continue
        a, b = parts[split]
        if a.pose.link != b.pose.link or not (a.observable and b.observable):
            continue
        pa, Ra, sa = _pose_vector(a)
        pb, Rb, sb = _pose_vector(b)
        d = np.r_[pb - pa, Rotation.from_matrix(Rb @ Ra.T).as_rotvec()]
        z[k] = d / np.sqrt(sa**2 + sb**2)
        for i in np.flatnonzero(np.abs(np.nan_to_num(z[k])) > Z_NAMED):
            if i < 3:
                what, size = "position", f"{d[i] * 1e3:+.1f} mm"
            else:
                what, size = "rotation", f"{np.degrees(d[i]):+.2f} deg"
            named.append(f"{split}: {what} {AXES[i % 3]} {size} ({abs(z[k, i]):.1f} std)")
    return z, named


def block_inflation(z: FloatArray) -> tuple[float, int, float]:
    """``(chi2, dof, inflation)`` of normalised differences ``z`` (any shape; NaN ignored): inflation
    ``sqrt(chi2 / dof)`` when chi2 exceeds its :data:`QUANTILE` quantile, else 1."""
    v = z[np.isfinite(z)]
    dof = int(v.size)
    c2 = float(np.sum(v * v))
    if dof == 0 or c2 <= chi2_dist.ppf(QUANTILE, dof):
        return c2, dof, 1.0
    return c2, dof, float(np.sqrt(c2 / dof))


def check(dataset: Dataset, result: CalibrationResult, refit: Refit) -> CalibrationResult:
    """``result`` with each unit's :class:`Consistency` (``extras["consistency"]``) and its std inflated
    where the parts disagree (module docstring); ``refit`` runs the method on each part."""
    if dataset.joints is None or not result.units:
        return result
    links = {name: int(u.pose.link) for name, u in result.units.items() if u.observable}
    if not links:
        return result
    outcomes: dict[str, dict[str, list[UnitResult | None]]] = {u: {} for u in links}
    errors: dict[str, list[str]] = {u: [] for u in links}
    for split in SPLITS:
        for side in (0, 1):
            try:
                part = refit(_part(dataset, split, side), links)
            except Exception as exc:  # noqa: BLE001 - a part that cannot be calibrated is a finding, not a crash
                for u in links:
                    errors[u].append(f"{split} part {side + 1}: {exc}")
                part = None
            for u in links:
                got = None if part is None else part.units.get(u)
                if part is not None and got is None:
                    reason = part.failed_units.get(u, "not calibrated")
                    errors[u].append(f"{split} part {side + 1}: {reason}")
                outcomes[u].setdefault(split, []).append(got)
    units = dict(result.units)
    for name in links:
        pairs = {s: (v[0], v[1]) for s, v in outcomes[name].items() if v[0] is not None and v[1] is not None}
        z, named = compare(pairs)  # type: ignore[arg-type]
        cp, dp, fp = block_inflation(z[:, :3])
        cr, dr, fr = block_inflation(z[:, 3:])
        c = Consistency(cp, cr, dp, dr, fp, fr, tuple(named), tuple(errors[name]))
        unit = units[name]
        warnings = list(unit.warnings)
        if fp > 1.0 or fr > 1.0:
            parts = [f"position x{fp:.1f}"] * (fp > 1.0) + [f"rotation x{fr:.1f}"] * (fr > 1.0)
            warnings.append(
                "independent parts of the recording disagree beyond their std ("
                + "; ".join(named[:3]) + "): std inflated by the observed excess, " + ", ".join(parts)
            )
        pos = None if unit.position_std_m is None else np.asarray(unit.position_std_m, dtype=float) * fp
        rot = None if unit.rotation_std_deg is None else np.asarray(unit.rotation_std_deg, dtype=float) * fr
        extras = {**unit.extras, "consistency": c.to_json()}
        cov = unit.pose_covariance
        if cov is not None and (fp > 1.0 or fr > 1.0):
            T = np.diag([fp] * 3 + [fr] * 3)
            cov = T @ cov @ T
        units[name] = replace(unit, position_std_m=pos, rotation_std_deg=rot, warnings=tuple(warnings), extras=extras,
                              pose_covariance=cov)  # fmt: skip
    return replace(result, units=units)
