#!/usr/bin/env python3
"""Screen size of a scene's Gaussians at the style projection's scale (BENCHMARKS.md,
"Plant x opart" / the plant x brick correction).

For the Gaussians of opacity >= 0.5 (those `Placement::of` uses for the object's centre),
prints percentiles of 2 sigma along the middle and the longest axis, in render pixels at
the object: sigma / world_per_pixel, with world_per_pixel = median over the cameras of
depth(centre) / fx, as in `src/baselines/projection.rs`.

    vendor/venv/bin/python scripts/gaussian_footprint.py SCENE.splat CAMERAS.json

SCENE: an antimatter15 `.splat` (32 bytes per Gaussian: position, linear scales, RGBA,
quaternion); CAMERAS: an INRIA cameras.json (e.g. a views artifact's).
"""
import json
import sys

import numpy as np


def main(scene, cameras):
    b = np.fromfile(scene, dtype=np.uint8)
    n = len(b) // 32
    a = b[: n * 32].reshape(n, 32)
    pos = a[:, :12].copy().view(np.float32).reshape(n, 3).astype(np.float64)
    scale = np.sort(a[:, 12:24].copy().view(np.float32).reshape(n, 3), axis=1)
    keep = a[:, 27] / 255.0 >= 0.5
    centre = np.median(pos[keep], axis=0)
    per_px = []
    for c in json.load(open(cameras)):
        forward = np.array(c["rotation"])[:, 2]  # camera-to-world: third column is +z
        depth = float((centre - np.array(c["position"])) @ forward)
        per_px.append(depth / c["fx"])
    wpp = float(np.median(per_px))
    print(f"{scene}: {n} Gaussians, {keep.sum()} of opacity >= 0.5, {wpp:.3e} world units per px")
    for name, axis in [("middle axis", 1), ("longest axis", 2)]:
        px = 2.0 * scale[keep, axis] / wpp
        q = np.percentile(px, [25, 50, 75, 90])
        print(f"  2 sigma along the {name}, px: p25 {q[0]:.2f}  median {q[1]:.2f}  p75 {q[2]:.2f}  p90 {q[3]:.2f}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
