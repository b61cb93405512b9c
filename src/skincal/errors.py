"""The one error family of skincal.

Library code raises these with the file, field or unit named in the message; only the CLI turns
them into a one-line message and a non-zero exit code.
"""

from __future__ import annotations


class SkincalError(Exception):
    """Base class of every error skincal raises on purpose."""


class ConfigError(SkincalError, ValueError):
    """Bad user input: unknown robot, method or preset, malformed chain, bad option value."""


class DatasetError(SkincalError, ValueError):
    """A dataset or result file is missing, truncated, of the wrong version or fails validation."""


class ProtocolError(SkincalError, ValueError):
    """A data-collection protocol violates joint position or velocity limits, or is malformed."""


class CalibrationError(SkincalError, RuntimeError):
    """Calibration cannot run on the given data (for one unit or for all)."""


def first_line(exc: BaseException) -> str:
    """The first line of a foreign exception's message (its type name when empty), for a one-line error."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
