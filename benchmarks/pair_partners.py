"""The pair step's partners (issue 31): where the rule of ``_choice.partners`` leaves a
candidate out of a round's pair step, also run the pair step of the rule before it (every
converged refit among the three strongest) beside it, and record whether that would have
accepted a pair: any change of decision is then the rule's.

    python benchmarks/pair_partners.py OUT.json ID [ID ...]

Each dataset runs in its own process (two at a time), as ``benchmarks/withheld.py`` runs
them; ``OUT.json`` holds each dataset's record with ``pair_log``: per pair step the model,
every refit's held-out RMS and shrink, the partners now and before, and what each step
accepted (``new``; ``old`` where the partners differed).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path


def work(dataset_id: str) -> dict:
    """Diagnose one dataset with the pair step logged (and the rule before it run beside)."""
    from fitstiff._testing.withheld_scoring import run_dataset
    from fitstiff.diagnosis import _choice, _rounds

    log = []
    pair = _choice.pair

    def logged(sp, folds, tried, starts, theta, hold, active, weights, *, current, noise,
               min_shrink):
        now = _choice.partners(tried, current)
        before = sorted((v for v in tried.values() if v.heldout.converged),
                        key=lambda v: v.score.log_p)[:_choice.MAX_REFITS]
        start = time.perf_counter()
        out = pair(sp, folds, tried, starts, theta, hold, active, weights, current=current,
                   noise=noise, min_shrink=min_shrink)
        entry = {"active": list(active), "current_N": current.rms_N,
                 "tried": {v.effect: [v.heldout.rms_N, v.shrink] for v in tried.values()},
                 "partners": [v.effect for v in now],
                 "partners_before": [v.effect for v in before],
                 "new": None if out is None else out.effects,
                 "new_s": time.perf_counter() - start}
        if entry["partners"] != entry["partners_before"]:
            rule = _choice.partners
            _choice.partners = lambda tried, current: before
            start = time.perf_counter()
            try:
                old = pair(sp, folds, tried, starts, theta, hold, active, weights,
                           current=current, noise=noise, min_shrink=min_shrink)
            finally:
                _choice.partners = rule
            entry["old"] = None if old is None else old.effects
            entry["old_s"] = time.perf_counter() - start
        log.append(entry)
        return out

    _rounds.pair = logged
    record = run_dataset(dataset_id)
    record["pair_log"] = log
    return record


def main(argv: list[str]) -> None:
    out_path, ids = Path(argv[0]), argv[1:]
    out: dict[str, dict] = {}
    context = mp.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=context, max_tasks_per_child=1) as pool:
        for record in pool.map(work, ids):
            out[record["id"]] = record
            steps = [(e["partners"], e["partners_before"], e["new"], e.get("old", "same"))
                     for e in record.get("pair_log", [])]
            print(record["id"], record.get("accepted"), record.get("error", ""), steps,
                  flush=True)
            out_path.write_text(json.dumps(out, indent=1, default=str) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
