#!/usr/bin/env python3
"""Independent float64 reference of the view-consistency warp, its round trip and the
RMSE excess (numpy only).

    consistency_ref.py GEOMETRY_VIEWS IMAGE_VIEWS --offset K [--out FILE]

GEOMETRY_VIEWS is a `views` artifact directory whose cameras.json (INRIA layout), depth.npy
[N, H, W] and alpha.npy [N, H, W] give the geometry; IMAGE_VIEWS one whose rgb.npy
[N, H, W, 3] gives the images (the same cameras). Prints (or writes to FILE) JSON

    {"pairs": [{"i": i, "j": j, "pair_valid": n, "round_trip_valid": m,
                "rmse": r, "excess_rmse": e}, ...]}

for the pairs (i, i + K), i = 0 .. N - K - 1. Definitions (src/metrics/consistency.rs and
src/maths/warp.rs, written again here from their docs):

    z      = depth / alpha where alpha > 0.5 and depth > 0, undefined elsewhere
    camera = R_w2c = rotation^T, t = -R_w2c position (INRIA cameras.json)
    warp(dst d, src s, image I_s, src depth z_s): for each pixel (x, y) of d with z_d
        defined, P = R_d^T (((x + 0.5 - cx) / fx z, (y + 0.5 - cy) / fy z, z) - t_d),
        q = R_s P + t_s; valid when q_z > 1e-9, u = fx_s q_x / q_z + cx_s - 0.5 and
        v = fy_s q_y / q_z + cy_s - 0.5 lie in [-1e-3, W - 1 + 1e-3] x [-1e-3, H - 1 + 1e-3]
        (then clamped to [0, W - 1] x [0, H - 1]), every bilinear neighbour with weight
        > 1e-6 has z_s defined, and |q_z - z_bar| <= 0.03 q_z where z_bar is the
        weight-normalised bilinear z_s over those neighbours; the value is the bilinear
        sample of I_s at (u, v).
    pair (i, j)        = warp(i, j, I_j, z_j)
    round trip (i, j)  = warp(i, j, T, z_j restricted to T's valid pixels), where
                         T = warp(j, i, I_i, z_i)
    rmse(A, B, mask)   = sqrt(mean over mask pixels and the 3 channels of (A - B)^2)
    rmse               = rmse(I_i, pair, pair mask) when the pair's valid pixels are at
                         least 2% of the image, else null
    excess_rmse        = rmse(I_i, pair, rt mask) - rmse(I_i, round trip, rt mask) when
                         rmse is not null and the round trip keeps at least half of the
                         pair's valid pixels, else null

Written from the definition above; shares no code with the Rust implementation.
"""
import json
import sys

import numpy as np

MIN_OVERLAP = 0.02
MIN_ROUND_TRIP = 0.5
DEPTH_REL_TOL = 0.03
SNAP = 1e-3


def cameras(path):
    out = []
    for c in json.load(open(path)):
        r = np.array(c["rotation"], dtype=np.float64).T
        t = -r @ np.array(c["position"], dtype=np.float64)
        cx = c.get("cx", c["width"] / 2.0)
        cy = c.get("cy", c["height"] / 2.0)
        out.append((r, t, float(c["fx"]), float(c["fy"]), float(cx), float(cy)))
    return out


def warp(cams, z, d, s, image, z_src):
    """`image` (view s's frame, depth z_src) warped into view d; returns (values, mask)."""
    h, w = z.shape[1:]
    rd, td, fx, fy, cx, cy = cams[d]
    rs, ts, sfx, sfy, scx, scy = cams[s]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    zd = z[d]
    defined = np.isfinite(zd)
    zz = np.where(defined, zd, 1.0)
    cam = np.stack([(xs + 0.5 - cx) / fx * zz, (ys + 0.5 - cy) / fy * zz, zz], -1)
    world = (cam - td) @ rd
    q = world @ rs.T + ts
    qz = q[..., 2]
    front = qz > 1e-9
    qz_safe = np.where(front, qz, 1.0)
    u = sfx * q[..., 0] / qz_safe + scx - 0.5
    v = sfy * q[..., 1] / qz_safe + scy - 0.5
    inside = (u >= -SNAP) & (v >= -SNAP) & (u <= w - 1 + SNAP) & (v <= h - 1 + SNAP)
    ok = defined & front & inside
    u = np.clip(np.where(ok, u, 0.0), 0, w - 1)
    v = np.clip(np.where(ok, v, 0.0), 0, h - 1)
    x0 = np.floor(u).astype(int)
    y0 = np.floor(v).astype(int)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fu, fv = u - x0, v - y0
    taps = [
        ((1 - fu) * (1 - fv), y0, x0),
        (fu * (1 - fv), y0, x1),
        ((1 - fu) * fv, y1, x0),
        (fu * fv, y1, x1),
    ]
    zsum = np.zeros_like(u)
    wsum = np.zeros_like(u)
    for wt, yy, xx in taps:
        used = wt > 1e-6
        zn = z_src[yy, xx]
        ok &= ~used | np.isfinite(zn)
        zsum += np.where(used & np.isfinite(zn), wt * np.nan_to_num(zn), 0.0)
        wsum += np.where(used, wt, 0.0)
    ok &= wsum > 0
    zbar = zsum / np.where(wsum > 0, wsum, 1.0)
    ok &= np.abs(qz - zbar) <= DEPTH_REL_TOL * qz
    values = sum(wt[..., None] * image[yy, xx] for wt, yy, xx in taps)
    return values, ok


def rmse(a, b, mask):
    if not mask.any():
        return 0.0
    return float(np.sqrt(((a - b) ** 2)[mask].mean()))


def main():
    args = sys.argv[1:]
    out = None
    if "--out" in args:
        k = args.index("--out")
        out = args[k + 1]
        del args[k : k + 2]
    k = args.index("--offset")
    offset = int(args[k + 1])
    del args[k : k + 2]
    geometry, images = args
    depth = np.load(f"{geometry}/depth.npy").astype(np.float64)
    alpha = np.load(f"{geometry}/alpha.npy").astype(np.float64)
    rgb = np.load(f"{images}/rgb.npy").astype(np.float64)
    cams = cameras(f"{geometry}/cameras.json")
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where((alpha > 0.5) & (depth > 0), depth / alpha, np.nan)
    n, h, w = z.shape
    pairs = []
    for i in range(n - offset):
        j = i + offset
        pair, pm = warp(cams, z, i, j, rgb[j], z[j])
        there, tm = warp(cams, z, j, i, rgb[i], z[i])
        back, rm = warp(cams, z, i, j, there, np.where(tm, z[j], np.nan))
        row = {"i": i, "j": j, "pair_valid": int(pm.sum()), "round_trip_valid": int(rm.sum())}
        measured = pm.sum() >= MIN_OVERLAP * h * w
        row["rmse"] = rmse(rgb[i], pair, pm) if measured else None
        row["excess_rmse"] = (
            rmse(rgb[i], pair, rm) - rmse(rgb[i], back, rm)
            if measured and rm.sum() >= MIN_ROUND_TRIP * pm.sum()
            else None
        )
        pairs.append(row)
    text = json.dumps({"pairs": pairs})
    if out:
        open(out, "w").write(text)
    else:
        print(text)


if __name__ == "__main__":
    main()
