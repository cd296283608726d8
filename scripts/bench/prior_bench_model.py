#!/usr/bin/env python3
"""Benchmark model for benches/prior.rs: a UNet-sized ONNX graph with the UNet contract.

usage: prior_bench_model.py OUT_DIR [LAYERS]

unet.onnx: sample [B,4,32,32] -> 3x3 conv 4->320 -> LAYERS x (3x3 conv 320->320, ReLU)
-> 3x3 conv 320->4 = out_sample. `timestep` (int64 [B]) and `encoder_hidden_states`
([B,2,9]) are declared inputs (the graph does not use them), as in a real UNet's
signature. The VAE graphs, text embeddings and image encoder are the Gaussian prior's
(scripts/setup/10_gaussian_prior.py). Weights are random (seeded), so the numbers are
meaningless but the arithmetic is that of a real convolution stack:
2*320*320*9*32*32 = 1.89 GFLOP per image per 320->320 layer.
"""
import importlib.util
import json
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

here = os.path.dirname(os.path.abspath(__file__))
spec = importlib.util.spec_from_file_location(
    "gaussian_prior", os.path.join(here, "..", "setup", "10_gaussian_prior.py"))
gp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(gp)


def conv_stack(layers, width=320, size=32, seed=0):
    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    prev, cin = "sample", 4
    for i in range(layers + 2):
        cout = 4 if i == layers + 1 else width
        w = (rng.standard_normal((cout, cin, 3, 3)) / np.sqrt(cin * 9)).astype(np.float32)
        b = np.zeros(cout, np.float32)
        inits += [numpy_helper.from_array(w, f"w{i}"), numpy_helper.from_array(b, f"b{i}")]
        out = "out_sample" if i == layers + 1 else f"h{i}"
        conv_out = out if i in (0, layers + 1) else f"c{i}"
        nodes.append(helper.make_node("Conv", [prev, f"w{i}", f"b{i}"], [conv_out],
                                      pads=[1, 1, 1, 1]))
        if conv_out != out:
            nodes.append(helper.make_node("Relu", [conv_out], [out]))
        prev, cin = out, cout
    inputs = [helper.make_tensor_value_info("sample", TensorProto.FLOAT, ["B", 4, size, size]),
              helper.make_tensor_value_info("timestep", TensorProto.INT64, ["B"]),
              helper.make_tensor_value_info("encoder_hidden_states", TensorProto.FLOAT,
                                            ["B", 2, gp.TOKEN_DIM])]
    outputs = [helper.make_tensor_value_info("out_sample", TensorProto.FLOAT,
                                             ["B", 4, size, size])]
    g = helper.make_graph(nodes, "conv_stack_unet", inputs, outputs, inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", gp.OPSET)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    return m


def main():
    out = sys.argv[1]
    layers = int(sys.argv[2]) if len(sys.argv) > 2 else 8
    tmp = gp.write_model_dir(out)
    onnx.save(conv_stack(layers), os.path.join(tmp, "unet.onnx"))
    man = gp.manifest()
    man.update(family="custom", name=f"conv-stack-{layers}")
    man["unet"].pop("image_tokens")
    man.pop("image_encoder")
    os.remove(os.path.join(tmp, "image_encoder.onnx"))
    with open(os.path.join(tmp, "model.json"), "w") as f:
        json.dump(man, f, indent=2)
    import shutil
    shutil.rmtree(out, ignore_errors=True)
    os.rename(tmp, out)
    print(f"bench model: wrote {out} ({layers} layers)")


if __name__ == "__main__":
    main()
