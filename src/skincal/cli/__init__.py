"""The ``skincal`` command: a thin typer layer over the packages.

Each command group lives in its own module of this package and registers itself on :data:`app`;
add a module and one import line below. Library errors (:class:`skincal.SkincalError`) become a
one-line message on stderr and exit code 2; no traceback reaches the user.
"""

from __future__ import annotations

import importlib
import os
import sys

from skincal.cli import avoid as _avoid  # noqa: E402,F401
from skincal.cli import bench_robustness as _bench_robustness  # noqa: E402,F401
from skincal.cli import benchmark as _benchmark  # noqa: E402,F401
from skincal.cli import calibrate as _calibrate  # noqa: E402,F401
from skincal.cli import demo as _demo  # noqa: E402,F401
from skincal.cli import hw as _hw  # noqa: E402,F401

# Command modules register themselves on import (one line each).
from skincal.cli import info as _info  # noqa: E402,F401
from skincal.cli import io as _io  # noqa: E402,F401
from skincal.cli import protocol as _protocol  # noqa: E402,F401
from skincal.cli import ros2 as _ros2  # noqa: E402,F401
from skincal.cli import simulate as _simulate  # noqa: E402,F401
from skincal.cli import viz as _viz  # noqa: E402,F401
from skincal.cli.app import app, console_error
from skincal.cli.signals import Terminated, unwinds

__all__ = ["Terminated", "app", "main"]


def _click_exceptions() -> tuple[tuple[type, ...], tuple[type, ...], tuple[type, ...]]:
    """``(ClickException, Abort, NoArgsIsHelpError)`` classes of every click that may raise: typer
    ships its own copy (``typer._click``) besides the separately installed one."""
    modules = []
    for name in ("typer._click.exceptions", "click.exceptions"):
        try:
            modules.append(importlib.import_module(name))
        except ImportError:
            continue
    pick = lambda attr: tuple(getattr(m, attr) for m in modules if hasattr(m, attr))  # noqa: E731
    return pick("ClickException"), pick("Abort"), pick("NoArgsIsHelpError")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    try:
        with unwinds():
            return _run(argv)
    except Terminated as exc:  # between the command's end and the handler's removal, or pending then
        console_error("terminated")
        return int(exc.code)
    except KeyboardInterrupt:
        console_error("interrupted")
        return 130


def _run(argv: list[str] | None) -> int:
    from skincal.errors import SkincalError
    from skincal.io.atomic import forget_claims

    forget_claims()  # an earlier command of this process (tests, a notebook) claimed its own outputs
    try:
        code = app(args=argv, prog_name="skincal", standalone_mode=False)
    except SkincalError as exc:
        console_error(str(exc))
        return 2
    except Terminated as exc:
        console_error("terminated")
        return int(exc.code)
    except KeyboardInterrupt:
        console_error("interrupted")
        return 130
    except OSError as exc:
        console_error(f"{getattr(exc, 'filename', '') or ''}: {exc.strerror or exc}".lstrip(": "))
        return 2
    except SystemExit as exc:  # typer/click usage errors and explicit exits
        return int(exc.code or 0) if isinstance(exc.code, int) else 1
    except Exception as exc:  # click's own exceptions (bad option, missing argument)
        usage, abort, no_args = _click_exceptions()
        if isinstance(exc, no_args):  # bare `skincal` or a group without its command: help was shown
            return 2
        if isinstance(exc, usage):
            exc.show()
            return exc.exit_code
        if isinstance(exc, abort):
            console_error("aborted")
            return 1
        if os.environ.get("SKINCAL_DEBUG"):
            raise
        console_error(f"internal error ({type(exc).__name__}: {exc}); rerun with SKINCAL_DEBUG=1 for a traceback")
        return 3
    # standalone_mode=False: typer returns the code of an explicit exit (typer.Exit) and turns Ctrl-C
    # into exit code 130; a command that simply ends returns None
    if isinstance(code, int) and not isinstance(code, bool):
        if code == 130:
            console_error("interrupted")
        return code
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
