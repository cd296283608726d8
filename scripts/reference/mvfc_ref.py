#!/usr/bin/env python3
"""Independent numpy reference for MVFC (FantasyStyle Sec. 4), and the golden files.

Computes the filter exactly as the paper writes it, with numpy.fft in float64:
fftshift-ed spectra of z_t and of the shared noise eps' (broadcast over views), a
Gaussian low-pass mask L built on the centred grid from numpy.fft.fftfreq (FreeInit's
mask with signed-frequency indexing; see src/mvfc.rs), H = 1 - L, and
z_t' = Re ifftn(ifftshift(H F + L (gamma F + (1 - gamma) G))).
Unlike the Rust code it does not use the linearity shortcut and transforms both arrays.

    python scripts/reference/mvfc_ref.py tests/golden/mvfc   # (re)write the golden files

Each case writes CASE_z.npy [N,C,h,w], CASE_eps.npy [C,h,w], CASE_out.npy and a line in
cases.json with gamma, d_s, d_t. The NOISE_FREE cases have eps' = 0, so their output is
the filter's action on z alone, (H + gamma L) z: the mvfc-filter stage test takes the
difference of two runs that share eps' (MVFC is linear) and compares it with them.
They also write CASE_path_out.npy: the filter on an open camera path (the N views are
not a circle, so the view axis is extended by its mirror image v0 .. v_{N-1},
v_{N-2} .. v1 before the FFT and cut back to N views after), which the mvfc-filter stage
applies to latents that record no iteration (one window of an open path).
"""
import json
import os
import sys

import numpy as np


def axis_factor(n, cutoff):
    d = 2.0 * np.fft.fftshift(np.fft.fftfreq(n) * n) / n  # centred, in [-1, 1)
    if np.isinf(cutoff):
        return np.ones(n)
    if cutoff <= 0:
        return (d == 0).astype(np.float64)
    return np.exp(-(d ** 2) / (2.0 * cutoff ** 2))


def low_pass_mask(n, h, w, d_s, d_t):
    """Centred (fftshift-ed) mask [n, h, w]."""
    mv, my, mx = axis_factor(n, d_t), axis_factor(h, d_s), axis_factor(w, d_s)
    return mv[:, None, None] * my[None, :, None] * mx[None, None, :]


def mvfc(z, eps, gamma, d_s, d_t):
    """z [N,C,h,w], eps [C,h,w] -> filtered [N,C,h,w] (float64)."""
    n, c, h, w = z.shape
    lpf = low_pass_mask(n, h, w, d_s, d_t)
    hpf = 1.0 - lpf
    out = np.empty(z.shape, dtype=np.float64)
    axes = (0, 1, 2)
    for ch in range(c):
        zc = z[:, ch].astype(np.float64)
        ec = np.broadcast_to(eps[ch].astype(np.float64), zc.shape)
        fz = np.fft.fftshift(np.fft.fftn(zc, axes=axes), axes=axes)
        fe = np.fft.fftshift(np.fft.fftn(ec, axes=axes), axes=axes)
        mixed = hpf * fz + lpf * (gamma * fz + (1.0 - gamma) * fe)
        out[:, ch] = np.fft.ifftn(np.fft.ifftshift(mixed, axes=axes), axes=axes).real
    return out


def mvfc_open_path(z, eps, gamma, d_s, d_t):
    """MVFC of N views along an open path: the mirror-extended view axis, cut back."""
    n = z.shape[0]
    if n <= 2:
        return mvfc(z, eps, gamma, d_s, d_t)
    order = list(range(n)) + list(range(n - 2, 0, -1))
    return mvfc(z[order], eps, gamma, d_s, d_t)[:n]


CASES = [
    # name, shape, gamma, d_s, d_t
    ("default_4v", (4, 4, 8, 8), 0.9, 0.25, 0.25),
    ("odd_3v", (3, 2, 5, 7), 0.5, 0.4, 0.6),
    ("single_view", (1, 3, 6, 9), 0.2, 0.3, 0.25),
    ("strong_mix", (6, 4, 12, 10), 0.0, 0.5, 1.0),
]

# eps' = 0 (after CASES, so that their random draws stay as they were). stage_4v: the
# shape and default parameters of the mvfc-filter stage test.
NOISE_FREE = [
    ("stage_4v", (4, 4, 8, 6), 0.9, 0.25, 0.25),
]


def main(out_dir):
    os.makedirs(out_dir, exist_ok=True)
    rng = np.random.default_rng(20260101)
    meta = {}
    for name, shape, gamma, d_s, d_t in CASES:
        z = rng.standard_normal(shape).astype(np.float32)
        eps = rng.standard_normal(shape[1:]).astype(np.float32)
        out = mvfc(z, eps, gamma, d_s, d_t).astype(np.float32)
        np.save(os.path.join(out_dir, f"{name}_z.npy"), z)
        np.save(os.path.join(out_dir, f"{name}_eps.npy"), eps)
        np.save(os.path.join(out_dir, f"{name}_out.npy"), out)
        meta[name] = {"gamma": gamma, "d_s": d_s, "d_t": d_t}
    for name, shape, gamma, d_s, d_t in NOISE_FREE:
        z = rng.standard_normal(shape).astype(np.float32)
        eps = np.zeros(shape[1:], dtype=np.float32)
        out = mvfc(z, eps, gamma, d_s, d_t).astype(np.float32)
        np.save(os.path.join(out_dir, f"{name}_z.npy"), z)
        np.save(os.path.join(out_dir, f"{name}_eps.npy"), eps)
        np.save(os.path.join(out_dir, f"{name}_out.npy"), out)
        path = mvfc_open_path(z, eps, gamma, d_s, d_t).astype(np.float32)
        np.save(os.path.join(out_dir, f"{name}_path_out.npy"), path)
        meta[name] = {"gamma": gamma, "d_s": d_s, "d_t": d_t, "noise_free": True}
    with open(os.path.join(out_dir, "cases.json"), "w") as f:
        json.dump(meta, f, indent=1, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tests/golden/mvfc")
