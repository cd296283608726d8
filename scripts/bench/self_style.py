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

One view is not the object's average look (an orbit's view 2 sees a darker side of every
shared scene), and the end follows its style's brightness (Image Analogies' remap), so
the own render's change is split: `brightness` is the mean luma change over the object
(Rec. 601), `without` the RMS change left once each channel's mean change is taken away,
and its ratio to the real styles' (their whole change). `--own grid` takes every view's
object box instead, side by side with gutters of the background (the object's look from
all sides, at the renders' scale before `texture.style_size`). `--own-scale render` runs
the own style at the renders' scale (its `texture.style_size` set to its shorter side, less
the crop's repetition) instead of the default 256. `--own-colours object` takes the crop's
colours un-premultiplied (divided by the coverage where it is above 0.02): the renders are
over black, so the object's anti-aliased rim is a dark blend in the default crop, which the
style's background test keeps as motif.

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
LUMA = np.array([0.299, 0.587, 0.114])


def load_source(source):
    """The source views' rgb [N, H, W, 3] (float64) and alpha [N, H, W]."""
    rgb = np.load(os.path.join(source, "rgb.npy")).astype(np.float64)
    alpha = np.load(os.path.join(source, "alpha.npy"))
    return rgb, alpha


UNPREMULTIPLIED_ALPHA = 0.02


def object_box(src, view, colours="render"):
    """View `view`'s render cropped to its object's box (alpha > 0.5); with `colours`
    "object", un-premultiplied where the coverage is above UNPREMULTIPLIED_ALPHA (black
    elsewhere)."""
    rgb, alpha = src
    ys, xs = np.nonzero(alpha[view] > 0.5)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    crop = rgb[view][box]
    if colours == "object":
        a = alpha[view][box][..., None]
        crop = np.where(a > UNPREMULTIPLIED_ALPHA, np.clip(crop / np.maximum(a, 1e-6), 0.0, 1.0), 0.0)
    return crop


def object_luma(rgb, alpha, views):
    """Mean un-premultiplied luma over the object pixels (alpha > 0.5) of `views`
    (the renders are over black)."""
    a = alpha[views]
    m = a > 0.5
    return float(((rgb[views][m] / a[m][:, None]) @ LUMA).mean())


def own_crop(src, view=OWN_VIEW, colours="render"):
    """View `view`'s object box ([`object_box`]), repeated until its shorter side is
    >= MIN_SIDE; and the repetition factor."""
    crop = object_box(src, view, colours)
    k = -(-MIN_SIDE // min(crop.shape[:2]))
    return np.repeat(np.repeat(crop, k, axis=0), k, axis=1), k


GUTTER = 4


def own_grid(src, colours="render"):
    """Every view's object box on a near-square grid, each centred in a cell of the
    largest box's size, cells apart by GUTTER pixels of the background (black): the
    background stays one region reaching the border, as the style's motif test wants."""
    n = src[0].shape[0]
    crops = [object_box(src, v, colours) for v in range(n)]
    cols = int(np.ceil(np.sqrt(n)))
    rows = -(-n // cols)
    ch = max(c.shape[0] for c in crops)
    cw = max(c.shape[1] for c in crops)
    img = np.zeros((rows * (ch + GUTTER) + GUTTER, cols * (cw + GUTTER) + GUTTER, 3), np.float32)
    for i, c in enumerate(crops):
        r, k = divmod(i, cols)
        y = GUTTER + r * (ch + GUTTER) + (ch - c.shape[0]) // 2
        x = GUTTER + k * (cw + GUTTER) + (cw - c.shape[1]) // 2
        img[y : y + c.shape[0], x : x + c.shape[1]] = c
    return img


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit(f"{cmd[0]} failed ({r.returncode}):\n{r.stderr[-2000:]}")


def change(scene, source, src, style, out, sets):
    """RMS colour change over the object of the default end with `style` (`src`: the
    source views, [`load_source`]), its mean luma change, its RMS change less each
    channel's mean change, and the result's object luma over every view."""
    cmd = [os.path.join(BIN, "distill"), "--scene", scene, "--source-views", source,
           "--model", os.path.join(ROOT, "priors", "patch"), "--style", style,
           "--preset", "default", "--set", "seed=0", "--iters", "0", "--threads", "0",
           "--out", out]
    for s in sets:
        cmd += ["--set", s]
    run(cmd)
    run([os.path.join(BIN, "render-views"), "--scene", out, "--cameras", source,
         "--width", "256", "--height", "256", "--threads", "0", "--out", out + "-views"])
    a, alpha = src
    b = np.load(os.path.join(out + "-views", "rgb.npy")).astype(np.float64)
    m = alpha > 0.5
    d = b[m] - a[m]
    rms = float(np.sqrt(np.mean(d**2)))
    brightness = float((d @ LUMA).mean())
    without = float(np.sqrt(np.mean((d - d.mean(axis=0)) ** 2)))
    return rms, brightness, without, object_luma(b, alpha, slice(None))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="plant,bob_100k,fish_10k,brucewick_100k")
    ap.add_argument("--view", type=int, default=OWN_VIEW, help="the view cropped for the own style")
    ap.add_argument("--own", choices=("view", "grid"), default="view",
                    help="the own style: one view's object box (--view), or every view's on a grid")
    ap.add_argument("--own-scale", choices=("default", "render"), default="default",
                    help="the own style at texture.style_size's default, or at the renders' scale")
    ap.add_argument("--own-colours", choices=("render", "object"), default="render",
                    help="the crop as rendered over black, or its colours un-premultiplied")
    ap.add_argument("--set", action="append", default=[], help="KEY=VALUE for every run")
    args = ap.parse_args()
    print("| capture | own render | mosaic | painting | ratio | own: brightness | own: without "
          "| ratio without | object luma: own style's views / all views / result |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            source = os.path.join(KEEP, "runs-keep", name, "source")
            scene = os.path.join(SCENES, name + ".splat")
            for p in (source, scene):
                if not os.path.exists(p):
                    sys.exit(f"{p}: missing (see the module docs)")
            own = os.path.join(tmp, name + "-own.png")
            src = load_source(source)
            if args.own == "view":
                img, k = own_crop(src, args.view, args.own_colours)
            else:
                img, k = own_grid(src, args.own_colours), 1
            own_views = [args.view] if args.own == "view" else slice(None)
            write_png(own, img * 255.0 + 0.5)
            own_sets = list(args.set)
            if args.own_scale == "render":
                own_sets.append(f"texture.style_size={min(img.shape[:2]) // k}")
            styles = [own] + [os.path.join(KEEP, "styles", s + ".png") for s in ("mosaic", "painting")]
            c = [change(scene, source, src, s, os.path.join(tmp, f"{name}-{i}"),
                        own_sets if i == 0 else args.set)
                 for i, s in enumerate(styles)]
            own_rms, bright, without, result_luma = c[0]
            real = 0.5 * (c[1][0] + c[2][0])
            lumas = (object_luma(*src, own_views), object_luma(*src, slice(None)), result_luma)
            print(f"| {name} | {own_rms:.3f} | {c[1][0]:.3f} | {c[2][0]:.3f} | {own_rms / real:.3f} "
                  f"| {bright:+.3f} | {without:.3f} | {without / real:.3f} "
                  f"| {lumas[0]:.3f} / {lumas[1]:.3f} / {lumas[2]:.3f} |", flush=True)


if __name__ == "__main__":
    main()
