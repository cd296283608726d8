#!/usr/bin/env python3
"""Summary of the quality benchmark (benches/quality/quality.toml).

    quality_summary.py RUNS_DIR [STYLES_DIR]

Reads, for every scene/style/method under RUNS_DIR, what `evaluate` wrote (metrics.json)
and the rendered views (rgb.npy, alpha.npy), and prints a Markdown report:

* per case: Gram distance to the style (stylized / original, lower = closer), LPIPS to
  the original (content change), short-range LPIPS between neighbouring views (lower =
  more consistent; the original's own value beside it), ArtFID, the distance of the
  object's RGB statistics from the style image's (|mean diff| + Frobenius |cov diff|,
  original -> stylized), clipped object pixels, and the brightness change of the faint
  silhouette fringe (alpha 0.02-0.5; the "glowing haze" of issue 11);
* per method: mean and 95% confidence interval (Student t over cases);
* how many cases our method beats the Gram baseline on each measure.

It also writes one contact sheet per scene, RUNS_DIR/sheets/<scene>.png: per style,
rows = style image, original, then each method; columns = every other view.
"""
import json
import os
import struct
import sys
import zlib

import numpy as np

from make_styles import write_png

METHODS = ["ours", "nomvfc", "gram"]
T95 = {1: 12.71, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306,
       9: 2.262, 10: 2.228, 11: 2.201, 12: 2.179, 15: 2.131, 20: 2.086, 30: 2.042}


def read_png(path):
    """8-bit RGB/RGBA PNG, any filter (enough for the style images)."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, w = 8, b"", None
    while pos < len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        t, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if t == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype in (2, 6), f"{path}: only 8-bit RGB(A)"
            ch = 3 if ctype == 2 else 4
        elif t == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + w * ch)
    out = np.zeros((h, w * ch), np.int32)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        prev = out[y - 1] if y else np.zeros(w * ch, np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) % 256
        else:
            cur = np.zeros(w * ch, np.int32)
            for i in range(w * ch):
                a = cur[i - ch] if i >= ch else 0
                b = prev[i]
                c = prev[i - ch] if i >= ch else 0
                if f == 1:
                    p = a
                elif f == 3:
                    p = (a + b) // 2
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (line[i] + p) % 256
        out[y] = cur
    return out.reshape(h, w, ch)[..., :3] / 255.0


def stats_distance(pix, style):
    mu = np.abs(pix.mean(0) - style.mean(0))
    cov = np.cov(pix.T) - np.cov(style.T)
    return float(np.linalg.norm(mu) + np.linalg.norm(cov))


def case(runs, scene, style_img, method):
    src = os.path.join(runs, scene, "source")
    rgb0, alpha = np.load(os.path.join(src, "rgb.npy")), np.load(os.path.join(src, "alpha.npy"))
    base = os.path.join(runs, scene, style_img[0])
    m = json.load(open(os.path.join(base, method + "-eval", "metrics.json")))
    rgb1 = np.load(os.path.join(base, method + "-views", "rgb.npy"))
    a = alpha[..., 0] if alpha.ndim == 4 else alpha
    cov_ = a > 0.5
    un0 = rgb0[cov_] / a[cov_][:, None]
    un1 = rgb1[cov_] / a[cov_][:, None]
    st = style_img[1].reshape(-1, 3)
    fringe = (a > 0.02) & (a < 0.5)
    clip = lambda u: float(np.mean(np.all(u <= 0.02, 1) | np.all(u >= 0.98, 1)))
    return {
        "gram_ratio": m["gram_style"] / m["gram_style_original"],
        "lpips_content": m["lpips_content"],
        "short_range": m["short_range"]["lpips_mean"],
        "short_range_orig": m["short_range"]["original_lpips_mean"],
        "artfid": m["artfid"],
        "stats0": stats_distance(np.clip(un0, 0, 1), st),
        "stats1": stats_distance(np.clip(un1, 0, 1), st),
        "clip0": clip(un0),
        "clip1": clip(un1),
        "fringe": float((rgb1[fringe] - rgb0[fringe]).mean()) if fringe.any() else 0.0,
        "views": (rgb0, rgb1),
    }


def ci(xs):
    xs = np.asarray(xs, float)
    if len(xs) < 2:
        return f"{xs.mean():.3f}"
    t = T95.get(len(xs) - 1, 2.0)
    return f"{xs.mean():.3f} ± {t * xs.std(ddof=1) / np.sqrt(len(xs)):.3f}"


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    runs = sys.argv[1]
    styles_dir = sys.argv[2] if len(sys.argv) == 3 else os.path.join(os.path.dirname(runs.rstrip("/")), "styles")
    scenes = sorted(d for d in os.listdir(runs) if os.path.isdir(os.path.join(runs, d, "source")))
    styles = sorted(f[:-4] for f in os.listdir(styles_dir) if f.endswith(".png"))
    res = {}
    for sc in scenes:
        for sty in styles:
            img = read_png(os.path.join(styles_dir, sty + ".png"))
            for me in METHODS:
                if os.path.isfile(os.path.join(runs, sc, sty, me + "-eval", "metrics.json")):
                    res[(sc, sty, me)] = case(runs, sc, (sty, img), me)
    keys = [("gram_ratio", "Gram to style (stylized/original)"), ("lpips_content", "LPIPS content"),
            ("short_range", "short-range LPIPS"), ("artfid", "ArtFID"),
            ("stats1", "RGB stats distance to style"), ("clip1", "clipped object px"),
            ("fringe", "fringe brightening")]
    print("| scene | style | method | " + " | ".join(k[1] for k in keys) + " |")
    print("|---" * (3 + len(keys)) + "|")
    for (sc, sty, me), r in sorted(res.items()):
        vals = [f"{r['gram_ratio']:.3f}", f"{r['lpips_content']:.3f}",
                f"{r['short_range']:.3f} (orig {r['short_range_orig']:.3f})", f"{r['artfid']:.1f}",
                f"{r['stats0']:.3f} -> {r['stats1']:.3f}", f"{100 * r['clip0']:.1f}% -> {100 * r['clip1']:.1f}%",
                f"{r['fringe']:+.4f}"]
        print(f"| {sc} | {sty} | {me} | " + " | ".join(vals) + " |")
    print()
    print("Mean ± 95% CI over cases (Student t):")
    print()
    print("| method | cases | " + " | ".join(k[1] for k in keys) + " |")
    print("|---" * (2 + len(keys)) + "|")
    for me in METHODS:
        rs = [r for (_, _, m), r in res.items() if m == me]
        if rs:
            print(f"| {me} | {len(rs)} | " + " | ".join(ci([r[k] for r in rs]) for k, _ in keys) + " |")
    print()
    better = {"gram_ratio": 1, "lpips_content": 1, "short_range": 1, "artfid": 1, "stats1": 1}
    pairs = [(res[(sc, sty, "ours")], res[(sc, sty, "gram")]) for sc in scenes for sty in styles
             if (sc, sty, "ours") in res and (sc, sty, "gram") in res]
    if pairs:
        wins = ", ".join(f"{name} {sum(o[k] < g[k] for o, g in pairs)}/{len(pairs)}"
                         for k, name in keys if k in better)
        print(f"Cases where ours is lower (better) than gram: {wins}.")
    os.makedirs(os.path.join(runs, "sheets"), exist_ok=True)
    for sc in scenes:
        rows = []
        for sty in styles:
            cases = {me: res.get((sc, sty, me)) for me in METHODS}
            if not any(cases.values()):
                continue
            any_case = next(c for c in cases.values() if c)
            v0 = any_case["views"][0]
            cols = list(range(0, v0.shape[0], 2))
            hh, ww = v0.shape[1:3]
            img = read_png(os.path.join(styles_dir, sty + ".png"))
            yi = (np.arange(hh) * img.shape[0] / hh).astype(int)
            xi = (np.arange(ww) * img.shape[1] / ww).astype(int)
            rows.append(np.concatenate([img[yi][:, xi]] * len(cols), 1))
            rows.append(np.concatenate([v0[c] for c in cols], 1))
            for me in METHODS:
                if cases[me]:
                    rows.append(np.concatenate([cases[me]["views"][1][c] for c in cols], 1))
        if rows:
            out = os.path.join(runs, "sheets", sc + ".png")
            write_png(out, np.concatenate(rows, 0) * 255.0 + 0.5)
            print(f"\ncontact sheet: {out} (per style: style, original, {', '.join(METHODS)})", file=sys.stderr)


if __name__ == "__main__":
    main()
