"""The ``fitstiff`` command line: a thin layer over the library.

Each subcommand lives in its own module ``fitstiff/cli/<name>.py`` exposing
``add_parser(subparsers)`` (which sets ``func`` on its parser). Exit codes: 0 success,
2 bad input (one line on stderr, no traceback), 1 internal failure.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from fitstiff import __version__
from fitstiff.errors import InputError

__all__ = ["main", "SUBCOMMANDS"]

# order = order in --help
SUBCOMMANDS = ("inspect", "stiffness", "simulate", "fit", "posterior", "report", "diagnose", "demo")


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line with exit code 2."""

    def error(self, message):  # noqa: D401
        sys.stderr.write(f"{self.prog}: error: {message}; see '{self.prog} --help'\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="fitstiff", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"fitstiff {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"fitstiff.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"fitstiff.cli.{name}":
                continue  # not built yet
            raise
        module.add_parser(sub)
    return parser


def _enable_compilation_cache() -> None:
    """Persistent JAX compilation cache, so a second run of a command skips compilation.

    ``FITSTIFF_CACHE_DIR`` sets the directory (default ``~/.cache/fitstiff/jax``); an empty
    value turns the cache off.
    """
    path = os.environ.get("FITSTIFF_CACHE_DIR",
                          os.path.join(os.path.expanduser("~"), ".cache", "fitstiff", "jax"))
    if not path:
        return
    from fitstiff._jax import jax

    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


def main(argv: list[str] | None = None) -> int:
    _enable_compilation_cache()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        sys.stderr.write(f"fitstiff {args.command}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"fitstiff {args.command}: interrupted\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
