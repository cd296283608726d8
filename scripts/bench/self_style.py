#!/usr/bin/env python3
"""Self-style (issue 53): a scene styled with a crop of its own render should barely move.

    scripts/bench/self_style.py [--scenes plant,bob_100k,...] [--set KEY=VALUE ...]

For each scene of ../shared/data/scenes: the default end alone (`distill --preset default
--iters 0`, 16 orbit views of 256x256, the keep benchmark's cameras and source views)
with three styles: the object's own render (the bounding box of its alpha > 0.5 in view
2, enlarged by pixel repetition until its shorter side is at least 128 px), and the
keep benchmark's mosaic and painting. Each result's RMS colour change over the object
(the source views' pixels with alpha > 0.5, the three channels) against the source
renders; the ratio is the own render's change over the two real styles' mean (issue 53's
bar: at most 1/5). `--set` passes a configuration key to every run (a variant).

Needs the release binaries (target/release) and the keep benchmark's source views
(`pipeline run --dag benches/quality/keep.toml source`); numpy only (vendor/venv).
Prints a Markdown table; its runs go to a temporary directory, removed at the end.
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
from make_styles import write_png  # noqa: E402  (scripts/make_styles.py: an 8-bit RGB PNG)
ROOT = os.path.dirname(os.path.dirname(HERE))
KEEP = os.path.join(ROOT, "benches", "quality")
SCENES = os.path.join(ROOT, "..", "shared", "data", "scenes")
BIN = os.path.join(ROOT, "target", "release")
OWN_VIEW = 2
MIN_SIDE = 128


def own_crop(source, view=OWN_VIEW):
    """View `view`'s object box, repeated until its shorter side is >= MIN_SIDE."""
    rgb = np.load(os.path.join(source, "rgb.npy"))[view]
    alpha = np.load(os.path.join(source, "alpha.npy"))[view]
    ys, xs = np.nonzero(alpha > 0.5)
    crop = rgb[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
    k = -(-MIN_SIDE // min(crop.shape[:2]))
    return np.repeat(np.repeat(crop, k, axis=0), k, axis=1)


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit(f"{cmd[0]} failed ({r.returncode}):\n{r.stderr[-2000:]}")


def change(scene, source, style, out, sets):
    """RMS colour change over the object of the default end with `style`."""
    cmd = [os.path.join(BIN, "distill"), "--scene", scene, "--source-views", source,
           "--model", os.path.join(ROOT, "priors", "patch"), "--style", style,
           "--preset", "default", "--set", "seed=0", "--iters", "0", "--threads", "0",
           "--out", out]
    for s in sets:
        cmd += ["--set", s]
    run(cmd)
    run([os.path.join(BIN, "render-views"), "--scene", out, "--cameras", source,
         "--width", "256", "--height", "256", "--threads", "0", "--out", out + "-views"])
    a = np.load(os.path.join(source, "rgb.npy")).astype(np.float64)
    b = np.load(os.path.join(out + "-views", "rgb.npy")).astype(np.float64)
    m = np.load(os.path.join(source, "alpha.npy")) > 0.5
    return float(np.sqrt(np.mean((a[m] - b[m]) ** 2)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="plant,bob_100k,fish_10k,brucewick_100k")
    ap.add_argument("--view", type=int, default=OWN_VIEW, help="the view cropped for the own style")
    ap.add_argument("--set", action="append", default=[], help="KEY=VALUE for every run")
    args = ap.parse_args()
    print("| capture | own render | mosaic | painting | ratio |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            source = os.path.join(KEEP, "runs-keep", name, "source")
            scene = os.path.join(SCENES, name + ".splat")
            for p in (source, scene):
                if not os.path.exists(p):
                    sys.exit(f"{p}: missing (see the module docs)")
            own = os.path.join(tmp, name + "-own.png")
            write_png(own, own_crop(source, args.view) * 255.0 + 0.5)
            styles = [own] + [os.path.join(KEEP, "styles", s + ".png") for s in ("mosaic", "painting")]
            c = [change(scene, source, s, os.path.join(tmp, f"{name}-{i}"), args.set)
                 for i, s in enumerate(styles)]
            ratio = c[0] / (0.5 * (c[1] + c[2]))
            print(f"| {name} | {c[0]:.3f} | {c[1]:.3f} | {c[2]:.3f} | {ratio:.3f} |", flush=True)


if __name__ == "__main__":
    main()
