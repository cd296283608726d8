#!/usr/bin/env python3
"""PSNR and mean |difference| between two views artifacts of the same cameras
(docs/splitting.md: a split scene's renders against the
unsplit scene's).

    vendor/venv/bin/python scripts/psnr_views.py VIEWS_A VIEWS_B

Reads each artifact's rgb.npy [N,H,W,3] (values in [0, 1]) and prints, per view, the
PSNR (peak 1) and the mean |rgb difference|, then the minimum and median PSNR.
"""
import sys

import numpy as np


def main(a_dir, b_dir):
    a = np.load(f"{a_dir}/rgb.npy").astype(np.float64)
    b = np.load(f"{b_dir}/rgb.npy").astype(np.float64)
    if a.shape != b.shape:
        sys.exit(f"{a_dir} and {b_dir}: rgb.npy shapes differ ({a.shape} vs {b.shape})")
    psnr = []
    for i in range(len(a)):
        mse = float(((a[i] - b[i]) ** 2).mean())
        psnr.append(float("inf") if mse == 0 else -10.0 * np.log10(mse))
        print(f"view {i:3d}: PSNR {psnr[-1]:.2f} dB, mean |d rgb| {np.abs(a[i] - b[i]).mean():.5f}")
    print(f"PSNR min {min(psnr):.2f} dB, median {float(np.median(psnr)):.2f} dB over {len(psnr)} views")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(*sys.argv[1:])
