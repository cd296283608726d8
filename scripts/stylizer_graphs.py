#!/usr/bin/env python3
"""The stylizer's float graphs against the shipped int8 ones (BENCHMARKS.md, "The
stylizer's transfer graph in float" and "Reproducibility across instruction sets").

Transfer graph: the mean |difference| of the two graphs' outputs on the test image of
`float_graphs_are_the_int8_network` (96x128: a checkerboard-modulated ramp, a vertical
ramp, a disc), both given the float graph's style vector of the test style image; the
relative difference layer by layer (at every activation the int8 graph quantizes: its own
8-bit rounding there, and the float graph's value against the int8 graph's); and, as a
control, a deliberately wrong rewrite (one weight scale for all output channels instead
of per-channel scales). Style prediction: the relative (L2) difference of the two style
vectors on the style image and the test image, and the wrong rewrite's. The int8 graphs
run as the ONNX standard defines them (no graph optimisation: each quantize / dequantize
an operator in float), as in the test.

    python3 -m venv /tmp/ortvenv && /tmp/ortvenv/bin/pip install onnxruntime==1.31.1 onnx numpy
    /tmp/ortvenv/bin/python scripts/stylizer_graphs.py [MODELS_DIR]   # vendor/models

(the onnxruntime Python package, which the set-up's venv does not carry).

Across instruction sets (issue 40): `--isa-dump OUT.npz` writes the style vectors of the
test style image from both predictors, with onnxruntime's full optimisation (the int8
graph's quantize/dequantize pairs fused into int8 kernels picked by instruction set) and
without; `--isa-compare A.npz B.npz ...` prints the largest differences between dumps.
Narrow the instruction set with qemu's user-mode emulator (it reports the CPU model's
features to onnxruntime's kernel dispatch):

    P=/tmp/ortvenv/bin/python; S=scripts/stylizer_graphs.py
    $P $S --isa-dump /tmp/native.npz
    qemu-x86_64 -cpu Haswell $P $S --isa-dump /tmp/avx2.npz     # AVX2 + FMA, no AVX-512
    qemu-x86_64 -cpu Nehalem $P $S --isa-dump /tmp/sse42.npz    # SSE4.2
    $P $S --isa-compare /tmp/native.npz /tmp/avx2.npz /tmp/sse42.npz
"""
import importlib.util
import os
import sys
import tempfile

import numpy as np
import onnx
import onnxruntime as ort

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def predictor_input(img):
    """[3, H, W] in [0, 1] -> the style-prediction graph's input as src/prior/stylizer.rs
    makes it (centre square crop, triangle-filter resize to 256, NHWC)."""
    ref = load_script("reference/stylizer_ref.py", "stylizer_ref")
    h, w = img.shape[1:]
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    x = ref.resize(img[:, top:top + side, left:left + side].astype(np.float64), 256, 256)
    return x.transpose(1, 2, 0)[None].astype(np.float32)


def style_image():
    s = np.load(os.path.join(ROOT, "tests/golden/csd/stylizer_style.npy"))
    return s.astype(np.float64).transpose(2, 0, 1) / 255


def load_script(rel, name):
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "scripts", rel))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def style_vector(models, img=None, variant="stylizer"):
    feed = {"style_image": predictor_input(style_image() if img is None else img)}
    return run(os.path.join(models, variant, "arbitrary_predict.onnx"), feeds=feed)[
        "mobilenet_conv/Conv/BiasAdd"]


def wrong_rewrite(src_graph, tmp):
    """The set-up's dequantize() with one weight scale for all output channels."""
    path = os.path.join(ROOT, "scripts/setup/20_stylizer.py")
    src = open(path).read()
    wrong = src.replace("scale, zp = scale.reshape(shape), zp.reshape(shape)", "scale, zp = scale[:1], zp[:1]")
    assert wrong != src, "the per-channel line of dequantize() moved: update this control"
    ns = {"__name__": "stylizer_setup_wrong"}
    exec(compile(wrong, path, "exec"), ns)
    p = os.path.join(tmp, os.path.basename(src_graph))
    onnx.save(onnx.load(src_graph), p)
    ns["dequantize"](p)
    return p


def run(model, feeds, outputs=(), level=None):
    """Outputs by name of `model` (a path or a ModelProto) on `feeds`, with `outputs`
    exposed as graph outputs; no graph optimisation unless `level`."""
    m = model if isinstance(model, onnx.ModelProto) else onnx.load(model)
    have = {o.name for o in m.graph.output}
    for name in outputs:
        if name not in have:
            m.graph.output.append(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, None))
    so = ort.SessionOptions()
    so.graph_optimization_level = level or ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    so.intra_op_num_threads = 1
    sess = ort.InferenceSession(m.SerializeToString(), so)
    return dict(zip([o.name for o in sess.get_outputs()], sess.run(None, feeds)))


def test_image():
    y, x = np.mgrid[0:96, 0:128]
    check = np.where((x // 16 + y // 16) % 2 == 0, 0.8, 0.2)
    disc = np.where(np.hypot(x - 64, y - 48) < 30, 0.9, 0.1)
    return np.stack([0.5 * x / 127 + 0.5 * check, y / 95, disc], -1)[None].astype(np.float32)


def main(models):
    # Style prediction.
    rel = lambda u, v: float(np.linalg.norm(u - v) / np.linalg.norm(v))  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        wrong = wrong_rewrite(os.path.join(models, "stylizer-int8/arbitrary_predict.onnx"), tmp)
        for name, img in [("style image", None), ("96x128 test image", test_image()[0].transpose(2, 0, 1))]:
            f, q = style_vector(models, img), style_vector(models, img, "stylizer-int8")
            feed = {"style_image": predictor_input(style_image() if img is None else img)}
            c = run(wrong, feed)["mobilenet_conv/Conv/BiasAdd"]
            print(f"style vector, {name}: float vs int8 relative difference {rel(f, q):.3f}; "
                  f"control (one weight scale for all channels) {rel(c, q):.3f}")

    # Transfer.
    int8 = os.path.join(models, "stylizer-int8/arbitrary_transform.onnx")
    flt = os.path.join(models, "stylizer/arbitrary_transform.onnx")
    feeds = {"content_image": test_image(), "mobilenet_conv/Conv/BiasAdd": style_vector(models)}
    out = "transformer/expand/conv3/conv/Sigmoid"
    a, b = run(flt, feeds)[out], run(int8, feeds)[out]
    print(f"float vs int8 output: mean |difference| {np.abs(a - b).mean():.4f}")

    # Layer by layer: the float value entering each quantize-dequantize pair of the int8 graph.
    g8 = onnx.load(int8)
    producer = {o: n for n in g8.graph.node for o in n.output}
    pairs = [(producer[n.input[0]].input[0], n.output[0]) for n in g8.graph.node
             if n.op_type == "DequantizeLinear" and n.input[0] in producer
             and producer[n.input[0]].op_type == "QuantizeLinear"]
    o8 = run(g8, feeds, [x for p in pairs for x in p])
    gf = onnx.load(flt)
    names = {o for n in gf.graph.node for o in n.output}
    of = run(gf, feeds, [x for x, _ in pairs if x in names])
    rel = lambda u, v: float(np.abs(u - v).mean() / (np.abs(v).mean() + 1e-12))  # noqa: E731
    print("activation (int8 graph order) | int8's own rounding | float vs int8")
    for x, dq in pairs:
        if x in of:
            print(f"  {x[:72]:72s} {rel(o8[dq], o8[x]):.3f} {rel(of[x], o8[x]):.3f}")

    # Control: the rewrite with one scale for all output channels.
    with tempfile.TemporaryDirectory() as tmp:
        c = run(wrong_rewrite(int8, tmp), feeds)[out]
    print(f"control, one weight scale for all channels: mean |difference| to int8 {np.abs(c - b).mean():.4f}")


def isa_dump(models, out):
    """Style vectors of the test style image from both predictors, with and without
    onnxruntime's graph optimisations."""
    feed = {"style_image": predictor_input(style_image())}
    levels = {"all": ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
              "none": ort.GraphOptimizationLevel.ORT_DISABLE_ALL}
    vecs = {}
    for variant in ("stylizer", "stylizer-int8"):
        for name, level in levels.items():
            g = os.path.join(models, variant, "arbitrary_predict.onnx")
            vecs[f"{variant}/{name}"] = run(g, feed, level=level)["mobilenet_conv/Conv/BiasAdd"].ravel()
    np.savez(out, **vecs)


def isa_compare(paths):
    dumps = [np.load(p) for p in paths]
    names = [os.path.basename(p) for p in paths]
    print("style vector | largest |difference| between dumps (" + ", ".join(names) + ") | largest |value|")
    for key in dumps[0].files:
        diffs = [f"{names[i]}-{names[j]} {np.abs(dumps[i][key] - dumps[j][key]).max():.2e}"
                 for i in range(len(dumps)) for j in range(i + 1, len(dumps))]
        print(f"  {key}: {'; '.join(diffs)} | {np.abs(dumps[0][key]).max():.3f}")
    for d, n in zip(dumps, names):
        print(f"  {n}: int8 fused vs unfused {np.abs(d['stylizer-int8/all'] - d['stylizer-int8/none']).max():.2e}, "
              f"float fused vs unfused {np.abs(d['stylizer/all'] - d['stylizer/none']).max():.2e}")


if __name__ == "__main__":
    default = os.path.join(ROOT, "vendor", "models")
    if len(sys.argv) > 1 and sys.argv[1] == "--isa-dump":
        isa_dump(sys.argv[3] if len(sys.argv) > 3 else default, sys.argv[2])
    elif len(sys.argv) > 1 and sys.argv[1] == "--isa-compare":
        isa_compare(sys.argv[2:])
    else:
        main(sys.argv[1] if len(sys.argv) > 1 else default)
