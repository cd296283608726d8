#!/usr/bin/env python3
"""Markdown table comparing methods from their `evaluate` artifacts (metrics.json).

    compare_methods.py NAME=EVAL_DIR[:WALL_SECONDS] ...

e.g. `ours=data-sample/runs/eval:412 gram=data-sample/runs/baseline-gram/eval:380`.
Reads only what evaluate wrote; prints one row per method.
"""
import json
import os
import sys


def row(name, path, wall):
    m = json.load(open(os.path.join(path, "metrics.json")))
    g = lambda k: m[k]["value"] if isinstance(m.get(k), dict) else m.get(k)
    return "| {} | {} | {:.4f} | {:.1f} | {:.4f} | {:.1f} | {:.2f} (orig {:.2f}) | {:.4f} | {:.4f} |".format(
        name, wall, m["lpips_content"], g("fid_style"), g("kid_style"), m["artfid"],
        m["gram_style"], m["gram_style_original"],
        m["short_range"]["lpips_mean"], m["long_range"]["lpips_mean"])


def main():
    print("| method | wall (s) | LPIPS content | FID style | KID style | ArtFID | Gram to style | short-range LPIPS | long-range LPIPS |")
    print("|---|---|---|---|---|---|---|---|---|")
    for a in sys.argv[1:]:
        name, rest = a.split("=", 1)
        path, _, wall = rest.partition(":")
        print(row(name, path, wall or "-"))


if __name__ == "__main__":
    main()
