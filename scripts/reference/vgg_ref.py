#!/usr/bin/env python3
"""Independent numpy reference for fantasystyle's VGG16 forward pass (src/vgg.rs).

Direct convolution as a sum of 9 shifted, zero-padded slices contracted with np.einsum
(no im2col, no GEMM library), in float64; 2x2 max-pool stride 2 (floor) via reshape;
ImageNet normalisation for inputs in [0, 1]. Writes the ReLU outputs relu1_2, relu2_2,
relu3_3 and relu4_3 of one input image.

    vgg_ref.py                       # narrow random weights (channels / 16) -> tests/golden/vgg/
    vgg_ref.py --weights DIR --out D # any conv{i}_weight.npy / conv{i}_bias.npy set (e.g. real VGG16)

The default writes its weights too (seeded numpy RNG), so the Rust test loads exactly
the same network through `Vgg16::load`. Deterministic; rerun only to regenerate.
"""
import argparse
import os

import numpy as np

MEAN = np.array([0.485, 0.456, 0.406])
STD = np.array([0.229, 0.224, 0.225])
BLOCKS = [2, 2, 3, 3]
CHANNELS = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512]
TAPS = {1: "relu1_2", 3: "relu2_2", 6: "relu3_3", 9: "relu4_3"}


def conv3x3(x, w, b):
    """x [C,H,W], w [O,C,3,3] -> [O,H,W]; stride 1, zero pad 1."""
    c, h, wd = x.shape
    xp = np.zeros((c, h + 2, wd + 2))
    xp[:, 1:-1, 1:-1] = x
    y = np.zeros((w.shape[0], h, wd))
    for ky in range(3):
        for kx in range(3):
            y += np.einsum("oc,chw->ohw", w[:, :, ky, kx], xp[:, ky:ky + h, kx:kx + wd])
    return y + b[:, None, None]


def pool(x):
    c, h, w = x.shape
    h2, w2 = h // 2, w // 2
    return x[:, :2 * h2, :2 * w2].reshape(c, h2, 2, w2, 2).max(axis=(2, 4))


def forward(img, weights):
    x = ((img - MEAN) / STD).transpose(2, 0, 1)
    out, i = {}, 0
    for bi, n in enumerate(BLOCKS):
        if bi > 0:
            x = pool(x)
        for _ in range(n):
            w, b = weights[i]
            x = np.maximum(conv3x3(x, w.astype(np.float64), b.astype(np.float64)), 0.0)
            if i in TAPS:
                out[TAPS[i]] = x
            i += 1
    return out


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--weights", help="directory of conv{i}_weight.npy / conv{i}_bias.npy")
    ap.add_argument("--out", default=os.path.join(here, "..", "..", "tests", "golden", "vgg"))
    ap.add_argument("--height", type=int, default=26)
    ap.add_argument("--width", type=int, default=19)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    rng = np.random.default_rng(20260121)
    weights = []
    cin = 3
    for i, c in enumerate(CHANNELS):
        if a.weights:
            w = np.load(os.path.join(a.weights, f"conv{i}_weight.npy"))
            b = np.load(os.path.join(a.weights, f"conv{i}_bias.npy"))
        else:
            cout = c // 16
            w = (rng.standard_normal((cout, cin, 3, 3)) * np.sqrt(2.0 / (9 * cin))).astype(np.float32)
            b = (rng.standard_normal(cout) * 0.05).astype(np.float32)
            np.save(os.path.join(a.out, f"conv{i}_weight.npy"), w)
            np.save(os.path.join(a.out, f"conv{i}_bias.npy"), b)
        weights.append((w, b))
        cin = w.shape[0]
    img = rng.random((a.height, a.width, 3)).astype(np.float32)
    np.save(os.path.join(a.out, "input.npy"), img)
    for name, f in forward(img.astype(np.float64), weights).items():
        np.save(os.path.join(a.out, f"{name}.npy"), f.astype(np.float32))
        print(f"{name}: shape {f.shape}, max {f.max():.4f}")


if __name__ == "__main__":
    main()
