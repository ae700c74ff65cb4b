"""Score stored withheld-benchmark records together (``benchmarks/withheld.py --json``).

The files' ``datasets`` are merged, each file's replacing those of the files before it;
each ``--rerun`` file's then replace the merged ones of the same id and add none (a re-run
of some datasets on a later code over the whole stored benchmark). Prints the scores (``withheld_scoring.score``) and, with ``--json``,
writes them with the merged records (``--summary-only``: the scores alone).

    python benchmarks/withheld_merge.py benchmarks/results/withheld_single_eb901e8.json \\
        benchmarks/results/withheld_rest_5bd97f1.json \\
        --rerun benchmarks/results/withheld_rival_f6455d6.json --json OUT.json --summary-only
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from fitstiff._testing.withheld_scoring import score
from fitstiff.io.output import to_jsonable, write_atomic


def merge(paths: Sequence[Path], reruns: Sequence[Path] = ()) -> dict[str, dict]:
    """The records of ``paths``, each file's replacing the earlier ones' of the same id, then
    those of ``reruns``, which replace and add nothing."""
    records: dict[str, dict] = {}
    for path in paths:
        records.update(_datasets(path))
    for path in reruns:
        records.update({i: r for i, r in _datasets(path).items() if i in records})
    return records


def _datasets(path: Path) -> dict[str, dict]:
    try:
        return json.loads(Path(path).read_text())["datasets"]
    except (OSError, ValueError, KeyError) as exc:
        raise SystemExit(f"{path}: not a withheld-benchmark record ({exc}); give a --json "
                         "file of benchmarks/withheld.py") from None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--rerun", type=Path, action="append", default=[],
                        help="records that replace those of the files and add none")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--summary-only", action="store_true")
    args = parser.parse_args(argv)
    records = merge(args.files, args.rerun)
    summary = score(records)
    print(json.dumps(to_jsonable(summary), indent=1))
    if args.json:
        out = {"files": [str(p) for p in args.files],
               "reruns": [str(p) for p in args.rerun], "summary": summary}
        if not args.summary_only:
            out["datasets"] = records
        write_atomic(args.json, json.dumps(to_jsonable(out), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
