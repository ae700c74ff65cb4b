"""Signals that stop a command: SIGINT (Ctrl-C) and SIGTERM (``kill``) as one exception.

The command line (:func:`fitstiff.cli.main`) runs every command inside :class:`Signals`: either
signal raises :class:`Interrupted` where the program is, the claimed output directories
discard what they staged (:class:`~fitstiff.io.output.OutputDir`), and the command ends with one
line and the shell's code for the signal (130 for SIGINT, 143 for SIGTERM).

Python drops an exception raised while a garbage-collection callback runs (JAX registers
one), so a signal can land where its exception is lost. The signal is therefore also
recorded (:func:`pending`): the sampler asks after every step, an output directory before it
commits anything, and the command line when the command returns. The lost exception's
"Exception ignored" report is silenced (it is not an error of the program).

Library code that is not run by the command line sees no handler: :func:`pending` is then
``None`` and Python's own SIGINT behaviour applies.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

__all__ = ["Interrupted", "Signals", "deferred", "pending"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """A stop by ``signum``; :attr:`kept` says what the interrupted work left for the user
    (set by the code that keeps something, e.g. a posterior's chain for ``--resume``)."""

    def __init__(self, signum: int = signal.SIGINT, kept: str = ""):
        super().__init__(signum)
        self.signum = int(signum)
        self.kept = kept

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """The shell's status of a process ended by the signal: 128 + its number."""
        return 128 + self.signum


_received: list[int] = []          # signals recorded by the active Signals, in order
_active: list[Signals] = []


def pending() -> int | None:
    """The first signal received under the active :class:`Signals` (None: none, or no
    command-line handler is installed)."""
    return _received[0] if _active and _received else None


def deferred():
    """:meth:`Signals.deferred` of the active handler (nothing to defer without one)."""
    return _active[-1].deferred() if _active else contextlib.nullcontext()


class Signals:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted` and are recorded for
    :func:`pending`; a lost :class:`Interrupted` is not reported as an ignored exception.
    Outside the main thread (where handlers cannot be set) it does nothing."""

    def __init__(self):
        self._deferred = 0

    def __enter__(self) -> Signals:
        self._previous: dict[int, object] = {}
        self._hook = None
        if threading.current_thread() is not threading.main_thread():
            return self
        _received.clear()
        _active.append(self)
        # a signal the parent set to be ignored (``nohup``, a shell's background job) stays so
        self._previous = {s: signal.signal(s, self._raise) for s in _SIGNALS
                          if signal.getsignal(s) is not signal.SIG_IGN}
        self._hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        return self

    def __exit__(self, *exc) -> None:
        if self._hook is None:
            return
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        sys.unraisablehook = self._hook
        _active.remove(self)
        _received.clear()

    @contextlib.contextmanager
    def deferred(self):
        """Within the block a signal is only recorded; it is raised when the block ends.
        For imports of compiled extensions: an exception raised while JAX's extension
        modules initialise crashed the interpreter (a segmentation fault, ``fitstiff fit``
        interrupted 0.8-1.0 s after its start). For code that asks :func:`pending` itself
        and must not be cut in the middle: the sampler, whose library (emcee) prints a
        traceback for any exception raised inside the log-posterior."""
        self._deferred += 1
        try:
            yield
        finally:
            self._deferred -= 1
        if not self._deferred and pending() is not None:
            raise Interrupted(pending())

    def _raise(self, signum, frame) -> None:
        _received.append(signum)
        if not self._deferred:
            raise Interrupted(signum)

    def _unraisable(self, info) -> None:
        if isinstance(info.exc_value, Interrupted):
            return               # recorded by _raise; pending() reports it
        self._hook(info)
