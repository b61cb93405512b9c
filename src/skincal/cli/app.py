"""The typer application object and the console helpers every command shares."""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

app = typer.Typer(
    name="skincal",
    help="Self-contained kinematic calibration of robot skin units from accelerometers.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

console = Console()
if not console.is_terminal:  # pipes and CI logs: tables wider than rich's 80-column default
    console = Console(width=140)
err_console = Console(stderr=True)


def console_error(message: str) -> None:
    """Print a one-line error to stderr: no markup interpretation of user text, and control
    characters (ESC sequences, newlines) shown escaped so the message stays one line."""
    from skincal.names import printable, shortened

    err_console.print(f"error: {shortened(printable(message))}", markup=False, highlight=False, soft_wrap=True)


def console_warning(message: str) -> None:
    """Print a one-line warning to stderr (kept off stdout, where ``--json`` output goes), escaped as
    :func:`console_error` escapes."""
    from skincal.names import printable, shortened

    err_console.print(f"warning: {shortened(printable(message))}", markup=False, highlight=False, soft_wrap=True)


def require_file(path: Path, what: str) -> None:
    """Refuse a missing or non-regular input file (``what``: :data:`skincal.io.files.DATASET_FILE`, ...) with
    its reader's own one-line message, before the command imports the libraries that would read it: a
    failing command answers at start-up speed (issue 26)."""
    from skincal.errors import DatasetError
    from skincal.io.files import regular_file

    regular_file(path, what, DatasetError)


def shown(text: object) -> str:
    """``text`` (a name, a note, a file name: anything that came from a file or a user) for a rich
    table cell or a markup string: control characters escaped (:func:`skincal.names.printable`)
    and rich markup neutralised, so it shows as stored and cannot restyle or rewrite the terminal."""
    from rich.markup import escape

    from skincal.names import printable

    return escape(printable(str(text)))


def at_rate(traj, rate: float):  # noqa: ANN001, ANN201  (a skincal.protocol.Trajectory)
    """``traj`` sampled at ``rate`` Hz for the controller (the limits were checked at the protocol's 1 kHz):
    :func:`skincal.protocol.trajectory.sampled_at`."""
    from skincal.protocol.trajectory import sampled_at

    return sampled_at(traj, rate)


def joint_names(chain) -> tuple[str, ...]:  # noqa: ANN001
    """The chain's joint names (``joint1``... when it has none)."""
    return tuple(chain.joint_names or tuple(f"joint{i + 1}" for i in range(chain.n_joints)))


def seed_option(value: int) -> int:
    """Option callback of every ``--seed``: a NumPy seed is an integer >= 0, so ``--seed -1`` is a
    one-line usage error (exit 2) before any work, not NumPy's ``ValueError`` deep in a run."""
    if value < 0:
        from skincal.errors import ConfigError

        raise ConfigError(f"--seed {value}: a seed is an integer >= 0")
    return value



class Throttle:
    """A redraw at most every ``period_s`` seconds of wall time (monotonic clock): :meth:`due` says whether
    to draw now (and counts it as drawn); ``force`` draws regardless (the final view)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._wall = -math.inf

    def due(self, force: bool = False) -> bool:
        now = time.monotonic()
        if not force and now - self._wall < self.period_s:
            return False
        self._wall = now
        return True


class Status:
    """What long work is doing: on a terminal rich's transient spinner line on stderr, elsewhere (a pipe,
    a CI log) plain lines on stderr once the work has lasted :data:`QUIET_S`: the message, then each new
    update at most every :data:`QUIET_S`, so that long work is never silent in a log while a command
    that fails at once still prints its one-line error alone. A context manager; :meth:`update` gives
    the new text (user text is escaped by the caller: :func:`shown`)."""

    QUIET_S = 2.0

    def __init__(self, message: str) -> None:
        self.message = message
        self.throttle = Throttle(self.QUIET_S)
        self._status: Any = None
        self._timer: threading.Timer | None = None
        self._line: str | None = None

    def __enter__(self) -> Status:
        if err_console.is_terminal:
            self._status = err_console.status(self.message)
            self._status.__enter__()
        else:
            self.throttle.due(force=True)  # the first update is due QUIET_S after the start
            self._timer = threading.Timer(self.QUIET_S, self._started)
            self._timer.daemon = True
            self._timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._status is not None:
            self._status.__exit__(*exc)
        if self._timer is not None:
            self._timer.cancel()

    def update(self, text: str) -> None:
        if self._status is not None:
            self._status.update(text)
        elif text != self._line and self.throttle.due():
            self._print(text)

    def _started(self) -> None:
        if self._line is None:
            self._print(self.message)

    def _print(self, text: str) -> None:
        self._line = text
        self.throttle.due(force=True)
        err_console.print(text, highlight=False, soft_wrap=True)


class LiveMeter:
    """The live meter of a command that follows a calibration (``calibrate --follow``, ``ros2``): on a
    terminal a rich table redrawn in place, elsewhere one plain line printed when it changes; drawn at
    most every 0.25 s on a terminal, 1 s elsewhere. ``target`` is a ``workflows.live.Target``; a context
    manager (the table is started and stopped with it); :meth:`show` is the ``on_meter`` callback."""

    def __init__(self, target: Any, title: str) -> None:
        from rich.live import Live

        self.target, self.title = target, title
        self.throttle = Throttle(0.25 if console.is_terminal else 1.0)
        self._line: str | None = None
        self.live = Live(console=console, refresh_per_second=4, transient=False) if console.is_terminal else None

    def __enter__(self) -> LiveMeter:
        if self.live is not None:
            self.live.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.stop()

    def show(self, statuses: Any, t_data: float, t_end: float | None, force_draw: bool = False) -> None:
        """Draw the units' ``statuses`` at ``t_data`` (s) of ``t_end`` (None: open-ended); ``force_draw``
        past the throttle (the final view). Without units nothing is printed."""
        from skincal.viz.meter import meter_line, meter_table

        if not self.throttle.due(force_draw):
            return
        goal = self.target
        if self.live is not None:
            self.live.update(meter_table(statuses, goal.position_m, goal.rotation_deg, t_data, t_end, self.title))
        elif statuses:
            line = meter_line(statuses, goal.position_m, goal.rotation_deg, t_data, t_end)
            if line != self._line:
                self._line = line
                console.print(line, markup=False, highlight=False, soft_wrap=True)
