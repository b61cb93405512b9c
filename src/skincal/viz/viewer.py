"""Browser 3D viewer of a calibration result (viser), served on the loopback interface by default.

Scene graph (names are viser paths; a child moves with its parent):

* ``/robot/link{i}`` (i = 0..n): link frame ``T_base_link_i`` at the current joint angles; under it
  the link's capsules (a cylinder and two spheres each; none when the URDF's meshes are drawn), the
  units on that link (estimated box and axes, the true box beside it when truth is given, coloured
  green..red by position error) and the units' uncertainty ellipsoids (``ELLIPSOID_SIGMA`` x
  ``position_std_m`` along the link axes, with a visible floor).
* ``/robot/urdf``: when the robot came from a URDF whose visual meshes resolve
  (:mod:`skincal.viz.meshes`), the URDF's visual geometry drawn by ``viser.extras.ViserUrdf`` (its
  root link placed so that the chain's base link is at the base frame), moved with the same joint
  angles (URDF joints outside the chain, such as fingers, stay at 0). Otherwise the capsules, and
  :attr:`Viewer.notes` says why.
* ``/play/rays``, ``/play/points``, ``/play/obstacles/*``: playback of a recording in the base
  frame: ToF rays and the obstacle points they see, computed with the *calibrated* poses.
* ``/robot/link{i}/live_{unit}`` and ``/robot/link{i}/live_sigma_{unit}``: live mode
  (:func:`start_live_viewer`, :func:`update_live`): each unit as the streaming calibrator sees it
  now, on its best link so far, with its 3-sigma ellipsoid (green once the unit reached its target,
  orange while a direction is undetermined), redrawn as the estimate converges.

GUI: one slider per joint (deg), and with a recording a time slider and a play checkbox. viser is
an optional dependency (``pip install skincal[viz]``); it is imported only when a viewer starts.

Cross-site and DNS-rebinding access: the viewer has no login, so any web page the user opens could
otherwise connect to it (``Origin: http://evil.example``) or reach it under a hostile name that
resolves to 127.0.0.1 (``Host: evil.example``). Every HTTP request and websocket handshake must carry
a ``Host`` naming the viewer's own address (:func:`allowed_hosts`) and, when it has an ``Origin``,
that same origin; anything else gets HTTP 403 before the websocket upgrade (:func:`refusal`).
"""

from __future__ import annotations

import contextlib
import errno
import http
import io
import ipaddress
import socket
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincal.calib.metrics import pose_errors
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import link_capsules
from skincal.kinematics.transforms import FloatArray, quat_wxyz_from_matrix
from skincal.skin.pose import SkinUnitPose
from skincal.viz.meshes import MeshRefused, MeshResolver, UrdfVisuals, urdf_visuals
from skincal.viz.model import (
    UNIT_BOX_M,
    Recording,
    check_result_robot,
    cylinder_pose,
    ellipsoid_semi_axes,
    error_color,
    tof_points_base,
)

ROBOT_COLOR = (175, 180, 190)
ROBOT_OPACITY = 0.55
"""Robot capsules and meshes are see-through: units on (or just under) the surface stay visible."""
ESTIMATE_COLOR = (40, 110, 230)
ELLIPSOID_COLOR = (120, 60, 220)
RAY_COLOR = (250, 150, 30)
POINT_COLOR = (230, 30, 30)
OBSTACLE_COLOR = (200, 60, 160)
POINT_TRAIL_S = 0.5
"""Obstacle points of the last this many seconds stay visible during playback, s."""
PLAYBACK_FPS = 30.0
CAMERA_POSITION = (1.3, -1.3, 1.0)
"""Initial camera position in the base frame, m."""
CAMERA_LOOK_AT = (0.0, 0.0, 0.4)
CAMERA_FOV_DEG = 50.0
"""Initial vertical field of view, deg."""


LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
"""Names of the loopback interface a browser may use for a viewer bound there."""
WILDCARD_HOSTS = ("", "0.0.0.0", "::")
"""Bind addresses meaning every interface (``--public``)."""


def url_host(host: str) -> str:
    """``host`` as it appears in a URL: IPv6 addresses in brackets (``[::1]``)."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def viewer_url(host: str, port: int) -> str:
    """The URL of a viewer bound to ``host:port`` (a wildcard bind is shown as 127.0.0.1)."""
    return f"http://{url_host('127.0.0.1' if host in WILDCARD_HOSTS else host)}:{port}"


def _split_host(value: str) -> tuple[str, int | None] | None:
    """``(host, port)`` of a ``Host`` header value (``name``, ``name:port``, ``[v6]:port``), host in lower
    case without brackets; ``None`` when malformed."""
    value = value.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        host, rest = value[1:end], value[end + 1 :]
        if rest and not rest.startswith(":"):
            return None
        port_text = rest[1:] if rest else ""
    else:
        host, _, port_text = value.partition(":")
        if ":" in port_text:
            return None
    if not host or (port_text and not port_text.isdigit()):
        return None
    return host, int(port_text) if port_text else None


def allowed_hosts(host: str) -> frozenset[str]:
    """Host names (lower case, IPv6 without brackets) under which a viewer bound to ``host`` may be
    addressed: the loopback names always, and the bound host itself (``--public``). A wildcard bind
    also accepts every IP address literal, since a DNS-rebinding attacker's
    ``Host`` is a name of their own."""
    names = set(LOOPBACK_NAMES)
    if host not in WILDCARD_HOSTS:
        names.add(host.strip("[]").lower())
    return frozenset(names)


def _is_ip_literal(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def refusal(headers: Any, bound_host: str, port: int | None) -> str | None:
    """Why a request with these HTTP ``headers`` must be refused by a viewer bound to
    ``bound_host:port`` (``None``: accept). ``Host`` must name the viewer (:func:`allowed_hosts`, the
    right port); an ``Origin``, when present, must be ``http://`` + that same host and port."""
    if port is None:
        return "the viewer is starting"
    values = headers.get_all("Host") if hasattr(headers, "get_all") else [headers.get("Host")]
    if len(values) != 1 or not values[0]:
        return "one Host header needed"
    parsed = _split_host(values[0])
    if parsed is None:
        return "malformed Host header"
    name, host_port = parsed
    if (host_port if host_port is not None else 80) != port:
        return f"Host port {host_port} is not this viewer's"
    if name not in allowed_hosts(bound_host) and not (bound_host in WILDCARD_HOSTS and _is_ip_literal(name)):
        return f"Host {name!r} is not this viewer's address"
    origins = headers.get_all("Origin") if hasattr(headers, "get_all") else [headers.get("Origin")]
    origins = [o for o in origins if o is not None]
    if origins:
        if len(origins) != 1 or not origins[0].lower().startswith("http://"):
            return "cross-site Origin"
        if _split_host(origins[0][len("http://") :].rstrip("/")) != parsed:
            return "cross-site Origin"
    return None


def check_listen(host: str, port: int) -> None:
    """Refuse, with a one-line :class:`ConfigError`, an address the viewer could never listen on: a
    port outside 0..65535, a host that does not resolve or is not this machine's, a port it may not
    use. (viser retries the next port on every error and would wait forever when none works; a port
    merely in use is left to that retry, and the URL printed is the port finally bound.)"""
    if not 0 <= int(port) <= 65535:
        raise ConfigError(f"port {port} is not a TCP port (0..65535; 0: any free port)")
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except (socket.gaierror, UnicodeError) as exc:
        raise ConfigError(f"cannot serve on host {host!r}: {getattr(exc, 'strerror', None) or exc}") from None
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise ConfigError(f"cannot serve on {url_host(host)}:{port} ({exc.strerror or exc})") from None


_SERVE_LOCK = threading.Lock()


@contextlib.contextmanager
def _guarded_serving(bound_host: str, port_of: Any) -> Any:
    """While a viser server starts, every websockets server it creates refuses requests that
    :func:`refusal` refuses with HTTP 403 (its ``process_request`` hook, composed with viser's own,
    which serves the client files). Yields a list that holds ``True`` once the hook is in place."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve
    installed: list[bool] = []

    def guarded(handler: Any, *args: Any, process_request: Any = None, **kwargs: Any) -> Any:
        def process(connection: Any, request: Any) -> Any:
            reason = refusal(request.headers, bound_host, port_of())
            if reason is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"skincal viewer: refused ({reason})\n")
            return None if process_request is None else process_request(connection, request)

        installed.append(True)
        return original(handler, *args, process_request=process, **kwargs)

    with _SERVE_LOCK:
        ws_server.serve = guarded
        try:
            yield installed
        finally:
            ws_server.serve = original


def _viser():
    try:
        import viser
    except ImportError:
        raise ConfigError("the 3D viewer needs viser: pip install 'skincal[viz]'") from None
    return viser


def scene_nodes(server: Any) -> dict[str, Any]:
    """The viser scene's handles by node name (``"/robot/link3/live_su1"``), live: viser keeps this lookup
    private and offers no public one, so it is read here alone (for removing a node by name and for
    tests that inspect the scene)."""
    return server.scene._handle_from_node_name  # noqa: SLF001


def _wxyz(R: FloatArray) -> tuple[float, float, float, float]:
    return tuple(float(x) for x in quat_wxyz_from_matrix(R))  # type: ignore[return-value]


@dataclass
class Viewer:
    """A running viewer: the viser server, its URL and the handles the GUI updates."""

    server: Any
    chain: SerialChain
    url: str
    link_frames: list[Any]
    sliders: list[Any]
    recording: Recording | None = None
    poses: dict[str, SkinUnitPose] = field(default_factory=dict)
    time_slider: Any = None
    play_checkbox: Any = None
    urdf: Any = None
    """The ``viser.extras.ViserUrdf`` drawing the URDF's meshes, or ``None`` (capsules)."""
    visuals: UrdfVisuals | None = None
    notes: list[str] = field(default_factory=list)
    """One-line notes for the user (why the robot is drawn as capsules)."""
    live: dict[str, int] = field(default_factory=dict)
    """Live mode: the link each unit is drawn on now (:func:`update_live`)."""
    live_text: Any = None
    """Live mode: the markdown handle of the status line."""
    _stop: threading.Event = field(default_factory=threading.Event)
    _quiet: bool = False
    _moving: threading.Lock = field(default_factory=threading.Lock)
    """Held while the robot moves: the playback thread and slider callbacks both move it, and the
    URDF's scene graph is not safe to update from two threads at once."""

    def set_joints(self, q: FloatArray) -> None:
        """Move the robot (and its units) to joint angles ``q`` ``(n,)``, rad."""
        q = np.asarray(q, dtype=float)
        T = self.chain.link_frames(q[None, :])[0]
        with self._moving, self.server.atomic():
            for handle, T_i in zip(self.link_frames, T, strict=True):
                handle.position = T_i[:3, 3]
                handle.wxyz = _wxyz(T_i[:3, :3])
            if self.urdf is not None and self.visuals is not None:
                self.urdf.update_cfg(self.visuals.configuration(q))

    def close(self) -> None:
        """Stop playback and the server."""
        self._stop.set()
        with contextlib.redirect_stdout(io.StringIO()):  # viser announces the stop on stdout
            self.server.stop()


def _add_urdf(server: Any, visuals: UrdfVisuals) -> Any:
    """Draw the URDF's visual geometry under ``/robot/urdf`` (see the module docstring); the ``ViserUrdf``."""
    from viser.extras import ViserUrdf

    T = visuals.T_base_root
    root = server.scene.add_frame("/robot/urdf", show_axes=False, wxyz=_wxyz(T[:3, :3]), position=T[:3, 3])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return ViserUrdf(
                server, visuals.urdf, root_node_name="/robot/urdf", mesh_color_override=(*ROBOT_COLOR, ROBOT_OPACITY)
            )
    except BaseException:
        root.remove()  # and whatever was drawn under it
        raise


def _add_robot(
    server: Any, chain: SerialChain, visuals: UrdfVisuals | None = None, notes: list[str] | None = None
) -> tuple[list[Any], Any]:
    """The link frames, and the ``ViserUrdf`` when ``visuals`` are drawn (else the capsules are; a
    failure to draw ``visuals`` is a line in ``notes``)."""
    frames = []
    for i in range(chain.n_joints + 1):
        frames.append(server.scene.add_frame(f"/robot/link{i}", show_axes=False))
    if visuals is not None:
        try:
            return frames, _add_urdf(server, visuals)
        except Exception as exc:  # noqa: BLE001 - any geometry viser cannot show: capsules instead
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            if notes is not None:
                notes.append(f"robot drawn as capsules: the URDF's meshes cannot be shown ({first[:200]})")
    for k, cap in enumerate(link_capsules(chain)):
        base = f"/robot/link{cap.link}/capsule{k}"
        T, length = cylinder_pose(cap)
        if length > 0:
            server.scene.add_cylinder(
                f"{base}/cyl", radius=cap.radius, height=length, color=ROBOT_COLOR, opacity=ROBOT_OPACITY,
                wxyz=_wxyz(T[:3, :3]), position=T[:3, 3], cast_shadow=False,
            )
        for j, p in enumerate((cap.p0, cap.p1) if length > 0 else (cap.p0,)):
            server.scene.add_icosphere(
                f"{base}/end{j}", radius=cap.radius, color=ROBOT_COLOR, opacity=ROBOT_OPACITY, position=p,
                cast_shadow=False,
            )
    return frames, None


def _add_unit(
    server: Any, name: str, pose: SkinUnitPose, color: tuple[int, int, int], tag: str, axes: float, wireframe: bool
) -> None:
    """A unit board (its top face at the unit origin, +z out of the skin) with its axes."""
    base = f"/robot/link{pose.link}/{tag}_{name}"
    q = _wxyz(pose.R_link_su)
    server.scene.add_frame(base, axes_length=axes, axes_radius=0.0025, wxyz=q, position=pose.p_link_su)
    server.scene.add_box(f"{base}/board", color=color, dimensions=UNIT_BOX_M, position=(0.0, 0.0, -UNIT_BOX_M[2] / 2),
                         wireframe=wireframe)


def build_scene(
    server: Any,
    result: CalibrationResult,
    chain: SerialChain,
    truth: dict[str, SkinUnitPose] | None = None,
    q0: FloatArray | None = None,
    visuals: UrdfVisuals | None = None,
    notes: list[str] | None = None,
) -> tuple[list[Any], dict[str, float], Any]:
    """Draw the robot (capsules, or ``visuals``: the URDF's meshes), the units and their uncertainty
    on ``server``; return the link-frame handles, the position error (mm) of each unit with truth
    and the ``ViserUrdf`` (``None`` with capsules)."""
    check_result_robot(result, chain)
    server.scene.set_up_direction("+z")
    server.scene.add_grid("/ground", width=2.0, height=2.0, cell_size=0.1, section_size=0.5)
    frames, urdf = _add_robot(server, chain, visuals, notes)
    q_ref = np.zeros(chain.n_joints) if q0 is None else np.asarray(q0, dtype=float)
    errors: dict[str, float] = {}
    for name, unit in result.units.items():
        _add_unit(server, name, unit.pose, ESTIMATE_COLOR, "est", 0.04, wireframe=False)
        semi, unknown = ellipsoid_semi_axes(unit.position_std_m)
        server.scene.add_icosphere(
            f"/robot/link{unit.pose.link}/sigma_{name}", radius=1.0, scale=tuple(semi), subdivisions=2,
            color=(230, 120, 30) if unknown.any() else ELLIPSOID_COLOR, opacity=0.3, position=unit.pose.p_link_su,
            cast_shadow=False,
        )
        if truth is not None and name in truth:
            err_mm, _, _ = pose_errors(chain, q_ref, unit.pose, truth[name])
            errors[name] = err_mm
            _add_unit(server, name, truth[name], error_color(err_mm), "true", 0.025, wireframe=True)
    return frames, errors, urdf


def _add_playback(viewer: Viewer) -> None:
    server, rec = viewer.server, viewer.recording
    assert rec is not None
    folder = server.gui.add_folder("Playback")
    with folder:
        t_slider = server.gui.add_slider("time [s]", rec.t_start, rec.t_end, 0.01, rec.t_start)
        playing = server.gui.add_checkbox("play", False)
        speed = server.gui.add_slider("speed", 0.1, 4.0, 0.1, 1.0)
    spheres = {
        name: server.scene.add_icosphere(f"/play/obstacles/{name}", radius=tr.radius, color=OBSTACLE_COLOR, opacity=0.6)
        for name, tr in rec.obstacles.items()
    }

    def show(t: float) -> None:
        q = rec.q_at(t)
        viewer._quiet = True  # move the sliders along without each one redrawing the robot
        try:
            for s, value in zip(viewer.sliders, np.degrees(q), strict=True):
                s.value = float(value)
        finally:
            viewer._quiet = False
        viewer.set_joints(q)
        origins, points, _ = tof_points_base(viewer.chain, viewer.poses, rec, t - POINT_TRAIL_S, t)
        latest = tof_points_base(viewer.chain, viewer.poses, rec, t - 0.05, t)
        with server.atomic():
            if len(points):
                server.scene.add_point_cloud("/play/points", points, POINT_COLOR, point_size=0.012)
            if len(latest[0]):
                segs = np.stack([latest[0], latest[1]], axis=1)
                server.scene.add_line_segments("/play/rays", segs, RAY_COLOR, thickness=0.003)
            for name, p in rec.obstacle_positions(t).items():
                spheres[name].position = p

    t_slider.on_update(lambda _e: show(float(t_slider.value)))
    viewer.time_slider, viewer.play_checkbox = t_slider, playing

    def loop() -> None:
        period = 1.0 / PLAYBACK_FPS
        while not viewer._stop.wait(period):
            if playing.value:
                t = float(t_slider.value) + period * float(speed.value)
                t_slider.value = rec.t_start if t > rec.t_end else t

    threading.Thread(target=loop, name="skincal-viewer-playback", daemon=True).start()
    show(rec.t_start)


def start_viewer(
    result: CalibrationResult,
    chain: SerialChain,
    *,
    truth: dict[str, SkinUnitPose] | None = None,
    recording: Recording | None = None,
    host: str = "127.0.0.1",
    port: int = 0,
    q0: FloatArray | None = None,
    meshes: MeshResolver | None = None,
) -> Viewer:
    """Start a viser server on ``host:port`` (``port=0``: any free port) showing ``result`` on
    ``chain``; returns at once (the server runs in its own threads). ``q0`` ``(n,)`` rad is the
    initial posture (default: the recording's first sample, else zeros). A URDF robot
    (``chain.source``) is drawn with its visual meshes as ``meshes`` resolves them (default: a
    resolver without folders, which finds none); when they do not resolve, as capsules with a note
    in :attr:`Viewer.notes`."""
    viser = _viser()
    check_listen(host, port)
    notes: list[str] = []
    visuals = None
    if chain.source is not None:
        try:
            visuals = urdf_visuals(chain, meshes if meshes is not None else MeshResolver())
        except MeshRefused as exc:
            notes.append(f"robot drawn as capsules: {exc}")
    bound: dict[str, int] = {}  # the port, once known: requests before that are refused
    with _guarded_serving(host, lambda: bound.get("port")) as installed:
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner; the CLI prints the URL
            server = viser.ViserServer(host=host, port=port, verbose=False)
    bound["port"] = int(server.get_port())
    try:
        if not installed:  # fail closed: a viser that no longer serves through websockets.asyncio.server.serve
            raise ConfigError("cannot guard this viser version's server against cross-site access; not serving")
        server.gui.configure_theme(show_share_button=False)  # sharing would tunnel through a public relay
        # No image-based lighting: plain lights render at once (also in software WebGL) and look the same
        # on every machine.
        server.scene.configure_environment_map(hdri=None)
        server.scene.add_light_hemisphere("/light", sky_color=(255, 255, 255), ground_color=(120, 120, 130),
                                          intensity=1.6)
        if q0 is None:
            q0 = recording.q[0] if recording is not None else np.zeros(chain.n_joints)
        frames, errors, urdf = build_scene(server, result, chain, truth, q0, visuals, notes)
        server.initial_camera.position = CAMERA_POSITION
        server.initial_camera.look_at = CAMERA_LOOK_AT
        server.initial_camera.fov = np.radians(CAMERA_FOV_DEG)
        url = viewer_url(host, bound["port"])
        viewer = Viewer(server, chain, url, frames, [], recording, {n: u.pose for n, u in result.units.items()},
                        urdf=urdf, visuals=visuals if urdf is not None else None, notes=notes)
        _add_gui(viewer, result, errors, np.asarray(q0, dtype=float))
        if recording is not None:
            _add_playback(viewer)
    except BaseException:
        server.stop()
        raise
    return viewer


def _markdown_literal(text: str) -> str:
    """``text`` shown as is in a viser markdown element: every markdown and HTML sign backslash-escaped."""
    return "".join("\\" + ch if ch in "\\`*_{}[]()<>#+-.!|~" else ch for ch in text)


LIVE_REACHED_COLOR = (40, 190, 80)
"""Live mode: a unit (and its ellipsoid) at its target."""
LIVE_ELLIPSOID_FLOOR_M = 2e-4
"""Live mode: smallest semi-axis drawn, m (below the result view's floor, so that the ellipsoids are
seen shrinking to a 0.3 mm target)."""


def start_live_viewer(
    chain: SerialChain,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    q0: FloatArray | None = None,
    meshes: MeshResolver | None = None,
) -> Viewer:
    """A viewer of ``chain`` without a result yet: the units appear and converge as :func:`update_live`
    is given the streaming calibrator's status (``skincal view --follow``)."""
    empty = CalibrationResult("online", chain.name, "", 0.0, {})
    viewer = start_viewer(empty, chain, host=host, port=port, q0=q0, meshes=meshes)
    viewer.live_text = viewer.server.gui.add_markdown("waiting for the first estimates")
    return viewer


def update_live(viewer: Viewer, statuses: Any, q: FloatArray | None = None, text: str | None = None) -> None:
    """Draw each unit of ``statuses`` (unit name -> :class:`skincal.calib.online.UnitStatus`, read by
    attribute) at its current estimate on its best link with its 3-sigma ellipsoid, remove a unit
    drawn on another link before, move the robot to ``q`` ``(n,)`` rad and show ``text`` (plain text)
    in the GUI. Units without a pose yet are not drawn."""
    server = viewer.server
    with server.atomic():
        for name, status in statuses.items():
            pose = status.pose
            if pose is None or not 1 <= int(pose.link) <= viewer.chain.n_joints:
                continue
            link = int(pose.link)
            before = viewer.live.get(name)
            if before is not None and before != link:
                for node in (f"/robot/link{before}/live_{name}", f"/robot/link{before}/live_sigma_{name}"):
                    handle = scene_nodes(server).get(node)
                    if handle is not None:
                        handle.remove()
            viewer.live[name] = link
            reached = bool(status.reached)
            _add_unit(server, name, pose, LIVE_REACHED_COLOR if reached else ESTIMATE_COLOR, "live", 0.04, False)
            semi, unknown = ellipsoid_semi_axes(status.position_std_m, LIVE_ELLIPSOID_FLOOR_M)
            color = (230, 120, 30) if unknown.any() else LIVE_REACHED_COLOR if reached else ELLIPSOID_COLOR
            server.scene.add_icosphere(
                f"/robot/link{link}/live_sigma_{name}", radius=1.0, scale=tuple(semi), subdivisions=2, color=color,
                opacity=0.3, position=pose.p_link_su, cast_shadow=False,
            )  # fmt: skip
    if text is not None and viewer.live_text is not None:
        from skincal.names import printable

        viewer.live_text.content = _markdown_literal(printable(text))
    if q is not None:
        viewer.set_joints(q)


def _add_gui(viewer: Viewer, result: CalibrationResult, errors: dict[str, float], q0: FloatArray) -> None:
    server, chain = viewer.server, viewer.chain
    lines = [f"**{result.method}** on {chain.name}: {len(result.units)} units", ""]
    lines.append("blue box = estimate; wire box = truth, green (0 mm) .. red (10 mm) by position error; "
                 "violet = 3-sigma ellipsoid (orange: unobservable)")
    if errors:
        lines.append("")
        lines += [f"- {n}: {e:.2f} mm" for n, e in errors.items()]
    server.gui.add_markdown("\n".join(lines))
    lower = chain.joint_lower if chain.joint_lower is not None else np.full(chain.n_joints, -np.pi)
    upper = chain.joint_upper if chain.joint_upper is not None else np.full(chain.n_joints, np.pi)
    with server.gui.add_folder("Joints [deg]"):
        for j in range(chain.n_joints):
            lo, hi = round(float(np.degrees(lower[j])), 1), round(float(np.degrees(upper[j])), 1)
            init = float(np.clip(np.degrees(q0[j]), lo, hi))
            viewer.sliders.append(server.gui.add_slider(f"q{j + 1}", lo, hi, 0.5, init))

    def on_slider(_event: Any) -> None:
        if viewer._quiet:
            return
        viewer.set_joints(np.radians([s.value for s in viewer.sliders]))

    for s in viewer.sliders:
        s.on_update(on_slider)
    viewer.set_joints(q0)


def serve_forever(viewer: Viewer, poll_s: float = 0.5, duration: float | None = None) -> None:
    """Block until interrupted (Ctrl-C) or, with ``duration``, for that many seconds; then stop the server."""
    try:
        if duration is not None:
            time.sleep(max(0.0, duration))
        while duration is None:
            time.sleep(poll_s)
    finally:
        viewer.close()
