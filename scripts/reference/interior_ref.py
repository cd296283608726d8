#!/usr/bin/env python3
"""Independent float64 reference of interior structure, edge recall, motif contrast and
style texture (issue 53; numpy only).

    interior_ref.py SOURCE_VIEWS STYLIZED_VIEWS STYLE_NPY [--style-side N] [--out FILE]

SOURCE_VIEWS and STYLIZED_VIEWS are `views` artifact directories of the same cameras
(rgb.npy [N, H, W, 3], alpha.npy [N, H, W]); STYLE_NPY the style image as loaded,
[h, w, 3] in [0, 1]. Prints (or writes to FILE) JSON

    {"style_spread": s,
     "per_view": [{"pixels": n, "strong": k, "interior_structure": r,
                   "edge_recall": e, "motif_contrast": m, "style_texture": t}, ...],
     "mean": {"interior_structure": ..., "edge_recall": ..., "motif_contrast": ...,
              "style_texture": ...}}

Definitions (docs/evaluation.md "Inside the object"):

    Y   = 0.299 R + 0.587 G + 0.114 B               (Rec. 601 luma of rgb as stored)
    D   = G_1 * Y - G_4 * Y                         (difference of Gaussians, px)
    M   = (source alpha > 0.5) eroded by 8 px with a 17 x 17 square; outside the image
          counts as outside the mask
    interior structure = Pearson correlation of D_src and D_sty over M
    edge recall = #{p in M: |D_src| >= P90(|D_src|), |D_src| > 1e-6,
                            D_src D_sty > 0, |D_sty| >= P75(|D_sty|), |D_sty| > 1e-6}
                / #{p in M: |D_src| >= P90(|D_src|), |D_src| > 1e-6}
    motif contrast = std(D_sty over M) / std(D_style over the whole style image)
    style texture  = std(R over M) / std(D_style over the whole style image), where
                     R = D_sty - beta D_src over M and beta = sum(D_src D_sty) / sum(D_src^2)
                     over M (the least-squares projection on the source's band pass,
                     through the origin), beta = 0 when sum(D_src^2) <= 1e-12
G_s: separable Gaussian of standard deviation s, taps exp(-i^2 / (2 s^2)) for
|i| <= ceil(3 s) divided by their sum, edge pixel repeated outside (clamp to edge).
Percentiles (P90, P75) over M: linear interpolation between closest ranks (numpy's
default). std: population (mean squared deviation). The style is first resized so its
shorter side is N px (--style-side, 256 by default): target size round(w * N / min(w, h)) x
round(h * N / min(w, h)) (halves rounded up); while the image is at least twice the target in both axes it is
halved by 2 x 2 box averaging (odd last rows/columns dropped); then bilinear sampling at
((x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5), sx = current width / target width,
coordinates clamped to the image.

A view with fewer than 64 pixels in M has no value (null) for all four; interior
structure is null when either band pass has variance below 1e-12 over M; edge recall is
null when no source pixel qualifies as strong; motif contrast and style texture are null
when the style's spread squared is below 1e-12. Means are over the non-null values.

Written from the definitions above; shares no code with the Rust implementation
(src/metrics/interior.rs, src/metrics/structure.rs). The band pass D and the Pearson
correlation are structure_ref.py's (the same definitions, referenced there).
"""
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from structure_ref import band_pass as dog, correlation as pearson  # noqa: E402

EROSION = 8
MIN_PIXELS = 64
MIN_VARIANCE = 1e-12
MIN_BAND = 1e-6
MIN_SOURCE_ENERGY = 1e-12
STYLE_SIDE = 256


def erode(mask, r):
    """Square erosion: every pixel of the (2r+1)^2 window inside the mask (and the image)."""
    p = np.pad(mask, r, mode="constant", constant_values=False)
    win = np.lib.stride_tricks.sliding_window_view(p, (2 * r + 1, 2 * r + 1))
    return win.all(axis=(-2, -1))


def halve(img):
    h, w = img.shape[0] // 2, img.shape[1] // 2
    c = img[: 2 * h, : 2 * w]
    return 0.25 * (c[0::2, 0::2] + c[0::2, 1::2] + c[1::2, 0::2] + c[1::2, 1::2])


def resize_shorter_side(img, side):
    h, w = img.shape[:2]
    s = side / min(w, h)
    tw = max(1, int(math.floor(w * s + 0.5)))
    th = max(1, int(math.floor(h * s + 0.5)))
    if (tw, th) == (w, h):
        return img
    while img.shape[1] >= 2 * tw and img.shape[0] >= 2 * th:
        img = halve(img)
    h, w = img.shape[:2]
    u = np.clip((np.arange(tw) + 0.5) * (w / tw) - 0.5, 0, w - 1)
    v = np.clip((np.arange(th) + 0.5) * (h / th) - 0.5, 0, h - 1)
    x0, y0 = np.floor(u).astype(int), np.floor(v).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (u - x0)[None, :, None], (v - y0)[:, None, None]
    top = img[y0][:, x0] * (1 - fx) + img[y0][:, x1] * fx
    bot = img[y1][:, x0] * (1 - fx) + img[y1][:, x1] * fx
    return top * (1 - fy) + bot * fy


def one_view(src, sty, alpha, style_spread):
    m = erode(alpha > 0.5, EROSION)
    n = int(m.sum())
    res = {"pixels": n, "strong": 0, "interior_structure": None, "edge_recall": None, "motif_contrast": None,
           "style_texture": None}
    if n < MIN_PIXELS:
        return res
    a, b = dog(src)[m], dog(sty)[m]
    res["interior_structure"] = pearson(a, b)
    strong = (np.abs(a) >= np.percentile(np.abs(a), 90)) & (np.abs(a) > MIN_BAND)
    hit = strong & (a * b > 0) & (np.abs(b) >= np.percentile(np.abs(b), 75)) & (np.abs(b) > MIN_BAND)
    res["strong"] = int(strong.sum())
    if strong.any():
        res["edge_recall"] = float(hit.sum() / strong.sum())
    if style_spread is not None:
        res["motif_contrast"] = float(np.std(b) / style_spread)
        # The stylized band pass less its least-squares fit by the source's (lstsq of b on
        # the single column a, no intercept).
        energy = float(a @ a)
        beta = float(np.linalg.lstsq(a[:, None], b, rcond=None)[0][0]) if energy > MIN_SOURCE_ENERGY else 0.0
        res["style_texture"] = float(np.std(b - beta * a) / style_spread)
    return res


def main():
    args = sys.argv[1:]
    out = None
    if "--out" in args:
        k = args.index("--out")
        out = args[k + 1]
        del args[k:k + 2]
    side = STYLE_SIDE
    if "--style-side" in args:
        k = args.index("--style-side")
        side = int(args[k + 1])
        del args[k:k + 2]
    src_dir, sty_dir, style_path = args
    src = np.load(f"{src_dir}/rgb.npy").astype(np.float64)
    sty = np.load(f"{sty_dir}/rgb.npy").astype(np.float64)
    alpha = np.load(f"{src_dir}/alpha.npy").astype(np.float64)
    style = np.load(style_path).astype(np.float64)
    assert src.shape == sty.shape and src.shape[:3] == alpha.shape, (src.shape, sty.shape, alpha.shape)
    s = float(np.std(dog(resize_shorter_side(style, side))))
    style_spread = s if s * s >= MIN_VARIANCE else None
    per_view = [one_view(src[v], sty[v], alpha[v], style_spread) for v in range(src.shape[0])]
    mean = {}
    for key in ("interior_structure", "edge_recall", "motif_contrast", "style_texture"):
        have = [p[key] for p in per_view if p[key] is not None]
        mean[key] = sum(have) / len(have) if have else None
    text = json.dumps({"style_spread": style_spread, "per_view": per_view, "mean": mean})
    if out:
        with open(out, "w") as f:
            f.write(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
