"""Writing results: atomic file writes and the run manifest (DESIGN §5).

Every command that writes takes ``--out DIR``, writes each file atomically (temporary file in
the same directory, then ``os.replace``), never overwrites an input, and records a
``manifest.json`` in DIR: version, command, inputs with their SHA-256, seed. A JSON result
holds finite numbers only (``None`` where a value is not determined): :meth:`OutputDir.write_json`
refuses one with an inf or NaN in it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from fitstiff.errors import InputError
from fitstiff.guards import first_nonfinite

__all__ = ["OutputDir", "sha256_file", "to_jsonable", "write_atomic"]


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


def write_atomic(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


class OutputDir:
    """An output directory that refuses to overwrite inputs and keeps a manifest.

    >>> out = OutputDir("results", inputs=["run1.csv"], command="fit", seed=0)  # doctest: +SKIP
    >>> out.write_json("fit.json", {...})                                        # doctest: +SKIP
    >>> out.finish()                                                             # doctest: +SKIP

    ``manifest_name`` names the manifest file; a command that adds to another run's directory
    (``fitstiff report``) uses its own name so that run's ``manifest.json`` stays.
    """

    def __init__(self, path: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
                 command: str | None = None, seed: int | None = None,
                 options: Mapping[str, object] | None = None,
                 manifest_name: str = "manifest.json"):
        self.path = Path(path)
        self.manifest_name = manifest_name
        self.inputs = [Path(p) for p in inputs]
        self._protected = {p.resolve() for p in self.inputs if p.exists()}
        if self.path.exists() and not self.path.is_dir():
            raise InputError(str(self.path), "--out", "is an existing file, not a directory",
                             "give a directory path")
        self.path.mkdir(parents=True, exist_ok=True)
        self.command = command or " ".join(sys.argv)
        self.seed = seed
        self.options = dict(options or {})
        self.written: list[str] = []

    def _target(self, name: str) -> Path:
        target = self.path / name
        if target.resolve() in self._protected:
            raise InputError(str(target), "output file", "would overwrite an input",
                             "choose another --out directory")
        return target

    def write_bytes(self, name: str, data: bytes | str) -> Path:
        target = write_atomic(self._target(name), data)
        self.written.append(name)
        return target

    def write_json(self, name: str, obj) -> Path:
        """Write ``obj`` as JSON, after checking that every number in it is finite.

        A result built on an overflow (an inf or NaN anywhere in ``obj``) is refused with an
        :class:`InputError` naming the entry, and nothing is written; a value that is not
        determined must be ``None`` (JSON null), set so by its producer.
        """
        hit = first_nonfinite(obj)
        if hit is not None:
            entry, value = hit
            raise InputError(str(self.path / name), f"entry '{entry}'",
                             f"is {value}, so the result is not written",
                             "a log probably holds extreme values the model cannot follow: "
                             "check each channel's range with fitstiff inspect")
        return self.write_bytes(name, json.dumps(to_jsonable(obj), indent=2, allow_nan=False)
                                + "\n")

    def temp_path(self, name: str) -> Path:
        """A path for writers that need a filename (matplotlib, h5py); commit with :meth:`commit`."""
        target = self._target(name)
        return target.with_name(f".{target.name}.partial{target.suffix}")

    def commit(self, name: str) -> Path:
        target = self._target(name)
        os.replace(self.temp_path(name), target)
        self.written.append(name)
        return target

    def manifest(self) -> dict:
        from fitstiff import __version__

        return {
            "fitstiff_version": __version__,
            "command": self.command,
            "cwd": os.getcwd(),
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "python": sys.version.split()[0],
            "seed": self.seed,
            "options": self.options,
            "inputs": [{"path": str(p), "sha256": sha256_file(p) if p.is_file() else None}
                       for p in self.inputs],
            "outputs": sorted(set(self.written)),
        }

    def finish(self) -> Path:
        """Write the manifest (last, so its presence marks a complete run)."""
        return write_atomic(self._target(self.manifest_name),
                            json.dumps(to_jsonable(self.manifest()), indent=2) + "\n")
