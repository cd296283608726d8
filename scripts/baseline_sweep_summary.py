#!/usr/bin/env python3
"""Summary of the VGG baselines' learning-rate sweep (benches/quality/baseline_sweep.toml).

    baseline_sweep_summary.py SWEEP_RUNS_DIR

Prints one Markdown row per method, learning rate and saved step: the object Gram
distance per VGG layer as stylized / original, KID_style, the luminance-spectrum
distance (stylized / original), LPIPS to the original, short-range consistency, clipped
object pixels, fringe brightening and the run's wall time at that step (timing.json).
Writes SWEEP_RUNS_DIR/sheet-<method>.png per method: rows = original, then each
learning rate and step; columns = views 0, 4, 8, 12.
"""
import json
import os
import sys

import numpy as np

from make_styles import write_png


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    src = np.load(os.path.join(d, "source", "rgb.npy"))
    cols = [0, 4, 8, 12][: src.shape[0]]
    print("| method | lr_dc | steps | wall s | Gram relu1_2 | Gram relu2_2 | Gram relu3_3 | Gram relu4_3 | KID_style | spectrum dist. | LPIPS content | short-range LPIPS | clipped | fringe |")
    print("|---" * 14 + "|")
    for method in ["gram", "nnfm"]:
        md = os.path.join(d, method)
        if not os.path.isdir(md):
            continue
        rows, names = [np.concatenate([src[c] for c in cols], 1)], ["original"]
        runs = sorted((n for n in os.listdir(md) if os.path.isfile(os.path.join(md, n, "timing.json"))),
                      key=lambda n: float(n[2:]))
        for run in runs:
            timing = json.load(open(os.path.join(md, run, "timing.json")))
            for c in timing["checkpoints"]:
                e = os.path.join(md, f"{run}-s{c['step']}-eval", "metrics.json")
                if not os.path.isfile(e):
                    continue
                m = json.load(open(e))
                t = m["texture"]
                g = [f"{l['ratio']:.3f}" for l in t["gram_object"]]
                o = t["object"]
                print(f"| {method} | {run[2:]} | {c['step']} | {c['elapsed_s']:.0f} | " + " | ".join(g)
                      + f" | {t['kid_style']['value']:.4f} | {t['spectrum']['distance_ratio']:.3f} | {m['lpips_content']:.3f}"
                      + f" | {m['short_range']['lpips_mean']:.4f} | {100 * o['clipped_stylized']:.1f}% | {o['fringe_brightening']:+.4f} |")
                v = np.load(os.path.join(md, f"{run}-s{c['step']}-views", "rgb.npy"))
                rows.append(np.concatenate([v[k] for k in cols], 1))
                names.append(f"lr {run[2:]}, step {c['step']}")
        out = os.path.join(d, f"sheet-{method}.png")
        write_png(out, np.concatenate(rows, 0) * 255.0 + 0.5)
        print(f"{out}: rows {', '.join(names)}", file=sys.stderr)


if __name__ == "__main__":
    main()
