#!/usr/bin/env python3
"""Screen size of a scene's Gaussians at the style projection's scale (docs/texture-term.md,
"Plant x opart" / the plant x brick correction).

For the Gaussians of opacity >= 0.5 (those `Placement::of` uses for the object's centre),
prints percentiles of 2 sigma along the middle and the longest axis, in render pixels at
the object: sigma / world_per_pixel, with world_per_pixel = median over the cameras of
depth(centre) / fx, as in `src/baselines/projection.rs`.

    vendor/venv/bin/python scripts/gaussian_footprint.py SCENE.splat CAMERAS.json [--by-height]

With --by-height (docs/style-projection.md "Normals from the rendered surface"), also for all
Gaussians, in the lowest 30% of the object's height (-y up; the plant's pot) and the
rest: the same sizes weighted by covered area (opacity x the two largest scales), and
the area-weighted share whose axis of smallest scale lies within 37 degrees (|cos| > 0.8)
of the direction away from the vertical axis through the object's centre (for a pot
around that axis, its radial direction; 20% for random directions).

SCENE: an antimatter15 `.splat` (32 bytes per Gaussian: position, linear scales, RGBA,
quaternion); CAMERAS: an INRIA cameras.json (e.g. a views artifact's).
"""
import json
import sys

import numpy as np


def load(scene, cameras):
    """The .splat's raw records [n, 32], positions, scales (as stored), opacities, the
    solid Gaussians (opacity >= 0.5), their per-axis median centre and the world length
    of one render pixel there (median over the cameras of depth / fx)."""
    b = np.fromfile(scene, dtype=np.uint8)
    n = len(b) // 32
    a = b[: n * 32].reshape(n, 32)
    pos = a[:, :12].copy().view(np.float32).reshape(n, 3).astype(np.float64)
    scale = a[:, 12:24].copy().view(np.float32).reshape(n, 3).astype(np.float64)
    op = a[:, 27] / 255.0
    solid = op >= 0.5
    centre = np.median(pos[solid], axis=0)
    per_px = []
    for c in json.load(open(cameras)):
        forward = np.array(c["rotation"])[:, 2]  # camera-to-world: third column is +z
        depth = float((centre - np.array(c["position"])) @ forward)
        per_px.append(depth / c["fx"])
    return a, pos, scale, op, solid, centre, float(np.median(per_px))


def main(scene, cameras):
    a, _, scale, _, keep, _, wpp = load(scene, cameras)
    scale = np.sort(scale, axis=1)
    print(f"{scene}: {len(a)} Gaussians, {keep.sum()} of opacity >= 0.5, {wpp:.3e} world units per px")
    for name, axis in [("middle axis", 1), ("longest axis", 2)]:
        px = 2.0 * scale[keep, axis] / wpp
        q = np.percentile(px, [25, 50, 75, 90])
        print(f"  2 sigma along the {name}, px: p25 {q[0]:.2f}  median {q[1]:.2f}  p75 {q[2]:.2f}  p90 {q[3]:.2f}")


def quat_axes(a):
    """Rotation matrices [n, 3, 3] of the .splat's quaternions (w, x, y, z as (v - 128) / 128)."""
    q = (a[:, 28:32].astype(np.float64) - 128.0) / 128.0
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def weighted_quantiles(x, w, qs):
    o = np.argsort(x)
    c = np.cumsum(w[o])
    c /= c[-1]
    return [x[o][min(np.searchsorted(c, q), len(x) - 1)] for q in qs]


def by_height(scene, cameras):
    a, pos, scale, op, solid, centre, wpp = load(scene, cameras)
    n = len(a)
    s = np.sort(scale, axis=1)
    area = op * s[:, 1] * s[:, 2]
    normal = quat_axes(a)[np.arange(n), :, np.argmin(scale, axis=1)]
    radial = pos - centre
    radial[:, 1] = 0.0
    radial /= np.linalg.norm(radial, axis=1, keepdims=True) + 1e-12
    aligned = np.abs((normal * radial).sum(1)) > 0.8
    up = -pos[:, 1]
    lo, hi = np.percentile(up[solid], [2, 98])
    low = up < lo + 0.3 * (hi - lo)
    for name, m in [("all", np.ones(n, bool)), ("lowest 30%", low), ("the rest", ~low)]:
        mid, lng = (2.0 * s[m, k] / wpp for k in (1, 2))
        print(f"  {name}: {m.sum()} Gaussians; area-weighted 2 sigma px, middle axis p25/50/75 "
              + " ".join(f"{v:.2f}" for v in weighted_quantiles(mid, area[m], [0.25, 0.5, 0.75]))
              + ", longest " + " ".join(f"{v:.2f}" for v in weighted_quantiles(lng, area[m], [0.25, 0.5, 0.75]))
              + f"; axis within 37 deg of radial: {area[m][aligned[m]].sum() / area[m].sum():.2f} of the area")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--by-height"]
    if len(args) != 2:
        sys.exit(__doc__)
    main(*args)
    if "--by-height" in sys.argv:
        by_height(*args)
