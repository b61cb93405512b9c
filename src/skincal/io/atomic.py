"""Atomic file replacement: write a temporary file next to the target, fsync it, then rename.

A reader of the target sees either the old complete file or the new complete file, never a
half-written one; a crash or an exception while writing leaves the old file untouched and no
temporary file behind. A process killed outright (SIGKILL, power cut) cannot clean up: its temporary
``.<name>.<pid>.<hex>.tmp`` carries the writer's pid, and the next :func:`atomic_path` for the same
target removes such debris of writers that are no longer alive.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import stat
from collections.abc import Iterator
from pathlib import Path


def _fsync_path(path: Path, directory: bool = False) -> None:
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        if directory:  # some platforms cannot open directories; the rename is still atomic
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not directory:
            raise
    finally:
        os.close(fd)


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (POSIX; elsewhere every pid counts as alive,
    so nothing is ever removed: ``os.kill(pid, 0)`` would terminate it on Windows)."""
    if pid == os.getpid():
        return True
    if os.name != "posix" or pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: someone else's live process
        return True
    return True


def remove_debris(target: str | Path, *, folders: bool = False) -> list[Path]:
    """Remove the temporaries ``.<name>.<pid>.<hex>.tmp`` that writers of ``target`` which are no
    longer alive left next to it (killed before they could clean up); returns the removed paths.
    Temporaries of live writers (and of other targets) are left alone. ``folders``: the target is a
    folder (a ROS 2 bag) written as a temporary folder of that name; such folders are removed too."""
    target = Path(target)
    directory = target.parent if str(target.parent) else Path(".")
    pattern = re.compile(rf"\.{re.escape(target.name)}\.(\d+)\.[0-9a-f]+\.tmp")
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match is None or _pid_alive(int(match.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
            elif folders and entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
                removed.append(Path(entry.path))
    return removed


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a fresh temporary path in ``path``'s directory; on clean exit replace ``path`` with it.

    The caller writes and closes the temporary file inside the ``with`` block. Afterwards it is
    fsynced and moved onto ``path`` with :func:`os.replace` (atomic on POSIX and Windows; an output that
    :func:`check_output` claimed as new is linked there only if still absent, :func:`_commit_new`), and the
    directory is fsynced so the rename survives a power cut. If the block raises, the temporary is
    removed and ``path`` keeps its previous contents. The temporary is created empty with the usual
    permissions (``0o666`` minus the umask) so the final file is not private by accident. Its name
    ``.<name>.<pid>.<hex>.tmp`` carries this process's pid; debris of dead writers of the same
    target is removed first (:func:`remove_debris`). A target that is a folder, a FIFO, a device or
    anything else but a regular file, or in a folder that does not exist or cannot be written, is
    refused with a one-line :class:`~skincal.errors.ConfigError`
    (callers that do work before writing should call :func:`check_output` first).
    """
    from skincal.errors import ConfigError

    target = Path(path)
    directory = target.parent if str(target.parent) else Path(".")
    _check_name_length(target)
    if target.is_dir():  # os.replace would fail only after all the writing, naming the temporary
        raise ConfigError(f"{target} is a folder; give a file name")
    _refuse_special(target)
    remove_debris(target)
    tmp = directory / f".{target.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
    # the name is this process's alone (its pid, 48 random bits): whatever ends the block from here on,
    # even a signal's exception right after the file was made, removes it
    try:
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileNotFoundError:
            raise ConfigError(f"{target}: the folder {directory} does not exist") from None
        except OSError as exc:
            raise ConfigError(f"{target}: cannot write in {directory} ({exc.strerror or exc})") from None
        os.close(fd)
        yield tmp
        _fsync_path(tmp)
        key = os.path.abspath(target)
        if key in _CLAIMED:
            _commit_new(tmp, target)
            _CLAIMED.discard(key)
        else:
            os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):  # absent (never made), or not removable: the error says why
            os.unlink(tmp)
        raise
    _fsync_path(directory, directory=True)


_CLAIMED: set[str] = set()
"""Absolute paths of outputs that :func:`check_output` found absent without ``force``: the command
claimed them as new files, so :func:`atomic_path` does not replace one that appeared while it ran
(the CLI forgets them at each command's start, :func:`forget_claims`)."""


def forget_claims() -> None:
    """Forget the outputs claimed by earlier :func:`check_output` calls of this process."""
    _CLAIMED.clear()


def release_claim(path: str | Path) -> None:
    """The command created ``path`` itself (a recorder's live file, made exclusively): its later writes
    through :func:`atomic_path` replace it."""
    _CLAIMED.discard(os.path.abspath(path))


def _commit_new(tmp: Path, target: Path) -> None:
    """Move ``tmp`` to ``target`` only if ``target`` still does not exist (a hard link fails on an existing
    name: the test and the move are one step). If it appeared meanwhile it keeps its contents; the output
    is linked to the first free ``<stem>-<n><suffix>`` beside it and a :class:`ConfigError` names both (the
    caller's clean-up then removes ``tmp``). A file system without hard links falls back to a test, then
    the rename."""
    from skincal.errors import ConfigError

    try:
        os.link(tmp, target, follow_symlinks=False)
    except FileExistsError:
        kept = None
        for n in range(1, 1000):
            alt = target.with_name(f"{target.stem}-{n}{target.suffix}")
            try:
                os.link(tmp, alt, follow_symlinks=False)
            except FileExistsError:
                continue
            except OSError:
                break
            kept = alt
            break
        where = f"this command's output is in {kept}" if kept is not None else "this command's output was not kept"
        raise ConfigError(f"{target} appeared while this command ran and was not overwritten; {where}") from None
    except OSError:  # no hard links here (some network and FAT file systems)
        if os.path.lexists(target):
            raise ConfigError(f"{target} appeared while this command ran and was not overwritten") from None
        os.replace(tmp, target)
        return
    os.unlink(tmp)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _refuse_special(target: Path) -> None:
    """Refuse ``target`` when it exists and is not a regular file or a folder (a FIFO, a character
    or block device, a socket), following symlinks: only regular files are ever replaced."""
    from skincal.errors import ConfigError

    try:
        mode = os.stat(target).st_mode
    except OSError:  # absent (or a dangling symlink, which the rename replaces): nothing to protect
        return
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return
    kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")  # fmt: skip
    raise ConfigError(f"{target} is {kind}; outputs are regular files only (never replaced, even with --force)")


TEMP_NAME_EXTRA = len(".") + len(".") + 7 + len(".") + 12 + len(".tmp")
"""Bytes the temporary ``.<name>.<pid>.<hex>.tmp`` adds to a file name (a pid of up to 7 digits: Linux's
``pid_max`` is at most 4194304)."""


def _check_name_length(target: Path) -> None:
    """Refuse a file name that the folder's file system cannot hold, or whose temporary it cannot (its
    ``NAME_MAX``, 255 bytes where it cannot be asked): caught before any work, not at the rename."""
    from skincal.errors import ConfigError

    directory = target.parent if str(target.parent) else Path(".")
    try:
        name_max = int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):  # no such folder (refused elsewhere), no pathconf (Windows)
        name_max = 255
    size = len(os.fsencode(target.name))
    if size + TEMP_NAME_EXTRA > name_max:
        raise ConfigError(
            f"{target}: the file name is {size} bytes; the file system here allows {name_max} and the temporary "
            f"written first adds {TEMP_NAME_EXTRA}: give a name of at most {name_max - TEMP_NAME_EXTRA} bytes"
        )


def check_output(path: str | Path, *, force: bool = False, inputs: tuple[str | Path, ...] = ()) -> Path:
    """Refuse an output path before any work is done, with a one-line :class:`ConfigError`:
    one of the command's ``inputs`` (the same file after resolving symlinks and hard links; never
    overwritten, even with ``force``), an existing file unless ``force``, a directory, anything else
    that is not a regular file (a FIFO, a device node such as ``/dev/null``, a socket: the rename of
    :func:`atomic_path` would replace it with a regular file, so ``force`` never applies to it), a
    file in a folder that does not exist, or a name too long for the file system with its temporary.
    Without ``force`` the absent output is claimed as new: a file another process puts there while this
    one works is not replaced by :func:`atomic_path` at the end (the output goes beside it, named in
    the error)."""
    from skincal.errors import ConfigError

    out = Path(path)
    _check_name_length(out)
    for source in inputs:
        with contextlib.suppress(OSError):
            if Path(source).exists() and out.exists() and os.path.samefile(out, source):
                raise ConfigError(f"{out} is the input {source}; write the output to another file")
    if out.is_dir():
        raise ConfigError(f"{out} is a folder; give a file name")
    _refuse_special(out)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ConfigError(f"{out}: the folder {parent} does not exist")
    if out.exists() and not force:
        raise ConfigError(f"{out} exists; pass --force to overwrite it")
    key = os.path.abspath(out)
    if force or os.path.lexists(out):  # may be replaced (a dangling symlink is, as before)
        _CLAIMED.discard(key)
    else:
        _CLAIMED.add(key)
    return out
