""":class:`OutputDir`: claim a directory, lock it, stage every output and commit them with their
manifest last, or discard them on an error or a signal."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path


from fitstiff.interrupts import Interrupted, pending
from fitstiff.errors import InputError
from fitstiff.io.guards import first_nonfinite
from fitstiff.io.output._files import _give_mode, _real, sha256_file, to_jsonable
from fitstiff.io.output._lock import _Lock, _acquire, _make_directory, _release, _unwritable
from fitstiff.io.output._records import (_MAIN_MANIFEST, _MANIFEST_SUFFIX, _Record, _log_companions,
                                         _read_manifest, _records)

__all__ = ["OutputDir"]

STAGING_PREFIX = ".fitstiff-partial-"
_FIX = "give another --out directory (a new or empty one)"


_COUNTER = itertools.count()


class OutputDir:
    """An output directory that is claimed before work, locked, and written all or nothing.

    >>> with OutputDir("results", inputs=["run1.csv", "run1.json"], planned=["fit.json"],
    ...                command="fit", seed=0) as out:            # doctest: +SKIP
    ...     result = ...                                          # the computation
    ...     out.write_json("fit.json", result)
    ...     out.finish()

    Args:
        path: the directory (created by :meth:`claim` when missing).
        inputs: files the run reads (recorded with their SHA-256, never written).
        planned: names (relative to ``path``) the run will write; checked by :meth:`claim`
            before any computation. A name ending in ``/`` is a directory the run fills.
            Names written without being planned are checked when written.
        command, seed, options: recorded in the manifest.
        manifest_name: the manifest's file name; a command that adds to another run's
            directory (``fitstiff report``) uses its own so that run's ``manifest.json``
            stays. ``None``: a claim that only locks and checks (it writes nothing).
    """

    def __init__(self, path: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
                 planned: Iterable[str] = (), command: str | None = None,
                 seed: int | None = None, options: Mapping[str, object] | None = None,
                 manifest_name: str | None = _MAIN_MANIFEST):
        self.path = Path(path)
        self.manifest_name = manifest_name
        self.inputs = [Path(p) for p in inputs]
        self.planned = tuple(dict.fromkeys(planned))
        self.command = command or " ".join(sys.argv)
        self.seed = seed
        self.options = dict(options or {})
        self.written: list[str] = []
        self._staged: dict[str, Path] = {}
        self._checked: set[str] = set()
        self._lock: _Lock | None = None
        self._created: list[Path] = []
        self._staging: Path | None = None
        self._records: list[_Record] = []
        self._finished = False

    # -- claim -----------------------------------------------------------------------------
    def claim(self) -> OutputDir:
        """Create and lock the directory and check the planned files (before any work).

        Raises:
            InputError: the directory cannot be created or written, another run holds it,
                or a planned file is refused (see the module docstring). Nothing is left
                behind then.
        """
        if self._lock is not None:
            return self
        self._created = _make_directory(self.path)
        try:
            self._lock, fresh = _acquire(self.path)
            if fresh:
                self._probe()
                self._sweep()
            self._records = _records(self.path)
            for name in (*self.planned, *([self.manifest_name] if self.manifest_name else [])):
                self._check(name)
        except BaseException:
            self._discard()
            raise
        return self

    def __enter__(self) -> OutputDir:
        return self.claim()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def close(self) -> None:
        """End the claim: a run that did not :meth:`finish` leaves nothing behind."""
        if not self._finished:
            self._discard()

    def _probe(self) -> None:
        try:
            fd, probe = tempfile.mkstemp(prefix=".fitstiff-probe-", dir=self.path)
        except OSError as exc:
            raise _unwritable(self.path, exc) from None
        os.close(fd)
        os.unlink(probe)

    def _sweep(self) -> None:
        """Remove staging directories of runs that died (we hold the lock: none is live)."""
        for p in self.path.iterdir():
            if p.name.startswith(STAGING_PREFIX) and p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)

    def _discard(self) -> None:
        if self._staging is not None:
            shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None
        self._staged.clear()
        if self._lock is not None:
            _release(self._lock)
            self._lock = None
        for directory in reversed(self._created):
            with contextlib.suppress(OSError):
                directory.rmdir()      # only when empty (never a directory another run holds)
        self._created = []

    # -- checks ----------------------------------------------------------------------------
    def _protected(self) -> dict[Path, str]:
        """Resolved paths this run must not write -> why."""
        out: dict[Path, str] = {}
        for p in self.inputs:
            out.setdefault(_real(p), "is an input of this run")
        for p in self.inputs:
            if p.suffix.lower() != ".json":
                out.setdefault(_real(p.with_suffix(".json")),
                               f"is the sidecar name of the input log {p}")
                out.setdefault(_real(p.with_name(f"{p.stem}.truth.json")),
                               f"is the truth file name of the input log {p}")
        # a run that adds to DIR under a manifest of its own (fitstiff report) reads DIR's
        # results: those stay writable for the next step of the run that made them (a refit,
        # a --resume), which a report must not block. Other inputs stay protected.
        main = [r for r in self._records if r.manifest.name == _MAIN_MANIFEST]
        own = ({_real(self.path / name) for r in main for name in r.outputs}
               | {_real(r.manifest) for r in main})
        for record in self._records:
            adds_on = record.manifest.name != _MAIN_MANIFEST
            for p in record.inputs:
                if not (adds_on and p in own):
                    out.setdefault(p, f"is an input of the run recorded in {record.manifest}")
        return out

    def _refuse(self, target: Path, found: str) -> InputError:
        return InputError(str(target), f"--out {self.path}", found, _FIX)

    def _check(self, name: str) -> None:
        """Refuse writing ``name`` (relative to the directory) unless it is safe."""
        if name in self._checked:
            return
        is_dir = name.endswith("/")
        relative = Path(name.rstrip("/"))
        if relative.is_absolute() or ".." in relative.parts or not relative.parts:
            raise ValueError(f"output name {name!r} must be a relative path inside DIR")
        target = self.path / relative
        protected = self._protected()
        if is_dir:
            if target.is_symlink() or (target.exists() and not target.is_dir()):
                raise self._refuse(target, "is not a directory fitstiff made")
            if target.is_dir():
                for p in sorted(target.rglob("*")):
                    if p.is_file() or p.is_symlink():
                        self._check_existing(p, p.relative_to(self.path).as_posix(), protected)
            self._checked.add(name)
            return
        why = protected.get(_real(target))
        if why:
            raise self._refuse(target, why)
        log = _log_companions(target.parent).get(target.name)
        planned_logs = {Path(n).name for n in self.planned
                        if (self.path / n).parent == target.parent}
        if log is not None and log not in planned_logs:
            kind = "truth file" if target.name.endswith(".truth.json") else "sidecar"
            raise self._refuse(target, f"is the {kind} of the log {target.parent / log}")
        if target.exists() or target.is_symlink():
            self._check_existing(target, relative.as_posix(), protected)
        self._checked.add(name)

    def _check_existing(self, target: Path, name: str, protected: Mapping[Path, str]) -> None:
        """An existing file may be replaced only when fitstiff wrote it and it is unchanged."""
        if target.is_symlink():
            raise self._refuse(target, "is a symbolic link (fitstiff does not write through "
                                       "links)")
        if target.is_dir():
            raise self._refuse(target, "is a directory")
        why = protected.get(_real(target))
        if why:
            raise self._refuse(target, why)
        if name.endswith(_MANIFEST_SUFFIX) and "/" not in name:
            if _read_manifest(target) is None:
                raise self._refuse(target, "exists and is not a fitstiff manifest")
            return
        recorded = [r for r in self._records if name in r.outputs]
        if not recorded:
            raise self._refuse(target, "exists and was not written by fitstiff (no manifest in "
                                       f"{self.path} records it)")
        shas = {r.outputs[name] for r in recorded}
        if None in shas:
            return                      # recorded before fitstiff kept output hashes
        digest = sha256_file(target)
        if digest not in shas:
            where = ", ".join(sorted({str(r.manifest) for r in recorded}))
            raise self._refuse(target, f"has changed since fitstiff wrote it (sha256 "
                                       f"{digest[:12]}... now, {sorted(shas)[0][:12]}... "
                                       f"recorded in {where})")

    # -- writing ---------------------------------------------------------------------------
    def _stage_path(self, name: str) -> Path:
        self.claim()
        self._check(name)
        if self._staging is None:
            self._staging = self.path / f"{STAGING_PREFIX}{os.getpid()}-{next(_COUNTER)}"
            self._staging.mkdir()
        path = self._staging / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def write_bytes(self, name: str, data: bytes | str) -> Path:
        """Stage ``name`` (moved into place by :meth:`finish`); returns its final path."""
        path = self._stage_path(name)
        path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        self._staged[name] = path
        return self.path / name

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
        """A path for writers that need a filename (matplotlib, netCDF); then :meth:`commit`."""
        return self._stage_path(name)

    def partial_path(self, name: str) -> Path:
        """Where ``name`` grows across runs (a resumable chain): ``.<name>.partial<suffix>``
        beside it, kept when a run fails; :meth:`commit_partial` moves it into place."""
        self.claim()
        self._check(name)
        target = self.path / name
        return target.with_name(f".{target.name}.partial{target.suffix}")

    def commit(self, name: str) -> Path:
        """Stage the file written at :meth:`temp_path`; returns its final path."""
        self._staged[name] = self.temp_path(name)
        return self.path / name

    def commit_partial(self, name: str) -> Path:
        """Move the file at :meth:`partial_path` into place at :meth:`finish`."""
        self._staged[name] = self.partial_path(name)
        return self.path / name

    def manifest(self) -> dict:
        """The manifest of the run: what :meth:`finish` writes (the staged files and those
        already moved into place count as outputs)."""
        from fitstiff import __version__

        where = {name: self.path / name for name in self.written} | dict(self._staged)
        outputs = sorted(where)
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
            "outputs": outputs,
            "output_sha256": {name: sha256_file(where[name]) for name in outputs},
            "earlier_runs": self._earlier_runs(set(outputs)),
        }

    def _earlier_runs(self, rewritten: set[str]) -> list[dict]:
        """Records of the manifest being replaced (and its earlier runs) whose outputs are
        still in the directory, unchanged and not rewritten by this run."""
        previous = _read_manifest(self.path / self.manifest_name)
        if previous is None:
            return []
        out = []
        for entry in [previous, *previous.get("earlier_runs", [])]:
            shas = entry.get("output_sha256") or {}
            kept = {}
            for name in entry.get("outputs", []):
                path = self.path / name
                if name in rewritten or not path.is_file() or path.is_symlink():
                    continue
                if shas.get(name) is not None and sha256_file(path) != shas[name]:
                    continue
                kept[name] = shas.get(name)
            if kept:
                record = {k: v for k, v in entry.items() if k != "earlier_runs"}
                record["outputs"] = sorted(kept)
                record["output_sha256"] = {k: v for k, v in kept.items() if v is not None}
                out.append(record)
        return out

    def finish(self) -> Path:
        """Move the staged files into place, write the manifest (last, so its presence marks
        a complete run) and release the directory."""
        self.claim()
        if not self.manifest_name:
            raise ValueError("this OutputDir has no manifest: it only claims the directory")
        if pending() is not None:     # a stop whose exception was lost: commit nothing
            raise Interrupted(pending())
        self._check(self.manifest_name)
        # everything is written (staged) before anything is moved: a full disk fails the run
        # while DIR is as it was; the moves need no room, and the manifest goes last
        manifest = self._stage_path(self.manifest_name)
        manifest.write_text(json.dumps(to_jsonable(self.manifest()), indent=2) + "\n",
                            encoding="utf-8")
        for name, source in self._staged.items():
            target = self.path / name
            target.parent.mkdir(parents=True, exist_ok=True)
            _give_mode(source, target)
            os.replace(source, target)
            self.written.append(name)
        self._staged.clear()
        path = self.path / self.manifest_name
        _give_mode(manifest, path)
        os.replace(manifest, path)
        self._finished = True
        self._created = []                          # keep what we made: it holds results
        self._discard()
        return path
