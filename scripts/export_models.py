#!/usr/bin/env python3
"""Export a diffusion model to a fantasystyle model directory (ONNX graphs + model.json).

Run once, on a machine WITH internet and a Python that has torch, diffusers,
transformers and onnx (see README, "Using real diffusion models"). Nothing here runs at
fantasystyle run time.

  python scripts/export_models.py --family sd15 --out models/sd15 \\
      --controlnet depth --ip-adapter --prompt "a painting in the style of the image"
  python scripts/export_models.py --family sdxl --out models/sdxl --controlnet depth \\
      --ip-adapter --fp16 --prompt "..."
  python scripts/export_models.py --tiny --family sd15 --controlnet depth --ip-adapter \\
      --out /tmp/tiny      # random tiny weights, no downloads, writes reference/ too

Writes (the graph contract is documented in src/prior/manifest.rs):
  vae_encoder.onnx   sample [B,3,H,W] in [-1,1] -> latent (posterior MEAN, unscaled)
  vae_decoder.onnx   latent_sample (unscaled) -> sample in [-1,1]
  text_encoder.onnx  input_ids int64 [B,77] (+ input_ids_2 for SDXL) -> hidden [B,77,D]
                     (+ pooled [B,P] for SDXL); tokenizer/ (+ tokenizer_2/) beside it
  unet.onnx          sample, timestep (int64 [B]), encoder_hidden_states
                     [+ text_embeds, time_ids (SDXL)] [+ image_tokens, ip_scale]
                     [+ down_res_0..N-1, mid_res (ControlNet residuals)] -> out_sample
  controlnet.onnx    sample, timestep, encoder_hidden_states, controlnet_cond [0,1]
                     [+ text_embeds, time_ids] -> down_0..N-1, mid
  image_encoder.onnx image [1,3,S,S] (CLIP-normalised; S = 224) -> tokens [1,4,D]
  null.npy, prompt_K.npy (+ *_pooled.npy for SDXL), ip_uncond.npy, model.json

Image conditioning (IP-Adapter routed by block, as InstantStyle does). The UNet takes the
projected IP-Adapter tokens and `ip_scale` [B, L]: one scale per IP-Adapter attention
layer and per batch row, so that one batched call can carry differently routed rows.
model.json's `image_conditioning` names the layers and holds the scale vectors of the
two image conditionings FantasyStyle needs: `style` (the style image's tokens only into
the style-carrying up-block attention; PromptStyle) and `content` (only into the
layout-carrying down block; Content). The vectors are read back from diffusers'
`set_ip_adapter_scale` with the block dictionaries below, so they mean exactly what they
mean in diffusers; change them with --style-blocks / --content-blocks (JSON), or edit
model.json. --ip-routing shared gives every layer scale 1 for both (plain IP-Adapter:
style == content, which csd-step refuses for the term csd).

IP-Adapter-Instruct is not exported: it is an IP-Adapter-Plus resampler conditioned on
instruction and prompt text embeddings, with its own classes and weights outside
diffusers; see README.

Precision: --fp16 casts the UNet, ControlNet, text and image encoders to float16 inside
the graphs (inputs and outputs stay float32); the VAE stays float32 when its config says
`force_upcast` (SD 1.5's and SDXL's do: SDXL's VAE overflows in fp16), unless --vae
names an fp16-safe VAE (e.g. madebyollin/sdxl-vae-fp16-fix).

Graphs whose weights exceed --external-data-threshold bytes (default 1 GiB; protobuf
caps a file at 2 GiB, and the fp32 SD 1.5 UNet is 3.4 GB) keep their weights in
`NAME.onnx.data` beside `NAME.onnx` (ONNX external data); onnxruntime reads it
from the graph's directory.

--tiny also writes reference/: eager-diffusers outputs on fixed inputs (a diffusers
pipeline built from the same random components; IP-Adapter through load_ip_adapter and
set_ip_adapter_scale; prompts through encode_prompt) and token ids from
scripts/reference/clip_bpe_ref.py. The Rust tests compare the ONNX graphs against them.
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference"))

from exporter.graphs import encode_text, export, null_text, save_tokenizer  # noqa: E402
from exporter.models import (CLIP_MEAN, CLIP_STD, DEFAULT_PROMPT, ROUTING,  # noqa: E402
                             load_real, load_tiny)
from exporter.reference import write_reference  # noqa: E402
from exporter.routing import install_routed_ip, ip_layers, scale_vector  # noqa: E402
from exporter.wrappers import build_wrappers  # noqa: E402


def parse():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--family", choices=["sd15", "sdxl"], default="sd15")
    p.add_argument("--model-id", help="override the diffusers model id")
    p.add_argument("--vae", help="diffusers id of a replacement VAE (e.g. an fp16-safe one)")
    p.add_argument("--out", required=True)
    p.add_argument("--controlnet", choices=["depth", "edges"])
    p.add_argument("--ip-adapter", nargs="?", const="default", choices=["default", "vit-h"],
                   help="add h94/IP-Adapter (SDXL: `vit-h` picks ip-adapter_sdxl_vit-h.bin)")
    p.add_argument("--ip-routing", choices=["instantstyle", "shared"], default="instantstyle")
    p.add_argument("--style-blocks", type=json.loads,
                   help="set_ip_adapter_scale dictionary of the style conditioning (JSON)")
    p.add_argument("--content-blocks", type=json.loads,
                   help="set_ip_adapter_scale dictionary of the content conditioning (JSON)")
    p.add_argument("--prompt", action="append", default=[],
                   help="prompt to pre-embed (repeatable; the first is the default)")
    p.add_argument("--fp16", action="store_true")
    p.add_argument("--opset", type=int, default=17)
    p.add_argument("--external-data-threshold", type=int, default=1 << 30,
                   help="graphs with more weight bytes than this use ONNX external data")
    p.add_argument("--random", choices=["tiny", "full"],
                   help="random weights, no downloads, + reference/: `tiny` = --family's "
                   "shape at a few hundred kB; `full` = SD 1.5's real sizes (860M-parameter "
                   "UNet, ControlNet, VAE, ViT-L text encoder; tiny image encoder), for "
                   "timings and the >2 GB path")
    p.add_argument("--tiny", action="store_const", dest="random", const="tiny",
                   help="same as --random tiny")
    a = p.parse_args()
    a.tiny = a.random is not None
    if a.random == "full" and a.family != "sd15":
        p.error("--random full is SD 1.5-sized only")
    if a.ip_adapter == "vit-h" and a.family != "sdxl":
        p.error("--ip-adapter vit-h is the SDXL adapter for the ViT-H encoder; SD 1.5's "
                "adapter already uses ViT-H")
    return a


def import_torch():
    try:
        import torch  # noqa: F401
        import diffusers  # noqa: F401
        import onnx  # noqa: F401
    except ImportError as e:
        sys.exit(f"export_models.py needs torch, diffusers and onnx ({e}); see README")
    import torch
    return torch


def main():
    a = parse()
    torch = import_torch()
    dtype = torch.float16 if a.fp16 else torch.float32
    os.makedirs(a.out, exist_ok=True)
    sdxl = a.family == "sdxl"
    pipe = load_tiny(torch, a) if a.tiny else load_real(torch, a, dtype)
    cn = getattr(pipe, "controlnet", None)
    has_ip = bool(a.ip_adapter)

    # Which dtype each component runs in.
    vae_fp32 = a.fp16 and bool(pipe.vae.config.get("force_upcast", False))
    dtypes = {k: dtype for k in ["unet", "controlnet", "text_encoder", "image_encoder"]}
    dtypes["vae"] = torch.float32 if vae_fp32 else dtype
    if vae_fp32:
        print("export: the VAE's config says force_upcast: keeping it in float32 "
              "(use --vae with an fp16-safe VAE to change that)")
    for name, m in [("unet", pipe.unet), ("vae", pipe.vae), ("controlnet", cn),
                    ("text_encoder", pipe.text_encoder),
                    ("text_encoder", getattr(pipe, "text_encoder_2", None)),
                    ("image_encoder", getattr(pipe, "image_encoder", None))]:
        if m is not None:
            m.to(dtypes[name]).eval()

    routing = None
    if has_ip:
        enc_dim = pipe.image_encoder.config.projection_dim
        proj = pipe.unet.encoder_hid_proj.image_projection_layers[0]
        want = proj.image_embeds.in_features
        if enc_dim != want:
            sys.exit(f"export: the IP-Adapter's projection expects {want}-d CLIP image "
                     f"embeddings, the image encoder gives {enc_dim}-d: wrong encoder for "
                     "these adapter weights")
        style_cfg, content_cfg = ROUTING[a.family]
        style_cfg = a.style_blocks or style_cfg
        content_cfg = a.content_blocks or content_cfg
        if a.ip_routing == "shared":
            style_cfg = content_cfg = 1.0
        routing = {"layers": [n.removesuffix(".processor") for n in ip_layers(pipe)],
                   "style": scale_vector(pipe, style_cfg),
                   "content": scale_vector(pipe, content_cfg),
                   "style_blocks": style_cfg, "content_blocks": content_cfg}
        if not any(routing["style"]) or not any(routing["content"]):
            sys.exit(f"export: the style or content blocks select no IP-Adapter layer "
                     f"({style_cfg}, {content_cfg})")

    out = a.out
    size = 64 if a.tiny else (1024 if sdxl else 512)
    h = size // 8
    prompts = a.prompt or [DEFAULT_PROMPT]
    null_e, null_p, null_zeros = null_text(torch, pipe, sdxl)
    if null_zeros:
        print("export: the unconditional text is zeros (force_zeros_for_empty_prompt)")
    if a.tiny:
        write_reference(torch, pipe, os.path.join(out, "reference"), sdxl, size, routing,
                        dtypes, null_e, null_p)

    # The transformers encoders export with their eager attention: the exporter's
    # scaled_dot_product_attention builds a float32 causal mask, which breaks fp16 graphs.
    for m in [pipe.text_encoder, getattr(pipe, "text_encoder_2", None),
              getattr(pipe, "image_encoder", None)]:
        if m is not None and hasattr(m, "set_attn_implementation"):
            m.set_attn_implementation("eager")

    # Down residuals: conv_in, then each resnet layer and each downsampler per block.
    n_down = 1 + sum(len(b.resnets) + (1 if b.downsamplers else 0)
                     for b in pipe.unet.down_blocks)
    proj = pipe.unet.encoder_hid_proj.image_projection_layers[0] if has_ip else None
    route = install_routed_ip(torch, pipe) if has_ip else None
    VaeEncoder, VaeDecoder, TextEncoder, Unet, ControlNet, ImageEncoder = build_wrappers(
        torch, pipe, sdxl, n_down, route, dtypes)
    B = {0: "B"}
    external = []

    def ex(module, args, names_in, names_out, dynamic, name):
        if export(torch, module, args, names_in, names_out, dynamic,
                  os.path.join(out, name), a):
            external.append(name)

    with torch.no_grad():
        x = torch.zeros(1, 3, size, size)
        ex(VaeEncoder(), [x], ["sample"], ["latent"],
           {"sample": {0: "B", 2: "H", 3: "W"}, "latent": {0: "B", 2: "h", 3: "w"}},
           "vae_encoder.onnx")
        z = torch.zeros(1, 4, h, h)
        ex(VaeDecoder(), [z], ["latent_sample"], ["sample"],
           {"latent_sample": {0: "B", 2: "h", 3: "w"}, "sample": {0: "B", 2: "H", 3: "W"}},
           "vae_decoder.onnx")

        # Text encoder(s) and their tokenizers.
        toks = [("tokenizer", pipe.tokenizer, "input_ids")]
        if sdxl:
            toks.append(("tokenizer_2", pipe.tokenizer_2, "input_ids_2"))
        ids = [torch.tensor([t(DEFAULT_PROMPT, padding="max_length", truncation=True,
                               max_length=t.model_max_length).input_ids]) for _, t, _ in toks]
        t_out = ["hidden_states"] + (["pooled"] if sdxl else [])
        ex(TextEncoder(), ids, [n for _, _, n in toks], t_out,
           {n: B for n in [n for _, _, n in toks] + t_out}, "text_encoder.onnx")
        tokenizer_cfg = []
        for d, t, n in toks:
            save_tokenizer(t, os.path.join(out, d))
            tokenizer_cfg.append({"input": n, "tokenizer": f"{d}/tokenizer.json",
                                  "max_length": int(t.model_max_length),
                                  "pad_id": int(t.pad_token_id)})

        np.save(os.path.join(out, "null.npy"), null_e.astype(np.float32))
        text = {"null": {"file": "null.npy"}, "prompts": []}
        if null_p is not None:
            np.save(os.path.join(out, "null_pooled.npy"), null_p.astype(np.float32))
            text["null"]["pooled"] = "null_pooled.npy"
        for k, p in enumerate(prompts):
            e, pooled = encode_text(torch, pipe, sdxl, p)
            np.save(os.path.join(out, f"prompt_{k}.npy"), e.astype(np.float32))
            entry = {"text": p, "file": f"prompt_{k}.npy"}
            if pooled is not None:
                np.save(os.path.join(out, f"prompt_{k}_pooled.npy"), pooled.astype(np.float32))
                entry["pooled"] = f"prompt_{k}_pooled.npy"
            text["prompts"].append(entry)
        text["encoder"] = {"file": "text_encoder.onnx", "tokenizers": tokenizer_cfg,
                           "hidden_output": "hidden_states"}
        if sdxl:
            text["encoder"]["pooled_output"] = "pooled"

        ehs = torch.from_numpy(null_e)
        t = torch.tensor([500], dtype=torch.int64)
        unet_in, unet_names = [z, t, ehs], ["sample", "timestep", "encoder_hidden_states"]
        dyn = {"sample": {0: "B", 2: "h", 3: "w"}, "timestep": B, "encoder_hidden_states": B,
               "out_sample": {0: "B", 2: "h", 3: "w"}}
        unet_cfg = {"file": "unet.onnx", "sample": "sample", "timestep": "timestep",
                    "encoder_hidden_states": "encoder_hidden_states", "output": "out_sample"}
        extra = []
        if sdxl:
            extra = [torch.from_numpy(null_p),
                     torch.tensor([[size, size, 0, 0, size, size]], dtype=torch.float32)]
            unet_in += extra
            unet_names += ["text_embeds", "time_ids"]
            dyn.update(text_embeds=B, time_ids=B)
            unet_cfg.update(text_embeds="text_embeds", time_ids="time_ids")

        manifest_extra = {}
        if has_ip:
            isz = int(pipe.image_encoder.config.image_size)
            img = torch.zeros(1, 3, isz, isz)
            ex(ImageEncoder(proj), [img], ["image"], ["tokens"], {"image": B, "tokens": B},
               "image_encoder.onnx")
            emb_dim = pipe.image_encoder.config.projection_dim
            unc = proj(torch.zeros(1, emb_dim, dtype=dtypes["unet"])).float()
            np.save(os.path.join(out, "ip_uncond.npy"), unc.numpy().astype(np.float32))
            unet_in += [unc, torch.zeros(1, len(routing["layers"]))]
            unet_names += ["image_tokens", "ip_scale"]
            dyn.update(image_tokens=B, ip_scale=B)
            unet_cfg.update(image_tokens="image_tokens", image_scale="ip_scale")
            manifest_extra["image_encoder"] = {
                "file": "image_encoder.onnx", "input": "image", "size": isz, "mean": CLIP_MEAN,
                "std": CLIP_STD, "style_output": "tokens", "content_output": "tokens",
                "uncond_tokens": "ip_uncond.npy"}
            manifest_extra["image_conditioning"] = {
                "scheme": "instantstyle-blocks" if a.ip_routing == "instantstyle"
                else "shared",
                "layers": routing["layers"], "style": routing["style"],
                "content": routing["content"], "style_blocks": routing["style_blocks"],
                "content_blocks": routing["content_blocks"]}

        if cn is not None:
            ctrl = torch.zeros(1, 3, size, size)
            cn_in = [z, t, ehs, ctrl] + extra
            cn_names = ["sample", "timestep", "encoder_hidden_states", "controlnet_cond"]
            cn_names += ["text_embeds", "time_ids"] if sdxl else []
            cn_m = ControlNet()
            outs = cn_m(*cn_in)
            down_names = [f"down_{i}" for i in range(len(outs) - 1)]
            cdyn = {n: B for n in cn_names + down_names + ["mid"]}
            cdyn["controlnet_cond"] = {0: "B", 2: "H", 3: "W"}
            cdyn["sample"] = {0: "B", 2: "h", 3: "w"}
            for n in down_names + ["mid"]:
                cdyn[n] = {0: "B", 2: f"{n}_h", 3: f"{n}_w"}
            ex(cn_m, cn_in, cn_names, down_names + ["mid"], cdyn, "controlnet.onnx")
            res_names = [f"down_res_{i}" for i in range(len(down_names))]
            unet_in += list(outs)
            unet_names += res_names + ["mid_res"]
            dyn.update({n: {0: "B", 2: f"{n}_h", 3: f"{n}_w"}
                        for n in res_names + ["mid_res"]})
            unet_cfg.update(down_residuals=res_names, mid_residual="mid_res")
            manifest_extra["controlnet"] = {
                "file": "controlnet.onnx", "sample": "sample", "timestep": "timestep",
                "encoder_hidden_states": "encoder_hidden_states", "cond": "controlnet_cond",
                "down_outputs": down_names, "mid_output": "mid", "control": a.controlnet,
                "scale": 1.0}
            if sdxl:
                manifest_extra["controlnet"].update(text_embeds="text_embeds",
                                                    time_ids="time_ids")
        ex(Unet(), unet_in, unet_names, ["out_sample"], dyn, "unet.onnx")

    sched = pipe.scheduler.config
    name = (f"{a.random}-random-{a.family}") if a.tiny else (a.model_id or a.family)
    manifest = {
        "format": "fantasystyle-model/1", "family": "custom" if a.tiny else a.family,
        "name": name, "latent_channels": 4,
        "vae_scaling_factor": float(pipe.vae.config.scaling_factor), "downsample": 8,
        "precision": "fp16" if a.fp16 else "fp32",
        "vae_precision": "fp32" if dtypes["vae"] == torch.float32 else "fp16",
        "scheduler": {
            "num_train_timesteps": int(sched["num_train_timesteps"]),
            "beta_start": float(sched["beta_start"]), "beta_end": float(sched["beta_end"]),
            "beta_schedule": sched["beta_schedule"],
            "prediction_type": sched.get("prediction_type", "epsilon")},
        "vae_encoder": {"file": "vae_encoder.onnx", "input": "sample", "output": "latent"},
        "vae_decoder": {"file": "vae_decoder.onnx", "input": "latent_sample",
                        "output": "sample"},
        "unet": unet_cfg, "text": text, **manifest_extra,
    }
    with open(os.path.join(out, "model.json"), "w") as f:
        json.dump(manifest, f, indent=2)
        f.write("\n")
    print(f"export: wrote {os.path.join(out, 'model.json')}"
          + (f"; external data: {', '.join(external)}" if external else ""))


if __name__ == "__main__":
    main()
