#!/usr/bin/env python3
"""The histogram colour finish tried on plant x opart and not kept (docs/colour-transfer.md
"Tried and not kept"): a distilled scene's DC colours moved so
that its rendered object's colours follow the style image's whole distribution, not only
its mean and covariance.

    vendor/venv/bin/python scripts/histogram_finish_trial.py SCENE_PLY CAMERAS STYLE_PNG OUT_PLY

SCENE_PLY: an INRIA PLY of SH degree 0 (a `distill` result's scene.ply); CAMERAS: what
`render-views --cameras` takes (the benchmark case's source views); OUT_PLY: the result.
Each of two passes renders the scene (target/release/render-views, 256x256), takes the
object's un-premultiplied colours (alpha > 0.5, weighted by alpha, black background),
builds an iterative sliced transfer onto the style's pixels (Pitie et al. 2005: along 8
orthonormal bases, the style's principal axes first, then random rotations from seed 0,
each axis's colours moved by 1D quantile matching) and applies the same monotone maps to
every Gaussian's DC colour. Then, as for any benchmark row (benches/quality):
`render-views --scene OUT_PLY --cameras runs/S/source --width 256 --height 256 --out V`
and `evaluate --original runs/S/source --stylized V --style styles/T.png --reference
runs/S/T/eval-ref --out E`.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from quality_summary import read_png  # noqa: E402

C0 = 0.28209479177387814
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RENDER = os.path.join(ROOT, "target", "release", "render-views")


def read_ply(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    if "format binary_little_endian 1.0" not in header:
        sys.exit(f"{path}: only binary little-endian PLY")
    n = int(next(l for l in header if l.startswith("element vertex")).split()[2])
    props = [l.split()[2] for l in header if l.startswith("property")]
    if any(p.startswith("f_rest") for p in props):
        sys.exit(f"{path}: SH degree above 0 (f_rest_*): the trial maps DC colours only")
    dtype = np.dtype([(p, "<f4") for p in props])
    return data[:end], np.frombuffer(data[end:end + n * dtype.itemsize], dtype=dtype).copy()


def render(ply, cameras, out):
    subprocess.run([RENDER, "--scene", ply, "--cameras", cameras, "--width", "256",
                    "--height", "256", "--out", out], check=True, capture_output=True)
    return np.load(f"{out}/rgb.npy").reshape(-1, 3), np.load(f"{out}/alpha.npy").reshape(-1)


def weighted_quantiles(x, w, qs):
    order = np.argsort(x)
    x, w = x[order], w[order]
    cw = np.cumsum(w)
    return np.interp(qs, (cw - 0.5 * w) / cw[-1], x)


def sliced_maps(src, w, style, bases, rng):
    """(rotation, [(source quantiles, style quantiles)] per axis) for each basis."""
    qs = np.linspace(0.0, 1.0, 201)
    maps, x = [], src.copy()
    for k in range(bases):
        r = np.linalg.eigh(np.cov(style.T))[1] if k == 0 else np.linalg.qr(rng.normal(size=(3, 3)))[0]
        px, py = x @ r, style @ r
        axes = []
        for a in range(3):
            # Strictly increasing source quantiles, for np.interp.
            xq = np.maximum.accumulate(weighted_quantiles(px[:, a], w, qs) + np.arange(len(qs)) * 1e-9)
            yq = np.quantile(py[:, a], qs)
            axes.append((xq, yq))
            px[:, a] = np.interp(px[:, a], xq, yq)
        x = px @ r.T
        maps.append((r, axes))
    return maps


def apply_maps(maps, c):
    for r, axes in maps:
        p = c @ r
        for a, (xq, yq) in enumerate(axes):
            p[:, a] = np.interp(p[:, a], xq, yq)
        c = p @ r.T
    return c


def main(scene, cameras, style_png, out, passes=2, bases=8):
    header, g = read_ply(scene)
    style = read_png(style_png).reshape(-1, 3).astype(np.float64)
    rng = np.random.default_rng(0)
    current = scene
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(passes):
            rgb, alpha = render(current, cameras, os.path.join(tmp, "views"))
            keep = alpha > 0.5
            src = (rgb[keep] / alpha[keep, None]).astype(np.float64)
            maps = sliced_maps(src, alpha[keep], style, bases, rng)
            dc = np.stack([g[f"f_dc_{i}"] for i in range(3)], 1).astype(np.float64)
            c = apply_maps(maps, 0.5 + C0 * dc)
            for i in range(3):
                g[f"f_dc_{i}"] = ((c[:, i] - 0.5) / C0).astype(np.float32)
            with open(out, "wb") as f:
                f.write(header)
                f.write(g.tobytes())
            current = out


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    main(*sys.argv[1:])
