"""ONNX export (with external data past a threshold), tokenizers and pre-embedded text."""
import os
import sys
import tempfile

import numpy as np


def weight_bytes(model):
    return sum(int(np.prod(t.dims)) * (2 if t.data_type in (10, 16) else 4)
               for t in model.graph.initializer)


def compact_names(model):
    """Short names for nodes, intermediate values and weights (graph inputs and outputs
    keep theirs): the tiny fixtures' graphs are mostly names otherwise."""
    g = model.graph
    if any(at.type in (5, 10) for n in g.node for at in n.attribute):  # GRAPH(S)
        return
    keep = {v.name for v in g.input} | {v.name for v in g.output}
    ren = {}

    def new(name):
        if not name or name in keep:
            return name
        if name not in ren:
            ren[name] = f"v{len(ren)}"
        return ren[name]

    for t in g.initializer:
        t.name = new(t.name)
    for i, n in enumerate(g.node):
        n.name = f"n{i}"
        n.doc_string = ""
        n.input[:] = [new(x) for x in n.input]
        n.output[:] = [new(x) for x in n.output]
    for v in g.value_info:
        v.name = new(v.name)


def export(torch, module, args, names_in, names_out, dynamic, path, a):
    """torch.onnx.export into a scratch directory, then save with ONNX external data
    (`NAME.onnx.data`) when the weights exceed --external-data-threshold."""
    import onnx
    d = os.path.dirname(path)
    with tempfile.TemporaryDirectory(dir=d) as tmp:
        t = os.path.join(tmp, os.path.basename(path))
        torch.onnx.export(module, tuple(args), t, input_names=names_in,
                          output_names=names_out, dynamic_axes=dynamic,
                          opset_version=a.opset, dynamo=False)
        model = onnx.load(t)  # also reads any external data the exporter wrote
        if a.random == "tiny":
            compact_names(model)
        data = os.path.basename(path) + ".data"
        if os.path.exists(os.path.join(d, data)):
            os.remove(os.path.join(d, data))
        big = weight_bytes(model) > a.external_data_threshold
        if big:
            onnx.save_model(model, path, save_as_external_data=True,
                            all_tensors_to_one_file=True, location=data, size_threshold=256)
        else:
            onnx.save_model(model, path)
    onnx.checker.check_model(path)
    print(f"export: wrote {path}" + (f" (+ external data {data})" if big else ""))
    return big


def save_tokenizer(tok, d):
    tok.save_pretrained(d)
    if not os.path.exists(os.path.join(d, "tokenizer.json")):
        sys.exit(f"export: {d}: the tokenizer was not saved as tokenizer.json "
                 "(fantasystyle reads that file)")


def encode_text(torch, pipe, sdxl, text):
    """diffusers' encode_prompt: hidden [1,77,D] and, for SDXL, pooled [1,P]."""
    with torch.no_grad():
        if sdxl:
            e, _, pooled, _ = pipe.encode_prompt(text, device="cpu", num_images_per_prompt=1,
                                                 do_classifier_free_guidance=False)
            return e.float().numpy(), pooled.float().numpy()
        e, _ = pipe.encode_prompt(text, "cpu", 1, False)
        return e.float().numpy(), None


def null_text(torch, pipe, sdxl):
    """The unconditional text: diffusers' SDXL pipelines use zeros
    (force_zeros_for_empty_prompt), SD 1.5 encodes the empty prompt."""
    if sdxl and pipe.config.get("force_zeros_for_empty_prompt", True):
        e, p = encode_text(torch, pipe, sdxl, "")
        return np.zeros_like(e), np.zeros_like(p), True
    e, p = encode_text(torch, pipe, sdxl, "")
    return e, p, False
