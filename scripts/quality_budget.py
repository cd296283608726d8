#!/usr/bin/env python3
"""A baseline's time budget for the quality benchmark: another stage's measured wall time.

    quality_budget.py --lock LOCK --stage NAME --out FILE

Reads the pipeline lock LOCK (e.g. benches/quality/quality.lock, written by `pipeline run`
after every stage), takes the wall time (`duration_s`) of stage NAME (e.g.
`ours@fish_10k.brick`, which must have finished successfully), and writes
{"budget_s": ..., "stage": NAME} to FILE, which `stylize-baseline --budget-from FILE`
reads. Exit code 2 with a message when the lock or the stage is missing or failed.
"""
import argparse
import json
import os
import sys


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--lock", required=True)
    p.add_argument("--stage", required=True)
    p.add_argument("--out", required=True)
    a = p.parse_args()
    try:
        with open(a.lock) as f:
            lock = json.load(f)
    except (OSError, ValueError) as e:
        print(f"error: {a.lock}: cannot read the pipeline lock: {e}", file=sys.stderr)
        return 2
    entry = lock.get("stages", {}).get(a.stage)
    if entry is None:
        print(f"error: {a.lock}: no stage `{a.stage}` (run it with `pipeline run` first)", file=sys.stderr)
        return 2
    if entry.get("status") != "ok":
        print(f"error: {a.lock}: stage `{a.stage}` has status {entry.get('status')!r}", file=sys.stderr)
        return 2
    out = {"budget_s": float(entry["duration_s"]), "stage": a.stage}
    tmp = a.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(out, f)
        f.write("\n")
    os.replace(tmp, a.out)
    print(f"{a.stage}: {out['budget_s']:.1f} s -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
