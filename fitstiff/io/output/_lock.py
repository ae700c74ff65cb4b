"""The lock of an output directory (``.fitstiff.lock`` with the writer's pid): one writer at a
time, a stale lock of a dead process taken over, no lock left behind by an error the process
survived; the directory made with the parents it needs."""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import os
from pathlib import Path


from fitstiff.errors import InputError
from fitstiff.io.output._files import NO_ROOM

__all__ = ["LOCK_NAME"]

LOCK_NAME = ".fitstiff.lock"


# -- the lock -----------------------------------------------------------------------------
@dataclasses.dataclass
class _Lock:
    key: str
    fd: int
    count: int = 1


_HELD: dict[str, _Lock] = {}        # this process's locks by real directory path


def _acquire(directory: Path) -> tuple[_Lock, bool]:
    """The exclusive lock of ``directory`` (nested claims of one process share it); whether
    this call took it."""
    key = os.path.realpath(directory)
    held = _HELD.get(key)
    if held is not None:
        held.count += 1
        return held, False
    path = os.path.join(key, LOCK_NAME)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise _unwritable(directory, exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise InputError(None, f"--out {directory} is in use by pid {pid}",
                             "(another fitstiff run writes there)",
                             "wait for it to finish, or give another --out directory") from None
        # the previous holder may have removed the file between our open and flock
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    except OSError as exc:          # no room for the pid (a full disk): leave no lock behind
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)
        raise _unwritable(directory, exc) from None
    lock = _Lock(key, fd)
    _HELD[key] = lock
    return lock, True


def _release(lock: _Lock) -> None:
    lock.count -= 1
    if lock.count > 0:
        return
    with contextlib.suppress(OSError):
        os.unlink(os.path.join(lock.key, LOCK_NAME))     # still holding it: no one else can
    os.close(lock.fd)
    _HELD.pop(lock.key, None)


def _unwritable(directory: Path, exc: OSError) -> InputError:
    return InputError(str(directory), "--out", f"is not writable ({exc.strerror})",
                      "free some space on its device and run again" if exc.errno in NO_ROOM
                      else "give a directory you can write to")


def _make_directory(path: Path) -> list[Path]:
    """Create ``path`` and missing parents; the directories created (deepest last)."""
    if path.is_dir():
        return []
    if path.exists() or path.is_symlink():
        raise InputError(str(path), "--out", "is an existing file, not a directory",
                         "give a directory path")
    missing = []
    parent = path
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(str(path), "--out", f"cannot be created: {parent} is a file, not a "
                         "directory", "give a path below a directory")
    try:
        path.mkdir(parents=True)
    except FileExistsError:        # made by someone else meanwhile
        return []
    except OSError as exc:
        raise InputError(str(path), "--out", f"cannot be created in {parent} ({exc.strerror})",
                         "give a directory you can write to") from None
    return missing[::-1]
