#!/usr/bin/env python3
"""Independent numpy forward passes of the metric networks, for checking the ONNX graphs.

Usage: metric_nets_ref.py REPO_ROOT   (run by scripts/setup/32_metric_nets_ref; idempotent)

Reads the same weights the ONNX graphs were built from (vendor/models/lpips/*/ .npy and
vendor/models/metrics/fid_inception_params.npz + fid_inception_layers.json) and computes,
in float64 and NHWC layout with hand-written ops (no onnx involved):

  * LPIPS AlexNet / VGG16: input scaling, conv/ReLU/max-pool stack, ReLU features at the
    five LPIPS taps, and the LPIPS distance (unit-normalise over channels, squared
    difference, linear head, spatial mean, sum over taps) for a few image pairs;
  * FID Inception-v3: TF-legacy bilinear resize to 299x299 (src = dst * in / out, clamp at
    the border), x*255/128 - 1 clamped to [-1, 0.9921875], conv + unfolded batch norm
    (eps 1e-3, no gamma) + ReLU, the Inception A-E blocks of the TF 2015 graph (as
    pytorch-fid's FIDInceptionA/C/E_1/E_2: average pools exclude padding, the last block
    max-pools), 8x8 average pool -> 2048-d pool3.

Writes vendor/models/metrics/ref/: images_lpips.npy [3,3,64,80], images_fid.npy
[2,3,72,100] (RGB in [0,1], NCHW), lpips_{alex,vgg16}_feat{k}.npy [3,C,h,w] float32,
lpips_{alex,vgg16}_dist.npy [3] float64 for the pairs (0,1), (0,2), (1,2),
fid_pool3.npy [2,2048] float32, ref.json.
The Rust tests (src/metrics/nets.rs) run the ONNX graphs on the same images and compare.
"""

import json
import os
import sys

import numpy as np

VERSION = 1


def test_images(n, h, w, seed):
    """Smooth colour gradients + sinusoids + a few discs: image-like, deterministic."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    imgs = []
    for _ in range(n):
        img = np.zeros((h, w, 3))
        for c in range(3):
            a, b, f, ph = rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(2, 9), rng.uniform(0, 6.3)
            img[..., c] = 0.5 + 0.25 * (a * xx + b * yy) + 0.2 * np.sin(f * (xx + yy * a) * 3.14 + ph)
        for _ in range(4):
            cy, cx, r = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.05, 0.25)
            m = (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
            img[m] = rng.uniform(0, 1, 3)
        img += rng.normal(0, 0.02, img.shape)
        imgs.append(np.clip(img, 0, 1))
    return np.stack(imgs).transpose(0, 3, 1, 2).astype(np.float32)  # NCHW


# ----------------------------------------------------------------- NHWC float64 ops


def conv2d(x, w_oihw, bias, stride, pad):
    """x [N,H,W,C]; weight OIHW; pad (ph, pw) symmetric."""
    n, h, w_, c = x.shape
    o, i, kh, kw = w_oihw.shape
    assert i == c, (i, c)
    sh, sw = stride
    ph, pw = pad
    xp = np.pad(x, ((0, 0), (ph, ph), (pw, pw), (0, 0)))
    ho = (h + 2 * ph - kh) // sh + 1
    wo = (w_ + 2 * pw - kw) // sw + 1
    wt = w_oihw.astype(np.float64).transpose(2, 3, 1, 0)  # kh, kw, I, O
    out = np.zeros((n, ho, wo, o))
    for dy in range(kh):
        for dx in range(kw):
            patch = xp[:, dy : dy + sh * (ho - 1) + 1 : sh, dx : dx + sw * (wo - 1) + 1 : sw, :]
            out += patch @ wt[dy, dx]
    if bias is not None:
        out += bias
    return out


def max_pool(x, k, s, p):
    n, h, w, c = x.shape
    xp = np.pad(x, ((0, 0), (p, p), (p, p), (0, 0)), constant_values=-np.inf)
    ho, wo = (h + 2 * p - k) // s + 1, (w + 2 * p - k) // s + 1
    out = np.full((n, ho, wo, c), -np.inf)
    for dy in range(k):
        for dx in range(k):
            out = np.maximum(out, xp[:, dy : dy + s * (ho - 1) + 1 : s, dx : dx + s * (wo - 1) + 1 : s, :])
    return out


def avg_pool(x, k, s, p, count_include_pad):
    n, h, w, c = x.shape
    xp = np.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))
    ones = np.pad(np.ones((1, h, w, 1)), ((0, 0), (p, p), (p, p), (0, 0)))
    ho, wo = (h + 2 * p - k) // s + 1, (w + 2 * p - k) // s + 1
    acc = np.zeros((n, ho, wo, c))
    cnt = np.zeros((1, ho, wo, 1))
    for dy in range(k):
        for dx in range(k):
            sl = (slice(None), slice(dy, dy + s * (ho - 1) + 1, s), slice(dx, dx + s * (wo - 1) + 1, s), slice(None))
            acc += xp[sl]
            cnt += ones[sl]
    return acc / (k * k if count_include_pad else cnt)


def relu(x):
    return np.maximum(x, 0.0)


# ----------------------------------------------------------------- LPIPS


def lpips_features(net_dir, images_nchw):
    with open(os.path.join(net_dir, "layout.json")) as f:
        layout = json.load(f)
    shift = np.array(layout["input"]["shift"])
    scale = np.array(layout["input"]["scale"])
    x = images_nchw.astype(np.float64).transpose(0, 2, 3, 1)
    x = (x * 2.0 - 1.0 - shift) / scale
    feats = []
    for layer in layout["layers"]:
        if layer["op"] == "conv":
            i = layer["index"]
            if i > max(layout["taps"]):
                break
            w = np.load(os.path.join(net_dir, f"conv{i}_weight.npy"))
            b = np.load(os.path.join(net_dir, f"conv{i}_bias.npy")).astype(np.float64)
            x = relu(conv2d(x, w, b, layer["stride"], layer["pad"][:2]))
            if i in layout["taps"]:
                feats.append(x)
        else:
            assert layer["pad"] == [0, 0, 0, 0]
            x = max_pool(x, layer["kernel"][0], layer["stride"][0], 0)
    lins = [np.load(os.path.join(net_dir, f"lin{k}.npy")).astype(np.float64) for k in range(len(feats))]
    return feats, lins


def lpips_distance(feats, lins, a, b):
    total = 0.0
    for f, lin in zip(feats, lins):
        fa, fb = f[a], f[b]
        na = fa / (np.sqrt((fa**2).sum(-1, keepdims=True)) + 1e-10)
        nb = fb / (np.sqrt((fb**2).sum(-1, keepdims=True)) + 1e-10)
        total += (((na - nb) ** 2) @ lin).mean()
    return total


# ----------------------------------------------------------------- Inception


def tf_legacy_resize(x, oh, ow):
    """Bilinear, src = dst * in / out (no half-pixel offset), indices clamped: x [N,H,W,C]."""
    n, h, w, c = x.shape

    def axis(o, i):
        src = np.arange(o) * (i / o)
        lo = np.clip(np.floor(src).astype(int), 0, i - 1)
        hi = np.clip(lo + 1, 0, i - 1)
        return lo, hi, src - np.floor(src)

    y0, y1, fy = axis(oh, h)
    x0, x1, fx = axis(ow, w)
    top = x[:, y0][:, :, x0] * (1 - fx)[None, None, :, None] + x[:, y0][:, :, x1] * fx[None, None, :, None]
    bot = x[:, y1][:, :, x0] * (1 - fx)[None, None, :, None] + x[:, y1][:, :, x1] * fx[None, None, :, None]
    return top * (1 - fy)[None, :, None, None] + bot * fy[None, :, None, None]


class Inception:
    def __init__(self, params, layers):
        self.p, self.l = params, layers

    def c(self, x, path):
        w = self.p[f"{path}.weight"]
        beta, mean, var = (self.p[f"{path}.{k}"].astype(np.float64) for k in ("beta", "mean", "var"))
        spec = self.l[path]
        y = conv2d(x, w, None, (spec["stride"], spec["stride"]), spec["padding"])
        return relu((y - mean) / np.sqrt(var + 1e-3) + beta)

    def seq(self, x, path, names):
        for n in names:
            x = self.c(x, f"{path}.{n}")
        return x

    def block_a(self, x, p):
        return np.concatenate([
            self.c(x, f"{p}.conv"),
            self.seq(x, f"{p}.tower", ["conv", "conv_1"]),
            self.seq(x, f"{p}.tower_1", ["conv", "conv_1", "conv_2"]),
            self.c(avg_pool(x, 3, 1, 1, False), f"{p}.tower_2.conv"),
        ], -1)

    def block_b(self, x, p):
        return np.concatenate([
            self.c(x, f"{p}.conv"),
            self.seq(x, f"{p}.tower", ["conv", "conv_1", "conv_2"]),
            max_pool(x, 3, 2, 0),
        ], -1)

    def block_c(self, x, p):
        return np.concatenate([
            self.c(x, f"{p}.conv"),
            self.seq(x, f"{p}.tower", ["conv", "conv_1", "conv_2"]),
            self.seq(x, f"{p}.tower_1", ["conv", "conv_1", "conv_2", "conv_3", "conv_4"]),
            self.c(avg_pool(x, 3, 1, 1, False), f"{p}.tower_2.conv"),
        ], -1)

    def block_d(self, x, p):
        return np.concatenate([
            self.seq(x, f"{p}.tower", ["conv", "conv_1"]),
            self.seq(x, f"{p}.tower_1", ["conv", "conv_1", "conv_2", "conv_3"]),
            max_pool(x, 3, 2, 0),
        ], -1)

    def block_e(self, x, p, last):
        a = self.c(x, f"{p}.tower_conv")
        b = self.c(self.c(x, f"{p}.tower_1_conv"), f"{p}.tower_1_conv_1")
        pooled = max_pool(x, 3, 1, 1) if last else avg_pool(x, 3, 1, 1, False)
        return np.concatenate([
            self.c(x, f"{p}.conv"),
            self.c(a, f"{p}.tower_mixed_conv"),
            self.c(a, f"{p}.tower_mixed_conv_1"),
            self.c(b, f"{p}.tower_1_mixed_conv"),
            self.c(b, f"{p}.tower_1_mixed_conv_1"),
            self.c(pooled, f"{p}.tower_2_conv"),
        ], -1)

    def __call__(self, images_nchw):
        x = images_nchw.astype(np.float64).transpose(0, 2, 3, 1)
        x = tf_legacy_resize(x, 299, 299)
        x = np.clip(x * 255.0 / 128.0 - 1.0, -1.0, 0.9921875)
        L = "layers"
        x = self.seq(x, L, ["conv", "conv_1", "conv_2"])
        x = max_pool(x, 3, 2, 0)
        x = self.seq(x, L, ["conv_3", "conv_4"])
        x = max_pool(x, 3, 2, 0)
        for m in ("mixed", "mixed_1", "mixed_2"):
            x = self.block_a(x, f"{L}.{m}")
        x = self.block_b(x, f"{L}.mixed_3")
        for m in ("mixed_4", "mixed_5", "mixed_6", "mixed_7"):
            x = self.block_c(x, f"{L}.{m}")
        x = self.block_d(x, f"{L}.mixed_8")
        x = self.block_e(x, f"{L}.mixed_9", last=False)
        x = self.block_e(x, f"{L}.mixed_10", last=True)
        assert x.shape[1:] == (8, 8, 2048), x.shape
        return x.mean(axis=(1, 2))


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.getcwd()
    metrics = os.path.join(root, "vendor", "models", "metrics")
    out = os.path.join(metrics, "ref")
    stamp = os.path.join(out, "ref.json")
    try:
        with open(stamp) as f:
            if json.load(f).get("version") == VERSION:
                print("metric_nets_ref: up to date")
                return
    except (OSError, ValueError):
        pass
    os.makedirs(out, exist_ok=True)
    imgs = test_images(3, 64, 80, seed=7)
    np.save(os.path.join(out, "images_lpips.npy"), imgs)
    pairs = [(0, 1), (0, 2), (1, 2)]
    for net in ("alex", "vgg16"):
        feats, lins = lpips_features(os.path.join(root, "vendor", "models", "lpips", net), imgs)
        for k, f in enumerate(feats):
            np.save(os.path.join(out, f"lpips_{net}_feat{k}.npy"), f.transpose(0, 3, 1, 2).astype(np.float32))
        d = np.array([lpips_distance(feats, lins, a, b) for a, b in pairs])
        np.save(os.path.join(out, f"lpips_{net}_dist.npy"), d)
        print(f"metric_nets_ref: lpips {net} distances {d}")
    fid_imgs = test_images(2, 72, 100, seed=11)
    np.save(os.path.join(out, "images_fid.npy"), fid_imgs)
    params = dict(np.load(os.path.join(metrics, "fid_inception_params.npz")))
    with open(os.path.join(metrics, "fid_inception_layers.json")) as f:
        layers = json.load(f)
    pool3 = Inception(params, layers)(fid_imgs)
    np.save(os.path.join(out, "fid_pool3.npy"), pool3.astype(np.float32))
    print(f"metric_nets_ref: inception pool3 mean {pool3.mean():.5f} max {pool3.max():.5f}")
    with open(stamp, "w") as f:
        json.dump({"version": VERSION, "pairs": pairs, "precision": "float64 numpy, NHWC"}, f)


if __name__ == "__main__":
    main()
