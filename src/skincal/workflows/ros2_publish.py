"""What ``skincal ros2`` publishes, as ROS 2 messages: the units' poses for ``/tf_static`` and their
status for ``/diagnostics`` (:mod:`skincal.workflows.ros2_live` decides when)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from skincal.kinematics.chain import SerialChain
from skincal.names import printable

HARDWARE_ID = "skincal"
"""``hardware_id`` of the session's own status."""


def unit_transforms(result: Any, chain: SerialChain, units: list[str], stamp_ns: int) -> dict[str, Any]:
    """``geometry_msgs/TransformStamped`` per unit of ``result`` (a ``CalibrationResult``) among ``units``:
    ``header.frame_id`` the link's frame (:func:`skincal.data.export.unit_frames` on ``chain``'s link
    names), ``child_frame_id`` the unit, ``T_link_su`` as translation (m) and rotation (quaternion
    x, y, z, w: ROS order), stamped ``stamp_ns`` (ns since the epoch)."""
    from scipy.spatial.transform import Rotation

    from skincal.data.export import link_frames_for, unit_frames
    from skincal.data.ros2 import messages as m

    picked = dataclasses.replace(result, units={u: r for u, r in result.units.items() if u in units})
    stamp = m.Time.from_ns(stamp_ns)
    out = {}
    for f in unit_frames(picked, link_frames_for(chain)):
        x, y, z, w = Rotation.from_matrix(f.R_parent_child).as_quat()  # scalar last: ROS order
        out[f.unit] = m.TransformStamped(
            header=m.Header(stamp, f.parent), child_frame_id=f.child,
            transform=m.Transform(m.Vector3(*(float(v) for v in f.p_parent_child)),
                                  m.Quaternion(float(x), float(y), float(z), float(w))),
        )  # fmt: skip
    return out


def _std_text(values: Any, scale: float) -> str:
    arr = np.asarray(values, float)
    return f"{scale * float(np.max(arr)):.3f}" if arr.size and np.all(np.isfinite(arr)) else "inf"


def unit_status(unit: str, status: Any, chain: SerialChain | None, target: str, state: str, published: bool) -> Any:
    """``diagnostic_msgs/DiagnosticStatus`` of one unit from its calibrator ``status``
    (:class:`skincal.calib.online.UnitStatus`): OK at the target, else WARN with what is missing;
    ``state`` ``moved`` (not re-published yet) or ``provisional`` (re-published after a move, std above
    the target) says so."""
    from skincal.data.ros2 import messages as m

    kv = m.KeyValue
    link = "-" if status.link is None or chain is None else chain.link_name(status.link)
    joint = "-" if status.best_joint is None or chain is None else chain.joint_name(status.best_joint + 1)
    if state == "moved":
        level, text = m.WARN, "moved on its link: re-calibrating"
    elif state == "provisional" and not status.reached:
        level, text = m.WARN, "moved on its link: re-published, std above the target"
    elif status.reached:
        level, text = m.OK, "calibrated (published on /tf_static)"
    else:
        level, text = m.WARN, status.missing or "calibrating: std above the target"
    values = [
        kv("link", printable(link)),
        kv("position std max (mm)", _std_text(status.position_std_m, 1e3)),
        kv("rotation std max (deg)", _std_text(status.rotation_std_deg, 1.0)),
        kv("target", target),
        kv("missing", status.missing or "-"),
        kv("move joint", joint),
        kv("samples", str(status.samples)),
        kv("published", "yes" if published else "no"),
    ]
    return m.DiagnosticStatus(level=level, name=f"skincal: {unit}", message=text, hardware_id=unit, values=values)


def session_status(state: str, running: bool, counts: dict[str, str]) -> Any:
    """The session's ``DiagnosticStatus`` (``skincal: session``): OK while calibrating, WARN while waiting."""
    from skincal.data.ros2 import messages as m

    values = [m.KeyValue(k, v) for k, v in counts.items()]
    return m.DiagnosticStatus(level=m.OK if running else m.WARN, name="skincal: session", message=state,
                              hardware_id=HARDWARE_ID, values=values)  # fmt: skip
