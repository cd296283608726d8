#!/usr/bin/env python3
"""Independent float64 reference of "structure kept" (issue 47; numpy only).

    structure_ref.py SOURCE_VIEWS STYLIZED_VIEWS [--out FILE]

SOURCE_VIEWS and STYLIZED_VIEWS are `views` artifact directories of the same cameras
(rgb.npy [N, H, W, 3], alpha.npy [N, H, W]). Prints (or writes to FILE) JSON
{"per_view": [r_0, ..., r_{N-1}], "mean": m}, where per view

    Y   = 0.299 R + 0.587 G + 0.114 B            (Rec. 601 luma of rgb as stored)
    D   = G_1 * Y - G_4 * Y                      (difference of Gaussians, in pixels)
    r   = Pearson correlation of D_source and D_stylized over the pixels with
          source alpha > 0.5

G_s is a separable Gaussian blur of standard deviation s px: taps exp(-i^2 / (2 s^2)) for
|i| <= ceil(3 s), divided by their sum; outside the image the edge pixel is repeated
(clamp to edge). r is null when fewer than 16 pixels are inside, or when either band-pass
image has a variance (mean squared deviation over those pixels) below 1e-12. m is the mean
of the non-null r (null when there are none).

Written from the definition above; shares no code with the Rust implementation
(src/metrics/structure.rs).
"""
import json
import math
import sys

import numpy as np

MIN_PIXELS = 16
MIN_VARIANCE = 1e-12


def kernel(sigma):
    r = math.ceil(3 * sigma)
    i = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-i * i / (2 * sigma * sigma))
    return k / k.sum()


def blur_axis(img, k, axis):
    """Convolve img [H, W] along one axis with the symmetric kernel k, edges repeated."""
    r = len(k) // 2
    pad = [(0, 0), (0, 0)]
    pad[axis] = (r, r)
    p = np.pad(img, pad, mode="edge")
    n = img.shape[axis]
    out = np.zeros_like(img)
    for t, w in enumerate(k):
        out += w * (p[t:t + n, :] if axis == 0 else p[:, t:t + n])
    return out


def gaussian(img, sigma):
    k = kernel(sigma)
    return blur_axis(blur_axis(img, k, 1), k, 0)


def band_pass(rgb):
    y = rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114
    return gaussian(y, 1.0) - gaussian(y, 4.0)


def correlation(a, b):
    if a.size < MIN_PIXELS:
        return None
    da, db = a - a.mean(), b - b.mean()
    va, vb = (da * da).mean(), (db * db).mean()
    if va < MIN_VARIANCE or vb < MIN_VARIANCE:
        return None
    return float((da * db).mean() / math.sqrt(va * vb))


def main():
    args = sys.argv[1:]
    out = None
    if "--out" in args:
        k = args.index("--out")
        out = args[k + 1]
        del args[k:k + 2]
    src_dir, sty_dir = args
    src = np.load(f"{src_dir}/rgb.npy").astype(np.float64)
    sty = np.load(f"{sty_dir}/rgb.npy").astype(np.float64)
    alpha = np.load(f"{src_dir}/alpha.npy").astype(np.float64)
    assert src.shape == sty.shape and src.shape[:3] == alpha.shape, (src.shape, sty.shape, alpha.shape)
    per_view = []
    for v in range(src.shape[0]):
        inside = alpha[v] > 0.5
        per_view.append(correlation(band_pass(src[v])[inside], band_pass(sty[v])[inside]))
    have = [r for r in per_view if r is not None]
    res = {"per_view": per_view, "mean": sum(have) / len(have) if have else None}
    text = json.dumps(res)
    if out:
        with open(out, "w") as f:
            f.write(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
