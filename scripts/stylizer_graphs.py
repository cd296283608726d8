#!/usr/bin/env python3
"""The stylizer's float transfer graph against the shipped int8 one (BENCHMARKS.md, "The
stylizer's transfer graph in float"): the mean |difference| of their outputs on the test
image of `float_transfer_graph_is_the_int8_network` (96x128: a checkerboard-modulated
ramp, a vertical ramp, a disc), the relative difference layer by layer (at every
activation the int8 graph quantizes: its own 8-bit rounding there, and the float graph's
value against the int8 graph's), and, as a control, a deliberately wrong rewrite (one
weight scale for all output channels instead of per-channel scales).

Needs the onnxruntime Python package, which the set-up's venv does not carry:

    python3 -m venv /tmp/ortvenv && /tmp/ortvenv/bin/pip install onnxruntime onnx numpy
    /tmp/ortvenv/bin/python scripts/stylizer_graphs.py [MODELS_DIR]   # vendor/models
"""
import importlib.util
import os
import sys
import tempfile

import numpy as np
import onnx
import onnxruntime as ort

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_image():
    y, x = np.mgrid[0:96, 0:128]
    check = np.where((x // 16 + y // 16) % 2 == 0, 0.8, 0.2)
    disc = np.where(np.hypot(x - 64, y - 48) < 30, 0.9, 0.1)
    return np.stack([0.5 * x / 127 + 0.5 * check, y / 95, disc], -1)[None].astype(np.float32)


def style_vector(models):
    s = np.load(os.path.join(ROOT, "tests/golden/csd/stylizer_style.npy")).astype(np.float32) / 255
    s256 = np.kron(s, np.ones((4, 4, 1)))[None].astype(np.float32)
    predict = ort.InferenceSession(os.path.join(models, "stylizer/arbitrary_predict.onnx"))
    return predict.run(None, {"style_image": s256})[0]


def run(model, feeds, outputs=()):
    m = model if isinstance(model, onnx.ModelProto) else onnx.load(model)
    have = {o.name for o in m.graph.output}
    for name in outputs:
        if name not in have:
            m.graph.output.append(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, None))
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(m.SerializeToString(), so)
    return dict(zip([o.name for o in sess.get_outputs()], sess.run(None, feeds)))


def main(models):
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
    spec = importlib.util.spec_from_file_location("stylizer_setup", os.path.join(ROOT, "scripts/setup/20_stylizer.py"))
    src = open(spec.origin).read()
    wrong = src.replace("scale, zp = scale.reshape(shape), zp.reshape(shape)", "scale, zp = scale[:1], zp[:1]")
    assert wrong != src, "the per-channel line of dequantize() moved: update this control"
    ns = {"__name__": "stylizer_setup_wrong"}
    exec(compile(wrong, spec.origin, "exec"), ns)
    with tempfile.TemporaryDirectory() as tmp:
        p = os.path.join(tmp, "wrong.onnx")
        onnx.save(onnx.load(int8), p)
        ns["dequantize"](p)
        c = run(p, feeds)[out]
    print(f"control, one weight scale for all channels: mean |difference| to int8 {np.abs(c - b).mean():.4f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "vendor", "models"))
