"""The typer application object and the console helpers every command shares."""

from __future__ import annotations

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
    from skincal.data.names import printable

    err_console.print(f"error: {printable(message)}", markup=False, highlight=False, soft_wrap=True)
