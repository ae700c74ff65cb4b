"""Writing results without destroying anything: claim, lock, stage, commit, manifest (DESIGN §5).

Every command that writes takes ``--out DIR`` and goes through one :class:`OutputDir`:

1. **Claim, before any computation** (:meth:`OutputDir.claim`, or ``with OutputDir(...)``):
   create DIR (or say in one line why it cannot be created or written), take an exclusive
   lock on it, and check every file the run plans to write (``planned``). A planned file is
   refused - :class:`~fitstiff.errors.InputError`, exit 2, nothing written - when it

   - is an input of this run (a log, its sidecar ``<stem>.json``, a format or priors file),
     or would become the sidecar ``<stem>.json`` / truth file ``<stem>.truth.json`` of a log
     in DIR (``*.csv``, ``*.tsv``, ``*.txt``, ``*.dat``, ``*.log``) that the run does not
     write itself, or is an input recorded by a manifest in DIR (except DIR's own results
     that a run adding to DIR under a manifest of its own, ``fitstiff report``, read: they
     stay writable for the refit or ``--resume`` of the run that made them);
   - exists but no fitstiff manifest in DIR records it as an output (a file fitstiff did not
     write), or it has changed since fitstiff wrote it (the manifests record SHA-256), or it
     is a directory or a symbolic link.

   A planned name ending in ``/`` is a directory the run fills (``figures/``): every file
   already in it must be fitstiff's own. fitstiff's own earlier outputs are replaced.

2. **Lock**: ``DIR/.fitstiff.lock`` holds the pid of the run and an ``fcntl.flock`` exclusive
   lock; a second run on DIR stops with ``--out DIR is in use by pid N`` (exit 2). The kernel
   drops the lock when a run dies, so a crashed run never blocks DIR. The lock file is removed
   when the run ends. Claims by one process nest (``fitstiff demo`` claims the directories
   its steps write before running them).

3. **Stage, then commit**: files are written into a private staging directory
   ``DIR/.fitstiff-partial-<pid>-<n>/`` and moved into place (``os.replace``, atomic per file)
   by :meth:`OutputDir.finish`, the manifest (staged with them, so a full disk fails the run
   before anything is moved) last. A signal received meanwhile (:mod:`fitstiff.interrupts`)
   stops :meth:`OutputDir.finish` before it moves anything. A run that fails leaves
   DIR as it was: the staging directory and a DIR it created are removed (a staging directory
   left by a killed run is clearly named and removed by the next run on DIR). Only a
   posterior's growing chain (:meth:`OutputDir.partial_path`, ``.chain.h5.partial.h5``) is
   kept on failure, deliberately, for ``--resume``.

4. **Modes**: a replaced file keeps the permission bits of the file it replaces; a new file
   gets ``0666`` minus the umask, as any program's would.

The manifest (``manifest.json``, or the name given) records version, command, working
directory, seed, options, inputs with SHA-256, ``outputs`` with their SHA-256 and, under
``earlier_runs``, the records of earlier fitstiff runs in DIR whose outputs are still there,
so overwriting a manifest loses no provenance.

A JSON result holds finite numbers only (``None`` where a value is not determined):
:meth:`OutputDir.write_json` refuses one with an inf or NaN in it.
"""

from __future__ import annotations

from fitstiff.io.output._dir import STAGING_PREFIX, OutputDir
from fitstiff.io.output._files import NO_ROOM, ensure_room, sha256_file, to_jsonable, write_atomic
from fitstiff.io.output._lock import LOCK_NAME
from fitstiff.io.output._records import LOG_SUFFIXES

__all__ = ["LOCK_NAME", "LOG_SUFFIXES", "NO_ROOM", "OutputDir", "STAGING_PREFIX", "ensure_room",
           "sha256_file", "to_jsonable", "write_atomic"]
