#!/usr/bin/env python3
"""Independent float64 reference of the patch prior's exact denoiser (numpy only).

    patch_ref.py DIR

Reads DIR/style.npy (a clean image [C, h, w]), DIR/z.npy (noisy latents [B, C, h, w]) and
DIR/params.json ({"k", "sa", "sb", "guide_weight"}, optional DIR/guide_style.npy [h', w']
and DIR/guide_z.npy [B, h, w] structure channels), and writes DIR/x0.npy [B, C, h, w]:
for every pixel i of z, the posterior mean of the patch distribution of the style image,

    x0[i] = sum_j softmax_j(-||P_i(z) - sa y_j||^2 / (2 sb^2) - g ||G_i - H_j||^2) c_j

over ALL k x k patches y_j of the style (mirror padding, numpy "reflect"), c_j their centre
pixels. Written from the formula; shares no code with the Rust implementation.
"""
import json
import sys

import numpy as np


def patches(img, k):
    """All k x k patches of img [C, h, w] as rows [h*w, k*k*C] in (dy, dx, c) order."""
    c, h, w = img.shape
    r = k // 2
    pad = np.pad(img, ((0, 0), (r, r), (r, r)), mode="reflect")
    rows = np.empty((h * w, k * k * c), dtype=np.float64)
    for y in range(h):
        for x in range(w):
            win = pad[:, y:y + k, x:x + k]  # [C, k, k]
            rows[y * w + x] = np.transpose(win, (1, 2, 0)).reshape(-1)
    return rows


def main():
    d = sys.argv[1]
    p = json.load(open(f"{d}/params.json"))
    k, sa, sb = int(p["k"]), float(p["sa"]), float(p["sb"])
    g = float(p.get("guide_weight", 0.0))
    style = np.load(f"{d}/style.npy").astype(np.float64)
    z = np.load(f"{d}/z.npy").astype(np.float64)
    bank = patches(style, k)
    c = style.shape[0]
    mid = ((k // 2) * k + k // 2) * c
    centres = bank[:, mid:mid + c]
    if g > 0:
        gs = np.load(f"{d}/guide_style.npy").astype(np.float64)[None]
        gz = np.load(f"{d}/guide_z.npy").astype(np.float64)
        gbank = patches(gs, k)
    out = np.empty_like(z)
    for b in range(z.shape[0]):
        q = patches(z[b], k)
        d2 = ((q[:, None, :] - sa * bank[None, :, :]) ** 2).sum(-1)
        logit = -d2 / (2 * sb * sb)
        if g > 0:
            gq = patches(gz[b][None], k)
            logit -= g * ((gq[:, None, :] - gbank[None, :, :]) ** 2).sum(-1)
        logit -= logit.max(1, keepdims=True)
        wgt = np.exp(logit)
        wgt /= wgt.sum(1, keepdims=True)
        x0 = wgt @ centres  # [h*w, C]
        out[b] = x0.T.reshape(c, z.shape[2], z.shape[3])
    np.save(f"{d}/x0.npy", out.astype(np.float32))


if __name__ == "__main__":
    main()
