"""The entry of the scripts in ``benchmarks/``: library errors as one line on stderr and exit code 2, as the
``skincal`` command does (no traceback for bad input)."""

from __future__ import annotations

import sys
from collections.abc import Callable


def run_script(main: Callable[[], object]) -> int:
    """Call ``main()``; a :class:`~skincal.errors.SkincalError` becomes ``error: <message>`` and exit code 2,
    Ctrl-C exit code 130."""
    from skincal.errors import SkincalError
    from skincal.names import printable

    try:
        main()
    except SkincalError as exc:
        print(f"error: {printable(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    return 0
