"""Exports of a calibration result for ROS: complete URDF, xacro macro, YAML/JSON with covariance,
one static-TF node for ROS 1 or ROS 2, CSV (``docs/interfaces.md``, section "Exports").

Every unit pose of a result is ``T_link_su`` in skincal link frame ``i`` (``docs/interfaces.md``).
ROS tools name their own frames, so each link is mapped to a named parent frame with a fixed
offset ``T_frame_link`` (the pose of link frame ``i`` in that frame); the exported pose is
``T_frame_child = T_frame_link @ T_link_su [@ T_SU_RANGE]``.

Link frame names come from the robot (:func:`robot_names`), no map needed:

* a URDF robot (``--robot arm.urdf``): its own link names (link frame ``i`` *is* the URDF frame of
  the child link of the ``i``-th movable joint);
* ``panda`` and ``xarm7``: the maker's URDF names (``panda_link<i>``; ``link_base``, ``link<i>``),
  because those URDF frames are the presets' modified-DH frames (same origins and axes);
* any other DH chain (``ur5e``, ``sawyer``, a DH chain file): ``<robot>_dh_link<i>``, since its DH
  frames are *not* the maker's URDF frames and must not be taken for them;
* a result exported onto another description of its robot (a DH preset's result onto the maker's
  URDF): each pose is moved into the target's link frame, ``X_i @ T_link_su`` with ``X_i =
  T_targetlink_sourcelink`` from both chains' forward kinematics (:func:`link_offsets`, refused when
  they do not move alike; the source chain from :func:`result_chain` or the dataset);
* ``--robot-links map.yaml`` overrides: ``{links: {<i>: <frame> | {frame: <name>, xyz: [m], rpy:
  [rad]}}}``; ``rpy`` is URDF's fixed-axis roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

``frame="range"`` exports, instead of each unit frame, its Range frame ``<unit>_range``: the ToF
beam (the unit's +z) is its +x, as ``sensor_msgs/Range`` expects: ``T_su_range = Ry(-90 deg)``
(:data:`T_SU_RANGE`; x_range = z_su, y_range = y_su, z_range = -x_su).

Quaternion order: skincal writes ``(w, x, y, z)`` (field ``quaternion_wxyz``); ROS uses
``(x, y, z, w)``: the TF nodes hold ``(x, y, z, w)`` and the CSV names its columns ``qw, qx, qy,
qz``. Files are written atomically.

Escaping by construction (no user text is ever pasted into a template):

* names: every unit name and the robot name must pass :func:`skincal.names.name_problem`, and
  the parent and child frame names (link map, ``prefix``) the same rule for each ``/``-separated
  part; anything else is refused with a one-line error naming it, before a byte is written;
* URDF and xacro: built with :mod:`xml.etree.ElementTree` (the user's URDF parsed with ``lxml``
  and extended element by element; names only in attributes, which the libraries escape); comments
  hold fixed text, and the method and robot appear there only as JSON string literals with every
  ``-`` written ``\\u002d`` and ``$`` written ``\\u0024``; in the xacro, names pass
  :func:`xacro_text` (a ``$`` run before ``{`` or ``(`` gets one more ``$``: xacro's escape);
* TF nodes: a fixed code skeleton; user data appear only as Python literals made by :func:`repr`
  of plain strings and numbers and checked with :func:`ast.literal_eval` (never in the docstring,
  a comment or a code position);
* CSV: through :mod:`csv`; a text cell starting with ``=``, ``+``, ``-``, ``@``, tab or CR gets a
  leading ``'`` (spreadsheet formula neutralisation); numbers are written as numbers;
* YAML and JSON: through :func:`yaml.safe_dump`'s representer and emitter (libyaml's when PyYAML has it, same text) and
  :func:`json.dumps`.

One job per module: :mod:`~skincal.data.export.frames` (frame names, link maps, the unit frames and their
covariance, the name checks), :mod:`~skincal.data.export.offsets` (a result moved onto another description
of its robot), :mod:`~skincal.data.export.escape` (user text made safe), the writers
:mod:`~skincal.data.export.urdf` (URDF, xacro), :mod:`~skincal.data.export.documents` (YAML, JSON, CSV) and
:mod:`~skincal.data.export.tf` (static-TF nodes); this module picks the writer (:func:`export_result`).
"""

from __future__ import annotations

from pathlib import Path

from skincal.data.export.documents import to_csv, to_json, to_yaml
from skincal.data.export.escape import shown
from skincal.data.export.frames import (
    FRAMES,
    T_SU_RANGE,
    UNKNOWN_VARIANCE,
    LinkFrame,
    UnitFrame,
    check_robot_name,
    link_frames_for,
    load_link_map,
    pose_covariance,
    robot_names,
    rpy_from_matrix,
    unit_frames,
)
from skincal.data.export.offsets import SAME_MOTION_ATOL_M, link_offsets, result_chain
from skincal.data.export.tf import to_tf_ros1, to_tf_ros2
from skincal.data.export.urdf import to_urdf, to_xacro
from skincal.data.provenance import result_robot
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.io.atomic import write_bytes_atomic
from skincal.kinematics.chain import SerialChain

__all__ = [
    "SAME_MOTION_ATOL_M",
    "T_SU_RANGE",
    "UNKNOWN_VARIANCE",
    "link_frames_for",
    "link_offsets",
    "load_link_map",
    "pose_covariance",
    "robot_names",
    "rpy_from_matrix",
    "to_urdf",
    "unit_frames",
    "FORMATS",
    "export_result",
    "export_text",
    "exportable",
    "without_position",
]


FORMATS = ("urdf", "xacro", "yaml", "json", "tf", "tf-ros2", "tf-ros1", "csv")
"""Export formats; ``tf`` is ``tf-ros2``."""
_WRITERS = {
    "xacro": to_xacro,
    "yaml": to_yaml,
    "json": to_json,
    "tf": to_tf_ros2,
    "tf-ros2": to_tf_ros2,
    "tf-ros1": to_tf_ros1,
    "csv": to_csv,
}


def exportable(result: CalibrationResult) -> CalibrationResult:
    """``result`` with only the units that have a position (:func:`~skincal.data.result.has_position`): a
    unit calibrated from rests only has a link and a rotation but no position, and a frame placed at
    its placeholder ``(0, 0, 0)`` would put it on the link's origin; the caller names the ones left out
    (:func:`without_position`). :class:`ConfigError` when no unit is left."""
    from dataclasses import replace

    from skincal.data.result import has_position

    kept = {name: unit for name, unit in result.units.items() if has_position(unit)}
    if result.units and not kept:
        raise ConfigError(
            "no unit has a position to export (calibrated from rests only: positions not determined); "
            "record motion that turns the units' links and calibrate again"
        )
    return result if len(kept) == len(result.units) else replace(result, units=kept)


def without_position(result: CalibrationResult) -> list[str]:
    """The units of ``result`` that :func:`exportable` leaves out (no position determined)."""
    from skincal.data.result import has_position

    return [name for name, unit in result.units.items() if not has_position(unit)]


def export_text(
    result: CalibrationResult,
    fmt: str,
    *,
    link_map: str | Path | None = None,
    prefix: str = "",
    robot: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    frame: str = "unit",
    source: SerialChain | None = None,
) -> tuple[str, list[UnitFrame]]:
    """The text of ``result`` as ``fmt`` and the exported frames (see :func:`export_result`)."""
    if fmt not in FORMATS:
        raise ConfigError(f"unknown export format '{shown(str(fmt))}' (use {', '.join(FORMATS)})")
    if frame not in FRAMES:
        raise ConfigError(f"unknown frame '{shown(str(frame))}' (use {' or '.join(FRAMES)})")
    if fmt == "urdf" and link_map is not None:
        raise ConfigError(
            "a complete URDF names its own links: --robot-links does not apply to -f urdf (use -f xacro "
            "to add the units to your own robot description)"
        )
    check_robot_name(result)  # before the robot is looked at: a crafted name is refused as such
    result = exportable(result)
    if robot is None and source is not None:
        if base_link is not None or tip_link is not None:
            raise ConfigError("--base-link and --tip-link apply to a URDF robot given with --robot")
        from skincal.data.result import check_links

        check_links(result, source, "result")
        chain: SerialChain | None = source
    else:
        chain = result_robot(result, robot, base_link=base_link, tip_link=tip_link)
    links = link_frames_for(chain, link_map)
    if links is not None and link_map is None and chain is not None:
        computed_on = result_chain(result, chain, source)
        if computed_on is not chain:
            X = link_offsets(computed_on, chain)
            links = {i: LinkFrame(f.name, X[i] @ f.T_frame_link) for i, f in links.items()}
    frames = unit_frames(result, links, frame=frame, prefix=prefix) if links is not None else None
    if frames is None:
        raise ConfigError(
            f"robot '{shown(str(result.robot))}' is not a preset; give the robot (--robot arm.urdf or "
            "a preset, or --dataset: the dataset the result was computed from) or a link map (--robot-links "
            "map.yaml with links: {1: frame, ...})"
        )
    if fmt == "urdf":
        return to_urdf(result, frames, chain, frame), frames
    return _WRITERS[fmt](result, frames, frame), frames


def export_result(
    result: CalibrationResult,
    fmt: str,
    out: str | Path,
    *,
    link_map: str | Path | None = None,
    prefix: str = "",
    robot: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    frame: str = "unit",
    source: SerialChain | None = None,
) -> list[UnitFrame]:
    """Write ``result`` as ``fmt`` (:data:`FORMATS`) to ``out`` atomically; returns the exported
    frames. The robot is ``robot`` (preset, ``.urdf`` with ``base_link``/``tip_link``, DH chain
    file), else ``source``, else the result's preset; ``source`` is the chain the result was computed
    on (its dataset's, checked by the caller), else found by :func:`result_chain`; each pose is moved
    from the source's link frame into the robot's (:func:`link_offsets`). ``link_map`` overrides the
    link frame names and offsets (not for ``urdf``); ``frame`` is ``unit`` or ``range``
    (:data:`T_SU_RANGE`)."""
    text, frames = export_text(
        result,
        fmt,
        link_map=link_map,
        prefix=prefix,
        robot=robot,
        base_link=base_link,
        tip_link=tip_link,
        frame=frame,
        source=source,
    )
    write_bytes_atomic(out, text.encode("utf-8"))
    return frames
