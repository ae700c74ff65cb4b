"""What the acceptance rule's least held-out gain (``MIN_GAIN``) separates, read off stored
withheld-effect records.

Every held-out refit a record keeps (``refits``: each candidate's last round; records
without it give the first round's ``ranked`` with the dataset's baseline figure) has a
gain, ``before - after`` held out, as a share of the noise floor, and a shrink. Two kinds
matter for the threshold:

- a **withheld effect left out**: the dataset's withheld effect, refitted and not accepted
  (the exact-set misses the threshold could mend);
- a **spurious refit**: a candidate that is not withheld (on nulls, and in any round of a
  dataset with an effect: the second round's candidates after the withheld one was taken).

Only the search's last round counts (a refit's round one past the accepted effects): in an
earlier round another candidate was accepted, and one that passed beside it lost the round
(a time delay beside viscous friction). For each threshold the script counts the last
round's refits of each kind that would pass the gain and shrink conditions (the rule's
other conditions, a bound and a left-out log made worse, are not in the records). A
spurious refit that passes there is an effect named wrongly, to first order: it ignores
ties within the round and what accepting it would change in later rounds.

    python benchmarks/gain_threshold.py benchmarks/results/withheld_handover_combined.json
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from fitstiff.diagnosis import MIN_SHRINK
from fitstiff.diagnosis.select import MIN_GAIN

THRESHOLDS = (0.01, 0.02, 0.025, 0.03, 0.04, MIN_GAIN)


def refits(record: dict) -> list[dict]:
    """The record's held-out refits: effect, round, gain (share of the floor), shrink."""
    noise = record["noise_N"]
    if "refits" in record:
        return [{"effect": r["effect"], "round": r["round"], "accepted": r["accepted"],
                 "gain": (r["before_N"] - r["after_N"]) / noise, "shrink": r["shrink"]}
                for r in record["refits"] if r["shrink"] is not None]
    before = record["heldout_rms_before_N"]
    return [{"effect": c["effect"], "round": 1, "accepted": c["accepted"],
             "gain": c["shrink"] * (before - noise) / noise, "shrink": c["shrink"]}
            for c in record["ranked"] if c.get("shrink") is not None]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="+", help="withheld.py JSON files")
    parser.add_argument("--min-shrink", type=float, default=MIN_SHRINK)
    args = parser.parse_args(argv)
    records: dict[str, dict] = {}
    for path in args.results:
        records.update(json.loads(path.read_text())["datasets"])
    left_out, spurious = [], []
    for key, record in sorted(records.items()):
        if "error" in record:
            continue
        last = len(record["accepted"]) + 1
        for r in refits(record):
            if r["accepted"] or r["round"] != last:
                continue
            row = (r["gain"], r["shrink"], key, r["effect"], r["round"],
                   _log10_p(record, r["effect"]))
            if r["effect"] in record["expected"]:
                left_out.append(row)
            else:
                spurious.append(row)
    print(f"{len(records)} records; the last round's refits: {len(left_out)} of a withheld "
          f"effect, {len(spurious)} spurious")
    print(f"{'least gain':>11} {'withheld mended':>16} {'spurious passing':>17}")
    for t in THRESHOLDS:
        mend = [r for r in left_out if r[0] >= t and r[1] >= args.min_shrink]
        wrong = [r for r in spurious if r[0] >= t and r[1] >= args.min_shrink]
        print(f"{t:>11.3f} {len(mend):>16d} {len(wrong):>17d}   "
              + ", ".join(f"+{k} {e}" for _, _, k, e, _, _ in mend)
              + ("; " if mend and wrong else "")
              + ", ".join(f"-{k} {e} (round {n})" for _, _, k, e, n, _ in wrong))
    print("\nwithheld effects refitted and left out (gain as a share of the floor, shrink, "
          "log10 p of the screen where the record ranks it):")
    for gain, shrink, key, effect, n, lp in sorted(left_out, reverse=True):
        print(f"  {gain:7.3f} {shrink:6.2f} {_shown(lp):>7}  {key} {effect} (round {n})")
    print(f"\nspurious refits with shrink >= {args.min_shrink} (the largest gains):")
    for gain, shrink, key, effect, n, lp in sorted(
            (r for r in spurious if r[1] >= args.min_shrink), reverse=True)[:12]:
        print(f"  {gain:7.3f} {shrink:6.2f} {_shown(lp):>7}  {key} {effect} (round {n})")


def _log10_p(record: dict, effect: str) -> float | None:
    """log10 of the effect's screen p-value as the record ranks it (its top five only)."""
    for c in record.get("ranked", []):
        if c["effect"] == effect and c.get("log_p_value") is not None:
            return c["log_p_value"] / math.log(10)
    return None


def _shown(log10_p: float | None) -> str:
    return "-" if log10_p is None else f"{log10_p:.0f}"


if __name__ == "__main__":
    main()
