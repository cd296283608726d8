#!/usr/bin/env python3
"""Procedural style images for quality benchmarks (numpy only; deterministic).

    make_styles.py OUT_DIR [SIZE]

Writes three styles far from the sample's style and from each other:
  painting.png  swirling brush strokes along a curl flow field, night-sky palette
  opart.png     concentric zig-zag rings, black / white / red, hard edges
  mosaic.png    stained glass: Voronoi cells in a warm palette with dark leading
"""
import os
import struct
import sys
import zlib

import numpy as np


def write_png(path, img):
    img = np.ascontiguousarray(np.clip(img, 0, 255).astype(np.uint8))
    h, w, _ = img.shape
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 9)))
        f.write(chunk(b"IEND", b""))


def painting(size, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    psi = np.zeros_like(x)
    for _ in range(7):
        cx, cy, r, s = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.1, 0.3), rng.choice([-1, 1])
        psi += s * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * r * r))
    psi += 0.3 * np.sin(3 * x + 2 * y)
    gy, gx = np.gradient(psi)
    vx, vy = gy, -gx
    n = np.hypot(vx, vy) + 1e-9
    vx, vy = vx / n, vy / n
    palette = np.array([[18, 32, 92], [36, 74, 160], [80, 130, 200], [230, 200, 60],
                        [250, 235, 140], [20, 60, 60], [245, 245, 220]], float)
    base = np.clip(psi - psi.min(), 0, None)
    base = base / base.max()
    canvas = palette[np.clip((base * 3).astype(int), 0, 2)].copy()
    scale = size / 512
    for _ in range(int(9000 * scale * scale)):
        px, py = rng.uniform(0, size, 2)
        col = palette[rng.choice(7, p=[.22, .25, .2, .12, .08, .08, .05])] * rng.uniform(0.85, 1.1)
        length, wdt = int(rng.integers(8, 28) * scale) + 2, max(rng.uniform(1.5, 3.5) * scale, 1.0)
        for _ in range(length):
            ix, iy = int(px) % size, int(py) % size
            x0, x1 = max(ix - int(wdt), 0), min(ix + int(wdt) + 1, size)
            y0, y1 = max(iy - int(wdt), 0), min(iy + int(wdt) + 1, size)
            canvas[y0:y1, x0:x1] = 0.35 * canvas[y0:y1, x0:x1] + 0.65 * col
            px += 1.5 * vx[iy, ix]
            py += 1.5 * vy[iy, ix]
    return canvas


def opart(size):
    y, x = (np.mgrid[0:size, 0:size] - size / 2) / size
    r, a = np.hypot(x, y), np.arctan2(y, x)
    ring = r * 18 + 0.35 * np.abs(((a * 12 / np.pi) % 2) - 1)
    k = np.floor(ring).astype(int) % 3
    return np.array([[10, 10, 10], [245, 245, 240], [210, 30, 35]], float)[k]


def mosaic(size, seed=1):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, size, (90, 2))
    palette = np.array([[200, 60, 30], [240, 170, 40], [120, 30, 90], [40, 110, 60],
                        [250, 220, 150], [170, 90, 40]], float)
    cols = palette[rng.integers(0, len(palette), len(pts))] * rng.uniform(0.8, 1.1, (len(pts), 1))
    y, x = np.mgrid[0:size, 0:size]
    d = (x[..., None] - pts[:, 0]) ** 2 + (y[..., None] - pts[:, 1]) ** 2
    order = np.argsort(d, axis=-1)
    near = order[..., 0]
    d1 = np.take_along_axis(d, order[..., :2], -1)
    edge = np.sqrt(d1[..., 1]) - np.sqrt(d1[..., 0]) < 3.0 * size / 512 + 1.0
    img = cols[near]
    img[edge] = [25, 20, 20]
    return img


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    out = sys.argv[1]
    size = int(sys.argv[2]) if len(sys.argv) == 3 else 256
    os.makedirs(out, exist_ok=True)
    for name, f in [("painting", painting), ("opart", opart), ("mosaic", mosaic)]:
        path = os.path.join(out, name + ".png")
        write_png(path, f(size))
        print("wrote", path)


if __name__ == "__main__":
    main()
