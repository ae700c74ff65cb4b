"""What fitstiff wrote into a directory before: the manifests of earlier runs, the inputs and
outputs they record, and the logs written there (an input of one run is never overwritten by
another)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path


from fitstiff.io.output._files import _real

__all__ = ["LOG_SUFFIXES"]

LOG_SUFFIXES = (".csv", ".tsv", ".txt", ".dat", ".log")
"""Files in an output directory with these suffixes count as logs: their sidecar and truth
file names are never written there (unless the run writes the log too)."""
_MANIFEST_SUFFIX = "manifest.json"
_MAIN_MANIFEST = "manifest.json"    # a run's own; runs that add to DIR name theirs otherwise


# -- what fitstiff wrote before -------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _Record:
    manifest: Path
    outputs: Mapping[str, str | None]      # name -> recorded sha256 (None: not recorded)
    inputs: tuple[Path, ...]               # resolved


def _manifests(directory: Path) -> list[Path]:
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.iterdir()
                  if p.name.endswith(_MANIFEST_SUFFIX) and p.is_file())


def _read_manifest(path: Path) -> dict | None:
    """A fitstiff manifest's content, or None when ``path`` is not one."""
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not (isinstance(content, dict) and "fitstiff_version" in content
            and isinstance(content.get("outputs"), list)):
        return None
    return content


def _records(directory: Path) -> list[_Record]:
    """The runs the manifests in ``directory`` record (each manifest and its earlier runs)."""
    out = []
    for path in _manifests(directory):
        content = _read_manifest(path)
        if content is None:
            continue
        for entry in [content, *content.get("earlier_runs", [])]:
            shas = entry.get("output_sha256") or {}
            cwd = Path(entry.get("cwd") or ".")
            inputs = []
            for item in entry.get("inputs", []):
                with contextlib.suppress(TypeError, KeyError, OSError):
                    inputs.append(_real(cwd / item["path"]))
            out.append(_Record(path, {str(n): shas.get(n) for n in entry.get("outputs", [])},
                               tuple(inputs)))
    return out


def _log_companions(directory: Path) -> dict[str, str]:
    """Sidecar / truth file name -> the log in ``directory`` they belong to."""
    out: dict[str, str] = {}
    if not directory.is_dir():
        return out
    for p in directory.iterdir():
        if p.suffix.lower() in LOG_SUFFIXES and p.is_file():
            out[p.with_suffix(".json").name] = p.name
            out[f"{p.stem}.truth.json"] = p.name
    return out
