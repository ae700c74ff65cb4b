"""Errors that reach the user.

Every problem with user input is an :class:`InputError`: one line that names the file, the
row / column / key / parameter, what was found and how to fix it. The command line prints it
and exits with code 2; it never shows a traceback for bad input.
"""

from __future__ import annotations

__all__ = ["FitstiffError", "InputError"]

_WHAT_LIMIT, _FOUND_LIMIT = 500, 1500   # characters of these parts shown in a message


def _clip(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


class FitstiffError(Exception):
    """Base class of fitstiff's own errors."""


class InputError(FitstiffError, ValueError):
    """Bad user input (file, column, metadata, option). Exit code 2 on the command line.

    Build the message from its parts so every error reads the same way::

        InputError("run1.csv", "row 17, column 'force_N'", "found 'abc'",
                   "make every cell a number")
        -> "run1.csv: row 17, column 'force_N': found 'abc'; make every cell a number"
    """

    def __init__(self, where: str | None, what: str, found: str | None = None,
                 fix: str | None = None):
        self.where, self.what, self.found, self.fix = where, what, found, fix
        # what and found can quote anything a user wrote: keep the line readable
        what, found = _clip(what, _WHAT_LIMIT), found and _clip(found, _FOUND_LIMIT)
        parts = f"{where}: {what}" if where else what
        if found:
            parts += f": {found}"
        if fix:
            parts += f"; {fix}"
        # one line, always
        super().__init__(" ".join(parts.split()))
