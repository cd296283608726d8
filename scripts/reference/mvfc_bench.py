#!/usr/bin/env python3
"""numpy side of the MVFC benchmark (benches/mvfc.rs runs this on the same arrays).

    python scripts/reference/mvfc_bench.py DIR REPS

For every CASE_z.npy / CASE_eps.npy in DIR (and DIR/cases.json with gamma, d_s, d_t),
times two numpy versions of the filter on the same float32 arrays, single-threaded
(numpy.fft / pocketfft), and prints one JSON object {case: {"paper_s": .., "linear_s": ..}}
with the median wall time of REPS runs:
  paper_s:  as the paper writes it: fftn of z and eps', fftshift, H F + L (g F + (1-g) G),
            ifftshift, ifftn, real part (two forward and one inverse 3D FFT per channel);
  linear_s: the same single-transform form as the Rust code: z + (1-g) Re ifftn(L fftn(eps'-z)).
"""
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mvfc_ref import axis_factor  # noqa: E402


def paper(z, eps, lpf, gamma):
    axes = (0, 2, 3)
    fz = np.fft.fftshift(np.fft.fftn(z, axes=axes), axes=axes)
    fe = np.fft.fftshift(np.fft.fftn(np.broadcast_to(eps[None], z.shape), axes=axes), axes=axes)
    mixed = (1 - lpf) * fz + lpf * (gamma * fz + (1 - gamma) * fe)
    return np.fft.ifftn(np.fft.ifftshift(mixed, axes=axes), axes=axes).real.astype(np.float32)


def linear(z, eps, lpf_unshifted, gamma):
    axes = (0, 2, 3)
    d = np.fft.fftn(eps[None] - z, axes=axes)
    return z + (1 - gamma) * np.fft.ifftn(lpf_unshifted * d, axes=axes).real.astype(np.float32)


def median_time(f, reps):
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main(d, reps):
    cases = json.load(open(os.path.join(d, "cases.json")))
    out = {}
    for name, p in sorted(cases.items()):
        z = np.load(os.path.join(d, f"{name}_z.npy"))
        eps = np.load(os.path.join(d, f"{name}_eps.npy"))
        n, _, h, w = z.shape
        mv, my, mx = axis_factor(n, p["d_t"]), axis_factor(h, p["d_s"]), axis_factor(w, p["d_s"])
        lpf = (mv[:, None, None, None] * my[None, None, :, None] * mx[None, None, None, :]).astype(np.float32)
        lpf_u = np.fft.ifftshift(lpf, axes=(0, 2, 3))
        g = p["gamma"]
        a = paper(z, eps, lpf, g)
        np.save(os.path.join(d, f"{name}_numpy.npy"), a)
        out[name] = {
            "paper_s": median_time(lambda: paper(z, eps, lpf, g), reps),
            "linear_s": median_time(lambda: linear(z, eps, lpf_u, g), reps),
        }
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5)
