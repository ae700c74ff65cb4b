"""The ``fitstiff`` command line: a thin layer over the library.

Each subcommand lives in its own module ``fitstiff/cli/<name>.py`` exposing
``add_parser(subparsers)`` (which sets ``func`` on its parser). Exit codes: 0 success,
2 bad input or no room to write (one line on stderr, no traceback), 1 internal failure, 130 and
143 when SIGINT or SIGTERM stopped it (one line that says what was kept).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import traceback
import warnings
from pathlib import Path

from fitstiff import __version__
from fitstiff.interrupts import Interrupted, Signals, pending
from fitstiff.malloc import limit_arenas
from fitstiff.errors import InputError

__all__ = ["main", "SUBCOMMANDS"]

# order = order in --help
SUBCOMMANDS = ("inspect", "stiffness", "simulate", "fit", "posterior", "report", "diagnose",
               "plan", "fleet", "demo")


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line with exit code 2."""

    def error(self, message):  # noqa: D401
        sys.stderr.write(f"{self.prog}: error: {message}; see '{self.prog} --help'\n")
        raise SystemExit(2)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or of ``only`` (then only its module is imported:
    ``fitstiff inspect`` does not import JAX, matplotlib or the samplers)."""
    parser = _Parser(prog="fitstiff", description="fitstiff: passive stiffness of pneumatic "
                     "cylinders from force-displacement logs (pre-sliding slope, breakaway, "
                     "the chamber's gas spring), with posteriors and a diagnosis of what a "
                     "model misses. 'fitstiff COMMAND --help' for each command.")
    parser.add_argument("--version", action="version", version=f"fitstiff {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in (only,) if only in SUBCOMMANDS else SUBCOMMANDS:
        importlib.import_module(f"fitstiff.cli.{name}").add_parser(sub)
    return parser


def _enable_compilation_cache() -> None:
    """Persistent JAX compilation cache, so a second run of a command skips compilation.

    ``FITSTIFF_CACHE_DIR`` sets the directory (default ``~/.cache/fitstiff/jax``); an empty
    value turns the cache off. Every compilation is kept, the small ones too: a fit compiles
    about 50 single operations of 15-50 ms each outside its compiled functions (parameter
    transforms, drive set-up), which JAX's default threshold (1 s) and the former 0.2 s left
    to compile again in every run. Kept, a second ``fitstiff fit`` of the benchmark log took
    8.2-8.6 s instead of 9.1-10.4 s (three alternating pairs on a slow host; 0.5 MB of cache).
    """
    path = os.environ.get("FITSTIFF_CACHE_DIR",
                          os.path.join(os.path.expanduser("~"), ".cache", "fitstiff", "jax"))
    if not path:
        return
    if "jax" not in sys.modules:    # read by JAX when (if) the command imports it
        os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", path)
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        return
    from fitstiff._jax import jax

    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


#: numpy's floating-point and empty-reduction warnings (the messages start with these)
_NUMERIC_WARNINGS = (r"(overflow|invalid value|divide by zero|underflow) encountered|"
                     r"Mean of empty slice|Degrees of freedom|All-NaN slice")


def _numeric_message(args: argparse.Namespace, exc: RuntimeWarning) -> str:
    """One line for a floating-point warning turned error: the inputs, the operation and
    where in fitstiff it happened, and what to check."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if f"{os.sep}fitstiff{os.sep}" in f.filename]
    at = ""
    if ours:
        frame = ours[-1]
        at = f" in {Path(frame.filename).name}:{frame.lineno}"
    inputs = ", ".join(str(p) for p in (getattr(args, "logs", None) or [])) or "the input"
    message = " ".join(str(exc).split())
    return (f"{inputs}: numerical problem: {message}{at}; the data or rig values are too "
            "extreme to compute with: check each channel's range and the rig metadata with "
            "fitstiff inspect")


def console(argv: list[str] | None = None) -> int:
    """The ``fitstiff`` command (and ``python -m fitstiff``): :func:`main` with JAX's
    persistent compilation cache on. The cache is a setting of the process, so it belongs to
    the command, not to :func:`main`, which scripts, notebooks and tests call in processes
    that live long: every executable JAX loads back from the cache keeps its memory maps in
    JAX's in-memory caches, and a test-suite worker that had turned it on by calling
    :func:`main` passed the kernel's limit on maps and segfaulted loading one more.

    A signal before :func:`main` installs its handlers, or after it returned (while the
    interpreter shuts down), ends the process with one line and the signal's code too."""
    try:
        _enable_compilation_cache()    # imports nothing: JAX reads it when a command imports it
        status = main(argv)
    except KeyboardInterrupt:
        sys.stderr.write("fitstiff: interrupted by SIGINT; nothing was written\n")
        status = 130
    for signum in (signal.SIGINT, signal.SIGTERM):   # the command is over: just go
        signal.signal(signum, _exit_now)
    if status in _SIGNAL_CODES:
        # stopped by a signal, its line written and its outputs settled: end here, as the
        # signal would have. JAX dispatches computations asynchronously: one the signal cut
        # off may still run on XLA's threads while the interpreter's shutdown tears the
        # client down (exit -11 after the line, twice in a clean clone's suite: `fit`
        # stopped 2.5 s in). Every file is closed by now (outputs, locks, chain files)
        _exit_now(status - 128, None)
    return status


#: the exit codes of a command stopped by SIGINT or SIGTERM (128 + the signal's number)
_SIGNAL_CODES = (128 + signal.SIGINT, 128 + signal.SIGTERM)


def _exit_now(signum, frame) -> None:
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    """Run one fitstiff command; returns its exit status: 0, 2 (bad input, or no room to
    write), 1 (an internal failure), 130 or 143 (stopped by SIGINT or SIGTERM,
    :mod:`fitstiff.interrupts`)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    name = f"fitstiff {argv[0]}" if argv and argv[0] in SUBCOMMANDS else "fitstiff"
    with Signals() as signals, _QuietStdout.installed():
        try:
            limit_arenas()             # before JAX starts its threads (fitstiff.malloc)
            with signals.deferred():   # the command's imports: JAX's extensions (see there)
                parser = build_parser(argv[0] if argv else None)
            args = parser.parse_args(argv)
            if not getattr(args, "func", None):
                parser.print_help()
                return 2
            with warnings.catch_warnings():
                # a floating-point warning means a computation met values it cannot handle:
                # stop there (a result built on inf or NaN is never written) and say so
                warnings.filterwarnings("error", message=_NUMERIC_WARNINGS,
                                        category=RuntimeWarning)
                status = int(args.func(args) or 0)
            if pending() is not None:  # its exception was lost (fitstiff.interrupts)
                raise Interrupted(pending(), kept="the run had finished: its outputs are "
                                                  "complete")
            return status
        except InputError as exc:
            sys.stderr.write(f"{name}: error: {exc}\n")
            return 2
        except RuntimeWarning as exc:
            sys.stderr.write(f"{name}: error: {_numeric_message(args, exc)}\n")
            return 2
        except KeyboardInterrupt as exc:
            stop = exc if isinstance(exc, Interrupted) else Interrupted(signal.SIGINT)
            sys.stderr.write(f"{name}: interrupted by {stop.name}; "
                             f"{stop.kept or 'its unfinished outputs were discarded'}\n")
            return stop.exit_code
        except OSError as exc:
            from fitstiff.io.output import NO_ROOM

            if exc.errno not in NO_ROOM:
                raise
            where = f"{exc.filename}: " if exc.filename else ""
            sys.stderr.write(f"{name}: error: {where}{exc.strerror} while writing; the run's "
                             "unfinished outputs were discarded: free some space (or raise the "
                             "limit) and run it again\n")
            return 2


class _QuietStdout:
    """``sys.stdout`` that stops writing when its reader has gone (``fitstiff inspect --json
    | head -1``): the rest goes to the null device and the command finishes its work, as
    ``head``'s writer would end without a word."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._to_null()
            return len(text)

    def flush(self):
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._to_null()

    def _to_null(self):
        null = os.open(os.devnull, os.O_WRONLY)
        with contextlib.suppress(OSError, ValueError):
            os.dup2(null, self._stream.fileno())
        os.close(null)

    def __getattr__(self, attr):
        return getattr(self._stream, attr)

    @classmethod
    @contextlib.contextmanager
    def installed(cls):
        stream = sys.stdout
        sys.stdout = cls(stream)
        try:
            yield
        finally:
            sys.stdout.flush()         # what is buffered goes now, not in the shutdown
            sys.stdout = stream


if __name__ == "__main__":  # pragma: no cover
    sys.exit(console())
