#!/usr/bin/env python3
"""Independent numpy reference for the radially averaged luminance power spectrum
(src/metrics/spectrum.rs), and its golden files.

Computed from the definitions with numpy only (float64): Rec. 709 luminance; for an
object view the alpha-windowed, zero-mean signal a (Y_obj - mu) (background luminance =
mean where alpha < 1e-3); for a style image (Y - mean) times a periodic 2D Hann window;
numpy.fft.fft2 power; frequencies from numpy.fft.fftfreq (cycles per pixel); 24 bands, 4
per octave, from 1/128 to 1/2 (the last band includes 1/2); band means divided by the
mean power over all non-DC samples; the peak is the band maximising mean power times
(f_hi^2 - f_lo^2), reported at its geometric centre; the distance is the RMS of log10
ratios over the bands both spectra have, band powers floored at 1e-8.

    python scripts/reference/spectrum_ref.py tests/golden/spectrum   # (re)write the goldens

Each case writes NAME_rgb.npy [H, W, 3] float32 (and NAME_alpha.npy [H, W] for object
cases), NAME_spectrum.npy [24] float32 (-1 for an empty band: the .npy reader refuses NaN) and an entry in
cases.json (kind, peak, and for some the distance to another case's spectrum).
"""
import json
import os
import sys

import numpy as np

F_MIN, BPO, BINS = 1.0 / 128.0, 4, 24


def edges():
    return F_MIN * 2.0 ** (np.arange(BINS + 1) / BPO)


def lum(rgb):
    rgb = rgb.astype(np.float64)
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def object_signal(rgb, alpha):
    y, a = lum(rgb), alpha.astype(np.float64)
    bg = y[a < 1e-3].mean() if (a < 1e-3).any() else 0.0
    obj = y - (1.0 - a) * bg  # = a * Y_obj
    mu = obj.sum() / a.sum()
    return obj - a * mu


def style_signal(rgb):
    y = lum(rgb)
    h, w = y.shape
    hann = lambda n: 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)
    return (y - y.mean()) * hann(h)[:, None] * hann(w)[None, :]


def spectrum(sig):
    h, w = sig.shape
    p = np.abs(np.fft.fft2(sig)) ** 2
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    f = np.hypot(fy, fx)
    nondc = f > 0
    norm = p[nondc].mean()
    e = edges()
    out = np.full(BINS, np.nan)
    for b in range(BINS):
        hi = f <= e[b + 1] + 1e-12 if b == BINS - 1 else f < e[b + 1]
        m = (f >= e[b]) & hi
        if m.any():
            out[b] = p[m].mean() / norm
    return out


def peak(s):
    e = edges()
    energy = np.where(np.isnan(s), -np.inf, s * (e[1:] ** 2 - e[:-1] ** 2))
    b = int(np.argmax(energy))
    return float(F_MIN * 2.0 ** ((b + 0.5) / BPO))


def distance(a, b):
    ok = ~np.isnan(a) & ~np.isnan(b)
    la, lb = np.log10(np.maximum(a[ok], 1e-8)), np.log10(np.maximum(b[ok], 1e-8))
    return float(np.sqrt(np.mean((la - lb) ** 2)))


def cases():
    rng = np.random.default_rng(21)
    out = []
    # A style-like image: two sinusoid families plus noise, odd size.
    h, w = 61, 90
    y, x = np.mgrid[0:h, 0:w]
    base = 0.5 + 0.2 * np.sin(2 * np.pi * (x * 0.9 + y * 0.3) / 11.0) + 0.1 * np.sin(2 * np.pi * y / 37.0)
    rgb = np.stack([base, base * 0.8 + 0.1, 1.0 - base], -1) + 0.05 * rng.standard_normal((h, w, 3))
    out.append(("style_odd", "style", np.clip(rgb, 0, 1), None))
    # A smooth random texture (noise blurred in Fourier space), even size.
    h, w = 96, 96
    n = np.fft.fft2(rng.standard_normal((h, w)))
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    tex = np.real(np.fft.ifft2(n * np.exp(-((np.hypot(fy, fx) - 0.08) ** 2) / (2 * 0.02 ** 2))))
    tex = 0.5 + 0.25 * tex / tex.std()
    rgb = np.clip(np.stack([tex, tex, tex * 0.7], -1), 0, 1)
    out.append(("style_band", "style", rgb, None))
    # An object: that texture on a soft-edged ellipse over black (other backgrounds: the
    # Rust unit test object_signal_removes_background_and_mean).
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot((xx - 45) / 32.0, (yy - 50) / 24.0)
    alpha = np.clip((1.0 - r) * 8.0, 0, 1)
    out.append(("object_black", "object", rgb * alpha[..., None], alpha))
    # A non-square object view with a different texture.
    h, w = 80, 112
    yy, xx = np.mgrid[0:h, 0:w]
    alpha = ((np.abs(xx - 50) < 30) & (np.abs(yy - 40) < 25)).astype(np.float64)
    t = 0.5 + 0.3 * np.sign(np.sin(2 * np.pi * xx / 7.0)) + 0.05 * rng.standard_normal((h, w))
    rgb = np.stack([t, t * 0.5, t * 0.2], -1) * alpha[..., None]
    out.append(("object_rect", "object", rgb, alpha))
    return out


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    os.makedirs(d, exist_ok=True)
    meta, spectra = [], {}
    for name, kind, rgb, alpha in cases():
        rgb = rgb.astype(np.float32)
        np.save(os.path.join(d, f"{name}_rgb.npy"), rgb)
        if alpha is not None:
            alpha = alpha.astype(np.float32)
            np.save(os.path.join(d, f"{name}_alpha.npy"), alpha)
            sig = object_signal(rgb, alpha)
        else:
            sig = style_signal(rgb)
        s = spectrum(sig)
        spectra[name] = s
        np.save(os.path.join(d, f"{name}_spectrum.npy"), np.where(np.isnan(s), -1.0, s).astype(np.float32))
        meta.append({"name": name, "kind": kind, "peak": peak(s)})
    for m in meta:
        if m["kind"] == "object":
            m["distance_to"] = "style_band"
            m["distance"] = distance(spectra[m["name"]], spectra["style_band"].astype(np.float32).astype(np.float64))
    with open(os.path.join(d, "cases.json"), "w") as f:
        json.dump(meta, f, indent=1)
    print("wrote", len(meta), "cases to", d)


if __name__ == "__main__":
    main()
