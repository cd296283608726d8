#!/usr/bin/env python3
"""Independent reference for the installed stylizer network (src/prior/stylizer.rs) on
the CSD test case of tests/golden/csd, computed on the machine that runs the tests.

Usage: stylizer_ref.py REPO_ROOT   (run by scripts/setup/22_stylizer_ref; idempotent)

The network's numbers cannot be written down once for every machine: onnxruntime picks
its kernels by the CPU's instruction set, so a recording from one CPU is a regression
check, not a reference (issue 40). Here they are computed from the installed graphs
(vendor/models/stylizer, model.json) by onnx's reference evaluator
(`onnx.reference.ReferenceEvaluator`: plain numpy, no onnxruntime), with the
preprocessing of src/prior/stylizer.rs written out in numpy:

  * style vector s(img): centre square crop, resize to the predictor's size with the
    `image` crate's triangle filter (separable, vertical then horizontal; output x at
    input (x + 0.5) in/out - 0.5, taps in [floor(c - support), ceil(c + support)) clamped
    to the image, support 1 scaled by in/out when shrinking, weights normalised; the
    horizontal pass clamps to [0, 1]), NHWC, the style-prediction graph;
  * transfer T(x, s): the image mirror-padded to at least 64 and a multiple of 8 (the
    graph is dynamic; 24x32 -> 64x64), NHWC, the transfer graph, cropped back.

The inputs are the golden case's (csd_ref.py: stylizer_style.npy, stylizer_z0_src.npy,
stylizer_z_tgt.npy, stylizer_z_src.npy) and the clean estimates x^ of csd_ref.py:

  s_style = s(style image), s_own[b] = s(z0_src[b]),
  T_ps_tgt[b] = T(x^_tgt[b], s_style), T_p_src[b] = T(x^_src[b], s_own[b]).

Everything is computed twice: in float64 (the graphs' weights, inputs and arithmetic
cast to double: the reference) and in float32 (the same evaluator on the graphs as they
are). The float32 run's distance from the float64 one is the size of float32 rounding on
this network and these inputs; any correct float32 evaluation (onnxruntime with any
kernels, any summation order) has an error of the same size, so the tests allow ten times
it (ref.json, `f32_error`). Then, from the float64 T, the expected CSD gradients and steps
of the stylizer cases, by csd_ref.py's own code.

Writes vendor/models/stylizer/ref/: s_style.npy [100], s_own.npy [2,100],
stylizer_T_ps_tgt.npy, stylizer_T_p_src.npy [2,3,24,32] (float64), the cases'
<case>_grad.npy and <case>_z1.npy, cases.json, and ref.json (version, the graphs' and
inputs' sha256, the float32 errors). Up to date when ref.json's hashes match.
"""
import hashlib
import importlib.util
import json
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper
from onnx.reference import ReferenceEvaluator

VERSION = 1
HERE = os.path.dirname(os.path.abspath(__file__))
INPUTS = ("stylizer_style.npy", "stylizer_z0.npy", "stylizer_z0_src.npy", "stylizer_eps.npy",
          "stylizer_z_src.npy", "stylizer_z_tgt.npy", "alphas_cumprod.npy")


def load_csd_ref():
    spec = importlib.util.spec_from_file_location("csd_ref", os.path.join(HERE, "csd_ref.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


CSD_REF = load_csd_ref()


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


# ---------------------------------------------------------------------------------
# Preprocessing (src/prior/stylizer.rs, src/imageio.rs), float64.


def triangle_weights(n_in, n_out):
    """[n_out, n_in] matrix of the `image` crate's triangle resampling along one axis."""
    ratio = n_in / n_out
    sratio = max(ratio, 1.0)
    support = 1.0 * sratio
    m = np.zeros((n_out, n_in))
    for o in range(n_out):
        c = (o + 0.5) * ratio
        left = min(max(int(np.floor(c - support)), 0), n_in - 1)
        right = min(max(int(np.ceil(c + support)), left + 1), n_in)
        i = np.arange(left, right)
        w = np.maximum(0.0, 1.0 - np.abs((i - (c - 0.5)) / sratio))
        m[o, left:right] = w / w.sum()
    return m


def resize(img, h, w):
    """[3, H, W] -> [3, h, w]: vertical pass, then horizontal, clamped to [0, 1]."""
    if img.shape[1:] == (h, w):
        return img.copy()
    v = np.einsum("oy,cyx->cox", triangle_weights(img.shape[1], h), img)
    return np.clip(np.einsum("ox,cyx->cyo", triangle_weights(img.shape[2], w), v), 0.0, 1.0)


# ---------------------------------------------------------------------------------
# The graphs, in float32 as installed and in float64.


def to_double(model):
    """The same graph computing in float64: float initialisers, inputs, outputs and value
    infos cast to double (Resize's roi and scales stay float, as the operator requires)."""
    m = onnx.ModelProto.FromString(model.SerializeToString())
    g = m.graph
    keep = {name for n in g.node if n.op_type == "Resize" for name in n.input[1:3]}
    for k, t in enumerate(g.initializer):
        if t.data_type == TensorProto.FLOAT and t.name not in keep:
            a = numpy_helper.to_array(t).astype(np.float64)
            g.initializer[k].CopyFrom(numpy_helper.from_array(a, t.name))
    for v in list(g.input) + list(g.output) + list(g.value_info):
        if v.type.tensor_type.elem_type == TensorProto.FLOAT:
            v.type.tensor_type.elem_type = TensorProto.DOUBLE
    if any(n.op_type == "Constant" for n in g.node):
        sys.exit("stylizer_ref: the graph has Constant nodes; to_double does not cast them")
    return m


class Net:
    def __init__(self, model_dir, dtype):
        mj = json.load(open(os.path.join(model_dir, "model.json")))["stylizer"]
        self.sp, self.tr, self.dtype = mj["style_predict"], mj["transform"], dtype
        if not mj["transform"].get("dynamic"):
            sys.exit("stylizer_ref: expects the dynamic transfer graph of the current set-up")
        for g in (self.sp, self.tr):
            m = onnx.load(os.path.join(model_dir, g["file"]))
            quant = [n.op_type for n in m.graph.node if n.op_type in ("QuantizeLinear", "DequantizeLinear")]
            if quant:
                sys.exit(f"stylizer_ref: {g['file']} still has {len(quant)} quantize/dequantize "
                         "nodes (a float graph is expected: scripts/setup/20_stylizer.py)")
            g["eval"] = ReferenceEvaluator(to_double(m) if dtype == np.float64 else m)

    def style_vector(self, img):
        """img [3, H, W] in [0, 1] -> [100]."""
        h, w = img.shape[1:]
        side = min(h, w)
        top, left = (h - side) // 2, (w - side) // 2
        x = resize(img[:, top:top + side, left:left + side], self.sp["size"], self.sp["size"])
        x = x.transpose(1, 2, 0)[None].astype(self.dtype)
        out = self.sp["eval"].run([self.sp["output"]], {self.sp["input"]: x})[0]
        return out.reshape(-1).astype(self.dtype)

    def stylize(self, img, s):
        """img [3, H, W] in [0, 1] (H, W <= 384), s [100] -> [3, H, W]."""
        _, h, w = img.shape
        ph, pw = -(-max(h, 64) // 8) * 8, -(-max(w, 64) // 8) * 8
        iy = np.array([CSD_REF.mirror(y, h) for y in range(ph)])
        ix = np.array([CSD_REF.mirror(x, w) for x in range(pw)])
        padded = img[:, iy][:, :, ix]
        feeds = {
            self.tr["content_input"]: padded.transpose(1, 2, 0)[None].astype(self.dtype),
            self.tr["style_input"]: s.reshape(1, 1, 1, -1).astype(self.dtype),
        }
        out = self.tr["eval"].run([self.tr["output"]], feeds)[0][0]
        return out[:h, :w].transpose(2, 0, 1)


def outputs(net, x, xh_t, xh_s, style):
    s_style = net.style_vector(style)
    s_own = np.stack([net.style_vector(c) for c in x["src"]])
    t_ps = np.stack([net.stylize(xh, s_style) for xh in xh_t])
    t_p = np.stack([net.stylize(xh, s) for xh, s in zip(xh_s, s_own)])
    return {"s_style": s_style, "s_own": s_own, "stylizer_T_ps_tgt": t_ps, "stylizer_T_p_src": t_p}


def main(root):
    model_dir = os.path.join(root, "vendor", "models", "stylizer")
    golden = os.path.join(root, "tests", "golden", "csd")
    out = os.path.join(model_dir, "ref")
    stamp = os.path.join(out, "ref.json")
    mj = json.load(open(os.path.join(model_dir, "model.json")))["stylizer"]
    hashes = {
        "graphs": {g: mj[g]["sha256"] for g in ("style_predict", "transform")},
        "inputs": {f: sha256(os.path.join(golden, f)) for f in INPUTS},
        "scripts": {f: sha256(os.path.join(HERE, f)) for f in ("stylizer_ref.py", "csd_ref.py")},
    }
    try:
        with open(stamp) as f:
            old = json.load(f)
        if old.get("version") == VERSION and old.get("sha256") == hashes:
            print("stylizer_ref: up to date")
            return
    except (OSError, ValueError):
        pass
    csd_ref = CSD_REF
    ab = csd_ref.alphas_cumprod()[csd_ref.STYLIZER_T]
    ld = lambda n: np.load(os.path.join(golden, n)).astype(np.float64)  # noqa: E731
    x = {"ab": ab, "z0": ld("stylizer_z0.npy"), "src": ld("stylizer_z0_src.npy"),
         "eps": ld("stylizer_eps.npy"), "z_src": ld("stylizer_z_src.npy"),
         "z_tgt": ld("stylizer_z_tgt.npy")}
    style = ld("stylizer_style.npy").transpose(2, 0, 1) / 255.0
    xh_t = np.stack([csd_ref.clean_estimate(z, ab)[0] for z in x["z_tgt"]])
    xh_s = np.stack([csd_ref.clean_estimate(z, ab)[0] for z in x["z_src"]])

    ref = outputs(Net(model_dir, np.float64), x, xh_t, xh_s, style)
    f32 = outputs(Net(model_dir, np.float32), x, xh_t.astype(np.float32), xh_s.astype(np.float32),
                  style.astype(np.float32))
    err = {k: float(np.abs(f32[k].astype(np.float64) - ref[k]).max()) for k in ref}

    os.makedirs(out, exist_ok=True)
    if os.path.exists(stamp):
        os.remove(stamp)
    for k, a in ref.items():
        np.save(os.path.join(out, f"{k}.npy"), a)
    meta = {}
    csd_ref.stylizer_cases(out, x, meta, T_ps=ref["stylizer_T_ps_tgt"], T_p=ref["stylizer_T_p_src"])
    with open(os.path.join(out, "cases.json"), "w") as f:
        json.dump(meta, f, indent=1, sort_keys=True)
        f.write("\n")
    info = {
        "version": VERSION,
        "sha256": hashes,
        "precision": "float64 (onnx.reference.ReferenceEvaluator on the graphs cast to double)",
        "f32_error": err,
        "max_abs": {k: float(np.abs(a).max()) for k, a in ref.items()},
    }
    with open(stamp + ".partial", "w") as f:
        json.dump(info, f, indent=1, sort_keys=True)
        f.write("\n")
    os.replace(stamp + ".partial", stamp)
    print(f"stylizer_ref: wrote {out}; float32 evaluation's max error: "
          + ", ".join(f"{k} {v:.2e}" for k, v in err.items()))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.getcwd())
