#!/usr/bin/env python3
"""Style images for quality benchmarks (numpy only; deterministic).

    make_styles.py OUT_DIR [SIZE] [--skimage-wheel WHEEL]
    make_styles.py --dev OUT_DIR [SIZE]      (the development styles only)

Writes three procedural styles far from the sample's style and from each other:
  painting.png  swirling brush strokes along a curl flow field, night-sky palette
  opart.png     concentric zig-zag rings, black / white / red, hard edges
  mosaic.png    stained glass: Voronoi cells in a warm palette with dark leading
and with --dev, instead, three development styles (for choosing settings outside the
benchmark; docs/texture-term.md "A texture term that carries arrangement"):
  tiles.png     coloured bricks in running bond with dark mortar (a regular arrangement)
  dots.png      yellow, red and green discs on a navy ground (small isolated motifs)
  waves.png     wavy parallel bands, navy / yellow / white, hard edges (a banded motif
                like opart's rings, without their centre)
and three photographs from scikit-image's sample data (licences in
benches/quality/styles/CREDITS.md):
  brick.png     scikit-image's `brick` (a brick-wall photo, CC0): the photographic texture,
                512x512 grayscale box-averaged to SIZE and written as RGB;
  astronaut.png scikit-image's `astronaut` (a portrait photograph of Eileen Collins, NASA,
                public domain): a style with recognisable content, 512x512 RGB
                box-averaged to SIZE;
  coffee.png    scikit-image's `coffee` (a cup on a saucer, CC0): a photograph of objects,
                600x400 RGB, the 400x400 square around the saucer (columns 80..480)
                area-averaged to SIZE;
  onblack.png   scikit-image's `retina` (a fundus photograph of a normal left eye, CC0):
                an object photographed on a black background (the disc of the retina,
                the corners black, ~23% of the area), 1411x1411 RGB baseline JPEG,
                decoded here (numpy only, within 3 levels of libjpeg's decoder) and
                area-averaged to SIZE.
The two content-bearing photographs are for measuring content leakage (issue 38): a
method that pastes the style image onto the scene shows a helmet, a cup. The files are
read from the scikit-image package's data directory without importing it (no pooch
download: they ship in the wheel): from an installed scikit-image, or from a wheel file
given with --skimage-wheel (`pip download --no-deps scikit-image==0.26.0` fetches one).
Skipped with a message when neither is available.
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


def tiles(size, seed=2):
    rng = np.random.default_rng(seed)
    s = size / 512
    palette = np.array([[40, 140, 150], [230, 140, 60], [245, 225, 170], [200, 70, 50],
                        [240, 190, 80], [150, 80, 50]], float)
    img = np.full((size, size, 3), 28.0)
    row_h, mortar = max(int(16 * s), 4), max(int(3 * s), 1)
    for y0 in range(0, size, row_h):
        x = -int(rng.uniform(0, 40 * s))
        while x < size:
            wdt = int(rng.uniform(24, 56) * s) + 2
            col = palette[rng.integers(0, len(palette))]
            ya, yb, xa, xb = y0, min(y0 + row_h - mortar, size), max(x, 0), min(x + wdt - mortar, size)
            if xb > xa:
                img[ya:yb, xa:xb] = col
            x += wdt
    return img * rng.uniform(0.88, 1.12, (size, size, 1))


def dots(size, seed=3):
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size, 3)) + [0, 12, 89]
    img += rng.uniform(0, 50, (size, size, 1)) * [1, 1, 0]
    y, x = np.mgrid[0:size, 0:size]
    cols = np.array([[255, 204, 25], [242, 76, 51], [51, 229, 153]], float)
    for _ in range(int(160 * (size / 256) ** 2)):
        cx, cy, r = rng.uniform(0, size), rng.uniform(0, size), rng.uniform(4, 10) * size / 256
        img[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = cols[rng.integers(0, 3)]
    return img


def waves(size):
    y, x = (np.mgrid[0:size, 0:size]) / size
    band = (x + y) * 11 + 0.6 * np.sin((x - y) * 2 * np.pi * 3)
    k = np.floor(band).astype(int) % 3
    return np.array([[20, 30, 90], [250, 205, 40], [245, 245, 235]], float)[k]


def read_png8(data):
    """An 8-bit grayscale or RGB, non-interlaced PNG (scikit-image's sample images) as
    uint8 [H, W] (grayscale) or [H, W, 3] (RGB)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat = 8, b""
    while pos < len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        t, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if t == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 8 or ctype not in (0, 2) or interlace != 0:
                raise ValueError(f"expected 8-bit grayscale or RGB, non-interlaced; got depth {depth} type {ctype}")
            ch = 1 if ctype == 0 else 3
        elif t == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + w * ch)
    out = np.zeros((h, w * ch), np.int64)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int64)
        prev = out[y - 1] if y else np.zeros(w * ch, np.int64)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) % 256
        else:
            # a = the byte one pixel to the left (ch bytes back), b = above, c = above-left.
            cur = np.zeros(w * ch, np.int64)
            for i in range(w * ch):
                a = cur[i - ch] if i >= ch else 0
                b = prev[i]
                c = prev[i - ch] if i >= ch else 0
                if f == 1:
                    p = a
                elif f == 3:
                    p = (a + b) // 2
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (line[i] + p) % 256
        out[y] = cur
    out = out.astype(np.uint8)
    return out.reshape(h, w) if ch == 1 else out.reshape(h, w, 3)


ZIGZAG = np.array([
    0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5,
    12, 19, 26, 33, 40, 48, 41, 34, 27, 20, 13, 6, 7, 14, 21, 28,
    35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51,
    58, 59, 52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63])


def huffman_lut(counts, symbols):
    """A JPEG Huffman table as a 65536-entry list: the next 16 bits -> (symbol, code
    length)."""
    lut = [None] * 65536
    code, k = 0, 0
    for length in range(1, 17):
        for _ in range(counts[length - 1]):
            lo = code << (16 - length)
            for v in range(lo, lo + (1 << (16 - length))):
                lut[v] = (symbols[k], length)
            code, k = code + 1, k + 1
        code <<= 1
    return lut


def jpeg_headers(data):
    """The tables and frame of a baseline JPEG: (quantisation tables, Huffman tables,
    (height, width), components [(id, h, v, table)], scan's {component: tables},
    entropy-coded data with the 0xFF00 stuffing removed)."""
    assert data[:2] == b"\xff\xd8", "not a JPEG"
    pos, qt, ht, frame = 2, {}, {}, None
    while True:
        marker = data[pos + 1]
        n = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        body = data[pos + 4:pos + 2 + n]
        if marker == 0xDB:
            i = 0
            while i < len(body):
                assert body[i] >> 4 == 0, "8-bit quantisation tables only"
                q = np.zeros(64)
                q[ZIGZAG] = np.frombuffer(body[i + 1:i + 65], np.uint8)
                qt[body[i] & 15] = q
                i += 65
        elif marker == 0xC4:
            i = 0
            while i < len(body):
                counts = list(body[i + 1:i + 17])
                ht[(body[i] >> 4, body[i] & 15)] = huffman_lut(counts, list(body[i + 17:i + 17 + sum(counts)]))
                i += 17 + sum(counts)
        elif marker == 0xC0:
            h, w, nc = struct.unpack(">HHB", body[1:6])
            frame = (h, w), [(body[6 + 3 * c], body[7 + 3 * c] >> 4, body[7 + 3 * c] & 15, body[8 + 3 * c])
                             for c in range(nc)]
        elif marker in (0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF, 0xDD):
            raise ValueError(f"marker {marker:#x}: baseline JPEG without restart markers only")
        elif marker == 0xDA:
            sel = {body[1 + 2 * c]: body[2 + 2 * c] for c in range(body[0])}
            pos += 2 + n
            break
        pos += 2 + n
    ent = data[pos:data.index(b"\xff\xd9", pos)].replace(b"\xff\x00", b"\xff")
    return qt, ht, frame[0], frame[1], sel, ent


def jpeg_coefficients(ht, size, comps, sel, ent):
    """Huffman-decode a baseline scan: per component its quantised DCT coefficients
    [blocks down, blocks across, 64] (natural order)."""
    b = np.frombuffer(ent + b"\x00" * 8, np.uint8).astype(np.uint64)
    # win[i]: the 32 bits from byte i on; the 16 bits from bit p: win[p >> 3] >> (16 - p % 8).
    win = ((b[:-3] << 24) | (b[1:-2] << 16) | (b[2:-1] << 8) | b[3:]).tolist()
    hmax, vmax = max(c[1] for c in comps), max(c[2] for c in comps)
    mx, my = -(-size[1] // (8 * hmax)), -(-size[0] // (8 * vmax))
    coef = [np.zeros((my * c[2], mx * c[1], 64)) for c in comps]
    pred, p = [0] * len(comps), 0

    def bits(s):  # the next s bits as JPEG's signed magnitude
        nonlocal p
        a = (win[p >> 3] >> (32 - (p & 7) - s)) & ((1 << s) - 1)
        p += s
        return a - (1 << s) + 1 if a < 1 << (s - 1) else a

    for by in range(my):
        for bx in range(mx):
            for ci, (cid, hs, vs, _) in enumerate(comps):
                dc, ac = ht[(0, sel[cid] >> 4)], ht[(1, sel[cid] & 15)]
                for v in range(vs):
                    for u in range(hs):
                        blk = coef[ci][by * vs + v, bx * hs + u]
                        s, length = dc[(win[p >> 3] >> (16 - (p & 7))) & 0xFFFF]
                        p += length
                        pred[ci] += bits(s) if s else 0
                        blk[0], k = pred[ci], 1
                        while k < 64:
                            rs, length = ac[(win[p >> 3] >> (16 - (p & 7))) & 0xFFFF]
                            p += length
                            if rs & 15 == 0:
                                if rs >> 4 != 15:
                                    break  # end of block
                                k += 16
                                continue
                            k += rs >> 4
                            blk[ZIGZAG[k]] = bits(rs & 15)
                            k += 1
    return coef


def upsample_h2v2(c):
    """libjpeg's 'fancy' 2x2 chroma upsampling (the triangle filter, its rounding)."""
    c = c.astype(np.int64)
    rows = np.empty((2 * c.shape[0], c.shape[1]), np.int64)
    rows[0::2] = 3 * c + np.vstack([c[:1], c[:-1]])
    rows[1::2] = 3 * c + np.vstack([c[1:], c[-1:]])
    out = np.empty((rows.shape[0], 2 * c.shape[1]), np.int64)
    out[:, 0::2] = (3 * rows + np.hstack([rows[:, :1], rows[:, :-1]]) + 8) >> 4
    out[:, 1::2] = (3 * rows + np.hstack([rows[:, 1:], rows[:, -1:]]) + 7) >> 4
    return out


def read_jpeg(data):
    """A baseline (sequential, Huffman) YCbCr JPEG, 4:2:0 or 4:4:4, without restart
    markers (scikit-image's sample JPEGs) as uint8 [H, W, 3] RGB: the inverse DCT in
    floating point, libjpeg's fancy upsampling, the JFIF colour transform. Within 3
    levels of libjpeg's integer decoder (Pillow's), 98% of the samples equal."""
    qt, ht, size, comps, sel, ent = jpeg_headers(data)
    assert len(comps) == 3, "YCbCr only"
    coef = jpeg_coefficients(ht, size, comps, sel, ent)
    x = np.arange(8)
    cm = np.cos((2 * x[:, None] + 1) * x[None, :] * np.pi / 16) / 2  # C[x, u], c(0) = 1/sqrt(2)
    cm[:, 0] /= np.sqrt(2)
    planes = []
    for (_, hs, vs, tq), co in zip(comps, coef):
        c = (co * qt[tq]).reshape(co.shape[:2] + (8, 8))
        pix = np.clip(np.round(np.einsum("xu,abuv,yv->abxy", cm, c, cm) + 128), 0, 255)
        pl = pix.transpose(0, 2, 1, 3).reshape(c.shape[0] * 8, c.shape[1] * 8)
        f = (comps[0][1] // hs, comps[0][2] // vs)
        assert f in ((1, 1), (2, 2)), "4:2:0 or 4:4:4 only"
        planes.append(upsample_h2v2(pl) if f == (2, 2) else pl)
    n0, n1 = planes[0].shape
    y, cb, cr = planes[0], planes[1][:n0, :n1] - 128.0, planes[2][:n0, :n1] - 128.0
    rgb = np.stack([y + 1.402 * cr, y - 0.344136 * cb - 0.714136 * cr, y + 1.772 * cb], -1)
    return np.clip(np.round(rgb), 0, 255)[:size[0], :size[1]].astype(np.uint8)


def area_matrix(n_in, n_out):
    """[n_out, n_in] weights of exact area averaging: output sample k covers the input
    interval [k n_in / n_out, (k + 1) n_in / n_out), each input pixel weighted by the
    length it overlaps (rows sum to 1; an integer factor is a plain box average)."""
    r = np.zeros((n_out, n_in))
    s = n_in / n_out
    for k in range(n_out):
        a, b = k * s, (k + 1) * s
        for i in range(int(np.floor(a)), min(int(np.ceil(b)), n_in)):
            r[k, i] = min(b, i + 1) - max(a, i)
    return r / r.sum(1, keepdims=True)


def skimage_file(name, wheel):
    """Bytes of skimage/data/NAME from a wheel or an installed scikit-image, else None."""
    if wheel:
        import zipfile
        with zipfile.ZipFile(wheel) as z:
            return z.read("skimage/data/" + name)
    import importlib.util
    spec = importlib.util.find_spec("skimage")  # finds the package without importing it
    if spec is None or not spec.submodule_search_locations:
        return None
    path = os.path.join(list(spec.submodule_search_locations)[0], "data", name)
    return open(path, "rb").read() if os.path.isfile(path) else None


def photo(name, size, wheel, x0=0, y0=0, side=None):
    """scikit-image's NAME: the square [x0, x0 + side) x [y0, y0 + side) (side: the
    shorter side) area-averaged to SIZE x SIZE, as RGB floats in [0, 255]; None when the
    data are not found."""
    data = skimage_file(name, wheel)
    if data is None:
        return None
    g = (read_jpeg(data) if name.endswith(".jpg") else read_png8(data)).astype(np.float64)
    side = side or min(g.shape[:2])
    g = g[y0:y0 + side, x0:x0 + side]
    r = area_matrix(side, size)
    if g.ndim == 2:
        return np.repeat((r @ g @ r.T)[..., None], 3, -1)
    return np.stack([r @ g[..., c] @ r.T for c in range(3)], -1)


def main():
    args = sys.argv[1:]
    wheel = None
    if "--skimage-wheel" in args:
        i = args.index("--skimage-wheel")
        if i + 1 >= len(args):
            sys.exit(__doc__)
        wheel = args[i + 1]
        del args[i:i + 2]
    dev = "--dev" in args
    if dev:
        args.remove("--dev")
    if len(args) not in (1, 2):
        sys.exit(__doc__)
    out = args[0]
    size = int(args[1]) if len(args) == 2 else 256
    os.makedirs(out, exist_ok=True)
    styles = [("painting", painting), ("opart", opart), ("mosaic", mosaic)]
    if dev:
        styles = [("tiles", tiles), ("dots", dots), ("waves", waves)]
    for name, f in styles:
        path = os.path.join(out, name + ".png")
        write_png(path, f(size))
        print("wrote", path)
    if dev:
        return
    # (file, output name, crop x0): the coffee photograph is 600x400, its saucer spans
    # columns ~75..480; the retina (onblack) is square, taken whole.
    for file, name, x0 in [("brick.png", "brick", 0), ("astronaut.png", "astronaut", 0),
                           ("coffee.png", "coffee", 80), ("retina.jpg", "onblack", 0)]:
        img = photo(file, size, wheel, x0=x0)
        path = os.path.join(out, name + ".png")
        if img is None:
            print(f"skipped {path}: scikit-image's data not found (give --skimage-wheel WHEEL)")
        else:
            write_png(path, img + 0.5)
            print("wrote", path)

if __name__ == "__main__":
    main()
