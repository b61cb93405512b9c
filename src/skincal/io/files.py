"""Input files checked before they are opened, without NumPy or h5py (so a command can refuse a
missing input before it loads the libraries that would read it: the start-up of a failing command).

:func:`regular_file` is the one check of every reader of a user's file (:mod:`skincal.io.jsonio`, the
dataset reader :mod:`skincal.data.hdf5`); :data:`DATASET_FILE` and :data:`RESULT_FILE` are the names
those readers give their files in messages, so the command's early check says what the reader says.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from skincal.errors import DatasetError, SkincalError

DATASET_FILE = "dataset file (.h5)"
"""What a dataset is called in the readers' messages (:func:`skincal.data.hdf5.read_dataset`)."""
RESULT_FILE = "result file (.json)"
"""What a calibration result is called in the readers' messages (:func:`skincal.data.result.read_result`)."""

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def regular_file(path: str | Path, what: str = "file", error: type[SkincalError] = DatasetError) -> int:
    """Size in bytes of ``path`` after checking that it is an existing regular file (symbolic links
    are followed); without opening it, so a FIFO or a device cannot block or stream forever."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: no such file; cannot read the {what}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
        raise error(f"{path}: is {kind}, expected a {what}")
    return int(st.st_size)
