"""Files written safely: a file's hash, JSON-ready values, room on the disk checked before a
write (a full disk ends in one line, not a traceback), modes as the umask gives them, and an
atomic write (a temporary file renamed into place)."""

from __future__ import annotations

import errno
import hashlib
import os
import stat
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np



__all__ = ["NO_ROOM", "ensure_room", "sha256_file", "to_jsonable", "write_atomic"]


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def to_jsonable(obj):
    """Convert numpy / jax scalars and arrays (recursively) to plain JSON types.

    Non-finite floats become ``None`` (JSON has no NaN).
    """
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if hasattr(obj, "shape") and hasattr(obj, "tolist"):
        return to_jsonable(np.asarray(obj).tolist())
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if np.isfinite(f) else None
    return obj


#: errors of the file system that the user resolves: no space, a quota, a file-size limit
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
#: room kept free beyond a write's own size (:func:`ensure_room`): an HDF5 file rewrites its
#: metadata (its writers add the size of the chunks they may allocate)
ROOM_MARGIN = 256 << 10


def ensure_room(directory: str | os.PathLike, nbytes: int, *, what: str) -> None:
    """Raise ``OSError(ENOSPC)`` before ``nbytes`` are written into ``directory`` when its
    file system has less room than that plus :data:`ROOM_MARGIN`. For writers that leave a
    broken file, or crash, when the disk fills in the middle of a write (HDF5: a posterior's
    chain on a full disk ended in a segmentation fault and a file ``--resume`` could not
    read); the file stays as it was after its last complete write."""
    stats = os.statvfs(directory)
    free = stats.f_bavail * stats.f_frsize
    need = int(nbytes) + ROOM_MARGIN
    if free < need:
        raise OSError(errno.ENOSPC, f"No space left on device for {what} ({free / 2**20:.1f} "
                      f"MiB free, {need / 2**20:.1f} MiB needed)", str(directory))


def _real(path: str | os.PathLike) -> Path:
    """The path with its links resolved; a link loop gives a path too (``Path.resolve``
    raised ``RuntimeError: Symlink loop`` there, a traceback for a looped input given with
    ``--out``; the loader then refuses the input in one line)."""
    return Path(os.path.realpath(path))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _give_mode(source: Path, target: Path) -> None:
    """``source`` gets the permission bits of the file it will replace, or those of a new
    file (0666 minus the umask)."""
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    os.chmod(source, mode)


def write_atomic(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename.

    A replaced file keeps its permission bits; a new one gets 0666 minus the umask.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        _give_mode(Path(tmp), path)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
