#!/usr/bin/env python3
"""Export a real diffusion model to a fantasystyle model directory (ONNX + model.json).

Run once, on a machine WITH internet and a Python that has torch, diffusers and
transformers (see README, "Using real diffusion models"). Nothing here runs at
fantasystyle run time.

  python scripts/export_models.py --family sd15 --out models/sd15 \
      --controlnet depth --ip-adapter --prompt "a painting in the style of the image"
  python scripts/export_models.py --family sdxl --out models/sdxl --controlnet depth \
      --ip-adapter --fp16 --prompt "..."
  python scripts/export_models.py --tiny --out /tmp/tiny   # random tiny weights, no downloads

Writes (the graph contract is documented in src/prior/manifest.rs):
  vae_encoder.onnx   sample [B,3,H,W] in [-1,1] -> latent (posterior MEAN, unscaled)
  vae_decoder.onnx   latent_sample (unscaled) -> sample in [-1,1]
  unet.onnx          sample, timestep (int64 [B]), encoder_hidden_states
                     [+ text_embeds, time_ids (SDXL)] [+ image_tokens (IP-Adapter)]
                     [+ down_res_0..N-1, mid_res (ControlNet residuals)] -> out_sample
  controlnet.onnx    sample, timestep, encoder_hidden_states, controlnet_cond [0,1]
                     [+ text_embeds, time_ids] -> down_0..N-1, mid
  image_encoder.onnx image [1,3,224,224] (CLIP-normalised) -> style_tokens, content_tokens
  null.npy, prompt_K.npy (+ *_pooled.npy for SDXL), ip_uncond.npy, model.json

fp16: weights are cast to float16 inside each graph; inputs and outputs stay float32
(Cast nodes at the boundary), as fantasystyle feeds float32.

IP-Adapter: diffusers' IP-Adapter (h94/IP-Adapter) projects one CLIP image embedding to
image tokens; the UNet graph takes the projected tokens. IP-Adapter-Instruct (style /
content / composition instructions) is not in diffusers, so here the style and content
token sets are the same projection (model.json's name says so); an Instruct export
would replace ImageEncoder.forward's second output.

--tiny also writes reference/ (eager-torch outputs on fixed inputs); the Rust test
`exported_model_matches_torch_reference` (FANTASYSTYLE_EXPORTED_MODEL=DIR) compares.
"""
import argparse
import json
import os
import sys

import numpy as np

SD15 = "stable-diffusion-v1-5/stable-diffusion-v1-5"
SDXL = "stabilityai/stable-diffusion-xl-base-1.0"
CONTROLNETS = {
    ("sd15", "depth"): "lllyasviel/control_v11f1p_sd15_depth",
    ("sd15", "edges"): "lllyasviel/control_v11p_sd15_canny",
    ("sdxl", "depth"): "diffusers/controlnet-depth-sdxl-1.0",
    ("sdxl", "edges"): "diffusers/controlnet-canny-sdxl-1.0",
}
IP_ADAPTER = {
    "sd15": ("h94/IP-Adapter", "models", "ip-adapter_sd15.bin"),
    "sdxl": ("h94/IP-Adapter", "sdxl_models", "ip-adapter_sdxl.bin"),
}
CLIP_MEAN = [0.48145466, 0.4578275, 0.40821073]
CLIP_STD = [0.26862954, 0.26130258, 0.27577711]


def parse():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--family", choices=["sd15", "sdxl"], default="sd15")
    p.add_argument("--model-id", help="override the diffusers model id")
    p.add_argument("--out", required=True)
    p.add_argument("--controlnet", choices=["depth", "edges"])
    p.add_argument("--ip-adapter", action="store_true")
    p.add_argument("--prompt", action="append", default=[],
                   help="prompt to embed (repeatable; the first is the default)")
    p.add_argument("--fp16", action="store_true")
    p.add_argument("--opset", type=int, default=17)
    p.add_argument("--tiny", action="store_true",
                   help="random tiny SD-1.5-shaped model (no downloads), to test the wiring")
    return p.parse_args()


def import_torch():
    try:
        import torch  # noqa: F401
        import diffusers  # noqa: F401
    except ImportError as e:
        sys.exit(f"export_models.py needs torch and diffusers ({e}); see README")
    import torch
    return torch


class Boundary:
    """Wraps a module so that float inputs/outputs are float32 and the body runs in `dtype`."""

    def __init__(self, torch, dtype):
        self.torch, self.dtype = torch, dtype

    def inp(self, x):
        return x.to(self.dtype) if x.is_floating_point() else x

    def out(self, x):
        return x.float()


def build_wrappers(torch, unet, vae, controlnet, image_proj, clip_vision, sdxl, bnd,
                   n_down):
    nn = torch.nn

    class VaeEncoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.vae = vae

        def forward(self, sample):
            return bnd.out(self.vae.encode(bnd.inp(sample)).latent_dist.mean)

    class VaeDecoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.vae = vae

        def forward(self, latent_sample):
            return bnd.out(self.vae.decode(bnd.inp(latent_sample)).sample)

    class Unet(nn.Module):
        def __init__(self):
            super().__init__()
            self.unet = unet

        def forward(self, sample, timestep, encoder_hidden_states, *rest):
            rest = list(rest)
            added = {}
            if sdxl:
                added["text_embeds"] = bnd.inp(rest.pop(0))
                added["time_ids"] = bnd.inp(rest.pop(0))
            if image_proj is not None:
                # Tokens are already projected: feed them past encoder_hid_proj.
                added["image_embeds"] = [bnd.inp(rest.pop(0))]
            down = mid = None
            if controlnet is not None:
                down = [bnd.inp(r) for r in rest[:n_down]]
                mid = bnd.inp(rest[n_down])
            out = self.unet(bnd.inp(sample), timestep, bnd.inp(encoder_hidden_states),
                            added_cond_kwargs=added or None,
                            down_block_additional_residuals=down,
                            mid_block_additional_residual=mid).sample
            return bnd.out(out)

    class ControlNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.cn = controlnet

        def forward(self, sample, timestep, encoder_hidden_states, controlnet_cond, *rest):
            added = None
            if sdxl:
                added = {"text_embeds": bnd.inp(rest[0]), "time_ids": bnd.inp(rest[1])}
            down, mid = self.cn(bnd.inp(sample), timestep, bnd.inp(encoder_hidden_states),
                                bnd.inp(controlnet_cond), added_cond_kwargs=added,
                                return_dict=False)
            return tuple(bnd.out(d) for d in down) + (bnd.out(mid),)

    class ImageEncoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.clip, self.proj = clip_vision, image_proj

        def forward(self, image):
            emb = self.clip(bnd.inp(image)).image_embeds
            tokens = self.proj(emb)
            if tokens.dim() == 2:
                tokens = tokens.unsqueeze(1)
            # Without IP-Adapter-Instruct, style and content tokens are the same set.
            return bnd.out(tokens), bnd.out(tokens)

    return VaeEncoder(), VaeDecoder(), Unet(), ControlNet(), ImageEncoder()


class PassThroughProj:
    """Stands in for diffusers' MultiIPAdapterImageProjection: tokens in, tokens out."""

    @staticmethod
    def install(torch, unet):
        class P(torch.nn.Module):
            def forward(self, image_embeds):
                return image_embeds

        real = unet.encoder_hid_proj
        unet.encoder_hid_proj = P()
        return real


def export(torch, module, args, names_in, names_out, dynamic, path, opset):
    torch.onnx.export(module, tuple(args), path, input_names=names_in, output_names=names_out,
                      dynamic_axes=dynamic, opset_version=opset, dynamo=False)
    print(f"export: wrote {path}")


def load_real(torch, a, dtype):
    import diffusers
    sdxl = a.family == "sdxl"
    mid = a.model_id or (SDXL if sdxl else SD15)
    Pipe = diffusers.StableDiffusionXLPipeline if sdxl else diffusers.StableDiffusionPipeline
    pipe = Pipe.from_pretrained(mid, torch_dtype=dtype)
    controlnet = None
    if a.controlnet:
        controlnet = diffusers.ControlNetModel.from_pretrained(
            CONTROLNETS[(a.family, a.controlnet)], torch_dtype=dtype)
    clip_vision = image_proj = None
    if a.ip_adapter:
        repo, sub, w = IP_ADAPTER[a.family]
        pipe.load_ip_adapter(repo, subfolder=sub, weight_name=w,
                             image_encoder_folder="models/image_encoder")
        clip_vision = pipe.image_encoder
        image_proj = pipe.unet.encoder_hid_proj.image_projection_layers[0]

    def encode(text):
        if sdxl:
            e, _, pooled, _ = pipe.encode_prompt(text, device="cpu", num_images_per_prompt=1,
                                                 do_classifier_free_guidance=False)
            return e.float().numpy(), pooled.float().numpy()
        e, _ = pipe.encode_prompt(text, "cpu", 1, False)
        return e.float().numpy(), None

    return pipe.unet, pipe.vae, controlnet, clip_vision, image_proj, encode, \
        pipe.vae.config.scaling_factor, pipe.scheduler.config


def load_tiny(torch, a):
    """Tiny random SD-1.5- or SDXL-shaped model (--family): same classes, same wiring,
    seconds to export."""
    import diffusers
    from diffusers.models.embeddings import ImageProjection
    from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection
    torch.manual_seed(0)
    sdxl = a.family == "sdxl"
    # SDXL: pooled text (32) + 6 time ids x 8 Fourier features feed the added embedding.
    xl = dict(addition_embed_type="text_time", addition_time_embed_dim=8,
              projection_class_embeddings_input_dim=32 + 6 * 8) if sdxl else {}
    unet = diffusers.UNet2DConditionModel(
        sample_size=8, in_channels=4, out_channels=4, layers_per_block=1,
        block_out_channels=(32, 64), down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=32,
        attention_head_dim=8, norm_num_groups=8, **xl)
    vae = diffusers.AutoencoderKL(
        in_channels=3, out_channels=3, latent_channels=4, block_out_channels=(8, 16, 16, 16),
        down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
        norm_num_groups=8)
    controlnet = diffusers.ControlNetModel.from_unet(unet, conditioning_channels=3) \
        if a.controlnet else None
    clip_vision = image_proj = None
    if a.ip_adapter:
        clip_vision = CLIPVisionModelWithProjection(CLIPVisionConfig(
            hidden_size=32, intermediate_size=37, num_hidden_layers=2, num_attention_heads=4,
            image_size=224, patch_size=32, projection_dim=32))
        image_proj = ImageProjection(cross_attention_dim=32, image_embed_dim=32,
                                     num_image_text_embeds=4)
        # Give the UNet IP-Adapter attention processors the diffusers way.
        from diffusers.models.attention_processor import IPAdapterAttnProcessor2_0
        from diffusers.models.embeddings import MultiIPAdapterImageProjection
        procs = {}
        for name in unet.attn_processors:
            if name.endswith("attn1.processor"):
                procs[name] = unet.attn_processors[name].__class__()
                continue
            if name.startswith("mid_block"):
                hs = unet.config.block_out_channels[-1]
            elif name.startswith("up_blocks"):
                hs = list(reversed(unet.config.block_out_channels))[int(name.split(".")[1])]
            else:
                hs = unet.config.block_out_channels[int(name.split(".")[1])]
            procs[name] = IPAdapterAttnProcessor2_0(hidden_size=hs, cross_attention_dim=32,
                                                    num_tokens=(4,), scale=1.0)
        unet.set_attn_processor(procs)
        unet.encoder_hid_proj = MultiIPAdapterImageProjection([image_proj])
        unet.config.encoder_hid_dim_type = "ip_image_proj"
    g = torch.Generator().manual_seed(1)

    def encode(text):
        seed = sum(map(ord, text)) % 1000
        g.manual_seed(seed)
        hidden = torch.randn(1, 77, 32, generator=g).numpy()
        return hidden, (torch.randn(1, 32, generator=g).numpy() if sdxl else None)

    sched = {"num_train_timesteps": 1000, "beta_start": 0.00085, "beta_end": 0.012,
             "beta_schedule": "scaled_linear", "prediction_type": "epsilon"}
    return unet, vae, controlnet, clip_vision, image_proj, encode, 0.18215, sched


def main():
    a = parse()
    torch = import_torch()
    dtype = torch.float16 if a.fp16 else torch.float32
    os.makedirs(a.out, exist_ok=True)
    sdxl = a.family == "sdxl"
    if a.tiny:
        unet, vae, cn, clip_vision, image_proj, encode, scaling, sched = load_tiny(torch, a)
    else:
        unet, vae, cn, clip_vision, image_proj, encode, scaling, sched = load_real(torch, a,
                                                                                    dtype)
    for m in (unet, vae, cn, clip_vision, image_proj):
        if m is not None:
            m.to(dtype).eval()
    bnd = Boundary(torch, dtype)
    # Down residuals: conv_in, then each resnet layer and each downsampler per block.
    n_down = 1 + sum(len(b.resnets) + (1 if b.downsamplers else 0) for b in unet.down_blocks)
    if image_proj is not None:
        real_proj = PassThroughProj.install(torch, unet)
        del real_proj
    enc_m, dec_m, unet_m, cn_m, img_m = build_wrappers(
        torch, unet, vae, cn, image_proj, clip_vision, sdxl, bnd, n_down)
    out = a.out
    size = 64 if a.tiny else (1024 if sdxl else 512)
    h = size // 8
    B = {0: "B"}

    with torch.no_grad():
        x = torch.zeros(1, 3, size, size)
        export(torch, enc_m, [x], ["sample"], ["latent"],
               {"sample": {0: "B", 2: "H", 3: "W"}, "latent": {0: "B", 2: "h", 3: "w"}},
               os.path.join(out, "vae_encoder.onnx"), a.opset)
        z = torch.zeros(1, 4, h, h)
        export(torch, dec_m, [z], ["latent_sample"], ["sample"],
               {"latent_sample": {0: "B", 2: "h", 3: "w"}, "sample": {0: "B", 2: "H", 3: "W"}},
               os.path.join(out, "vae_decoder.onnx"), a.opset)

        prompts = a.prompt or ["a painting in the style of the reference image"]
        null_e, null_p = encode("")
        np.save(os.path.join(out, "null.npy"), null_e.astype(np.float32))
        text = {"null": {"file": "null.npy"}, "prompts": []}
        if null_p is not None:
            np.save(os.path.join(out, "null_pooled.npy"), null_p.astype(np.float32))
            text["null"]["pooled"] = "null_pooled.npy"
        for k, p in enumerate(prompts):
            e, pooled = encode(p)
            np.save(os.path.join(out, f"prompt_{k}.npy"), e.astype(np.float32))
            entry = {"text": p, "file": f"prompt_{k}.npy"}
            if pooled is not None:
                np.save(os.path.join(out, f"prompt_{k}_pooled.npy"), pooled.astype(np.float32))
                entry["pooled"] = f"prompt_{k}_pooled.npy"
            text["prompts"].append(entry)

        ehs = torch.from_numpy(null_e)
        t = torch.tensor([500], dtype=torch.int64)
        unet_in, unet_names = [z, t, ehs], ["sample", "timestep", "encoder_hidden_states"]
        dyn = {"sample": {0: "B", 2: "h", 3: "w"}, "timestep": B, "encoder_hidden_states": B,
               "out_sample": {0: "B", 2: "h", 3: "w"}}
        unet_cfg = {"file": "unet.onnx", "sample": "sample", "timestep": "timestep",
                    "encoder_hidden_states": "encoder_hidden_states", "output": "out_sample"}
        extra = []
        if sdxl:
            te = torch.from_numpy(null_p)
            ti = torch.tensor([[size, size, 0, 0, size, size]], dtype=torch.float32)
            extra = [te, ti]
            unet_in += extra
            unet_names += ["text_embeds", "time_ids"]
            dyn.update(text_embeds=B, time_ids=B)
            unet_cfg.update(text_embeds="text_embeds", time_ids="time_ids")

        manifest_extra = {}
        if image_proj is not None:
            img = torch.zeros(1, 3, 224, 224)
            export(torch, img_m, [img], ["image"], ["style_tokens", "content_tokens"],
                   {"image": B, "style_tokens": B, "content_tokens": B},
                   os.path.join(out, "image_encoder.onnx"), a.opset)
            emb_dim = clip_vision.config.projection_dim
            unc = image_proj(torch.zeros(1, emb_dim, dtype=dtype)).float()
            if unc.dim() == 2:
                unc = unc.unsqueeze(1)
            np.save(os.path.join(out, "ip_uncond.npy"), unc.numpy().astype(np.float32))
            unet_in.append(unc)
            unet_names.append("image_tokens")
            dyn["image_tokens"] = B
            unet_cfg["image_tokens"] = "image_tokens"
            manifest_extra["image_encoder"] = {
                "file": "image_encoder.onnx", "input": "image", "size": 224, "mean": CLIP_MEAN,
                "std": CLIP_STD, "style_output": "style_tokens",
                "content_output": "content_tokens", "uncond_tokens": "ip_uncond.npy"}

        if cn is not None:
            ctrl = torch.zeros(1, 3, size, size)
            cn_in = [z, t, ehs, ctrl] + extra
            cn_names = ["sample", "timestep", "encoder_hidden_states", "controlnet_cond"]
            cn_names += ["text_embeds", "time_ids"] if sdxl else []
            outs = cn_m(*cn_in)
            down_names = [f"down_{i}" for i in range(len(outs) - 1)]
            cdyn = {n: B for n in cn_names + down_names + ["mid"]}
            cdyn["controlnet_cond"] = {0: "B", 2: "H", 3: "W"}
            export(torch, cn_m, cn_in, cn_names, down_names + ["mid"], cdyn,
                   os.path.join(out, "controlnet.onnx"), a.opset)
            res_names = [f"down_res_{i}" for i in range(len(down_names))]
            unet_in += list(outs)
            unet_names += res_names + ["mid_res"]
            dyn.update({n: B for n in res_names + ["mid_res"]})
            unet_cfg.update(down_residuals=res_names, mid_residual="mid_res")
            manifest_extra["controlnet"] = {
                "file": "controlnet.onnx", "sample": "sample", "timestep": "timestep",
                "encoder_hidden_states": "encoder_hidden_states", "cond": "controlnet_cond",
                "down_outputs": down_names, "mid_output": "mid", "control": a.controlnet,
                "scale": 1.0}
            if sdxl:
                manifest_extra["controlnet"].update(text_embeds="text_embeds",
                                                    time_ids="time_ids")
        export(torch, unet_m, unet_in, unet_names, ["out_sample"], dyn,
               os.path.join(out, "unet.onnx"), a.opset)

    family = "custom" if a.tiny else a.family
    manifest = {
        "format": "fantasystyle-model/1", "family": family,
        "name": ("tiny-random" if a.tiny else (a.model_id or family))
        + ("+ip-adapter(style=content tokens)" if image_proj is not None else ""),
        "latent_channels": 4, "vae_scaling_factor": float(scaling), "downsample": 8,
        "precision": "fp16" if a.fp16 else "fp32",
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
    print(f"export: wrote {os.path.join(out, 'model.json')}")
    if a.tiny:
        write_reference(torch, os.path.join(out, "reference"), enc_m, dec_m, unet_m, cn_m,
                        img_m, scaling, size, n_down, cn is not None, image_proj is not None,
                        os.path.join(out, "prompt_0.npy"), os.path.join(out, "null.npy"),
                        os.path.join(out, "ip_uncond.npy"), sdxl)


def write_reference(torch, ref, enc_m, dec_m, unet_m, cn_m, img_m, scaling, size, n_down,
                    has_cn, has_ip, prompt_file, null_file, uncond_file, sdxl):
    """Eager-torch outputs of the exported modules on fixed inputs, for the Rust test
    `exported_model_matches_torch_reference` (FANTASYSTYLE_EXPORTED_MODEL=DIR)."""
    os.makedirs(ref, exist_ok=True)
    g = torch.Generator().manual_seed(7)
    img = torch.rand(2, 3, size, size, generator=g)
    z = torch.randn(1, 4, size // 8, size // 8, generator=g)
    ctrl = torch.rand(1, 3, size, size, generator=g)
    style = torch.rand(1, 3, 224, 224, generator=g)
    t = 321
    with torch.no_grad():
        lat = enc_m(img * 2 - 1) * scaling
        dec = (dec_m(z / scaling) + 1) / 2
        mean = torch.tensor(CLIP_MEAN).view(1, 3, 1, 1)
        std = torch.tensor(CLIP_STD).view(1, 3, 1, 1)
        eps = {}
        for name, text_file, tokens in [("null", null_file, "uncond"),
                                        ("prompt_style", prompt_file, "style")]:
            ehs = torch.from_numpy(np.load(text_file))
            args = [z, torch.tensor([t]), ehs]
            extra = []
            if sdxl:
                pooled = torch.from_numpy(np.load(text_file.replace(".npy", "_pooled.npy")))
                extra = [pooled, torch.tensor([[size, size, 0, 0, size, size]],
                                              dtype=torch.float32)]
                args += extra
            if has_ip:
                tok = (img_m((style - mean) / std)[0] if tokens == "style"
                       else torch.from_numpy(np.load(uncond_file)))
                args.append(tok)
            if has_cn:
                res = cn_m(z, torch.tensor([t]), ehs, ctrl, *extra)
                args += list(res)
            eps[name] = unet_m(*args)
    for k, v in [("images", img), ("latents", lat), ("z", z), ("decoded", dec),
                 ("control", ctrl), ("style", style), ("eps_null", eps["null"]),
                 ("eps_prompt_style", eps["prompt_style"])]:
        np.save(os.path.join(ref, f"{k}.npy"), v.float().numpy().astype(np.float32))
    with open(os.path.join(ref, "t.txt"), "w") as f:
        f.write(f"{t}\n")
    print(f"export: wrote reference outputs to {ref}")


if __name__ == "__main__":
    main()
