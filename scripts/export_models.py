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
import shutil
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference"))

SD15 = "stable-diffusion-v1-5/stable-diffusion-v1-5"
SDXL = "stabilityai/stable-diffusion-xl-base-1.0"
CONTROLNETS = {
    ("sd15", "depth"): "lllyasviel/control_v11f1p_sd15_depth",
    ("sd15", "edges"): "lllyasviel/control_v11p_sd15_canny",
    ("sdxl", "depth"): "diffusers/controlnet-depth-sdxl-1.0",
    ("sdxl", "edges"): "diffusers/controlnet-canny-sdxl-1.0",
}
# (repo, subfolder, weights, image encoder folder). ip-adapter_sdxl.bin was trained on
# OpenCLIP ViT-bigG/14 image embeddings (1280-d, sdxl_models/image_encoder); the _vit-h
# SDXL adapter and the SD 1.5 adapter on ViT-H/14 (1024-d, models/image_encoder).
IP_ADAPTERS = {
    ("sd15", "default"): ("h94/IP-Adapter", "models", "ip-adapter_sd15.bin",
                          "models/image_encoder"),
    ("sdxl", "default"): ("h94/IP-Adapter", "sdxl_models", "ip-adapter_sdxl.bin",
                          "sdxl_models/image_encoder"),
    ("sdxl", "vit-h"): ("h94/IP-Adapter", "sdxl_models", "ip-adapter_sdxl_vit-h.bin",
                        "models/image_encoder"),
}
# InstantStyle's blocks (diffusers `set_ip_adapter_scale` dictionaries). SDXL: style in
# up_blocks.0.attentions.1, layout in down_blocks.2.attentions.1 (InstantStyle paper,
# Sec. 3). SD 1.5 (InstantStyle's experimental SD 1.5 demo): style in up_blocks.1,
# layout in down_blocks.2 and the mid block.
ROUTING = {
    "sdxl": ({"up": {"block_0": [0.0, 1.0, 0.0]}}, {"down": {"block_2": [0.0, 1.0]}}),
    "sd15": ({"up": {"block_1": 1.0}}, {"down": {"block_2": 1.0}, "mid": 1.0}),
}
CLIP_MEAN = [0.48145466, 0.4578275, 0.40821073]
CLIP_STD = [0.26862954, 0.26130258, 0.27577711]
DEFAULT_PROMPT = "a painting in the style of the reference image"


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


# ---------------------------------------------------------------------------- models

def pipeline_class(sdxl, controlnet):
    import diffusers
    if sdxl:
        return (diffusers.StableDiffusionXLControlNetPipeline if controlnet
                else diffusers.StableDiffusionXLPipeline)
    return diffusers.StableDiffusionControlNetPipeline if controlnet \
        else diffusers.StableDiffusionPipeline


def load_real(torch, a, dtype):
    """The diffusers pipeline of --family (+ ControlNet, + IP-Adapter with the image
    encoder its weights were trained on)."""
    import diffusers
    sdxl = a.family == "sdxl"
    mid = a.model_id or (SDXL if sdxl else SD15)
    kw = {}
    if a.controlnet:
        kw["controlnet"] = diffusers.ControlNetModel.from_pretrained(
            CONTROLNETS[(a.family, a.controlnet)], torch_dtype=dtype)
    if a.vae:
        kw["vae"] = diffusers.AutoencoderKL.from_pretrained(a.vae, torch_dtype=dtype)
    if not sdxl:
        kw.update(safety_checker=None, requires_safety_checker=False)
    pipe = pipeline_class(sdxl, a.controlnet).from_pretrained(mid, torch_dtype=dtype, **kw)
    if a.ip_adapter:
        repo, sub, weights, enc = IP_ADAPTERS[(a.family, a.ip_adapter)]
        pipe.load_ip_adapter(repo, subfolder=sub, weight_name=weights,
                             image_encoder_folder=enc)
    return pipe


def tiny_tokenizer(torch, pad_token):
    """A CLIP tokenizer (the transformers class Stable Diffusion uses) over a
    CLIP-format vocabulary of a few hundred tokens learnt from a small word list."""
    from clip_bpe_ref import train_merges, vocab_from_merges
    from transformers import CLIPTokenizer
    text = ("a painting in the style of the reference image watercolour oil ink sketch "
            "of a tree house plant garden stone bridge river mountain sky cloud sunset "
            "portrait landscape impressionist cubist bright dark colourful strokes brush "
            "texture pattern light shadow blue red green yellow orange purple golden "
            "photo render scene view object surface detailed high quality the and with")
    words = text.split() * 3 + ["painting", "style", "the", "of", "a"] * 5
    merges = train_merges(words, 300)
    vocab = vocab_from_merges(merges)
    return CLIPTokenizer(vocab=vocab, merges=[tuple(m) for m in merges],
                         pad_token=pad_token, model_max_length=77), vocab, merges


def tiny_ip_adapter_state(torch, unet, image_embed_dim, g):
    """Random IP-Adapter weights in h94's file layout ({image_proj, ip_adapter}), so that
    the tiny model goes through diffusers' load_ip_adapter like the real one."""
    cross = unet.config.cross_attention_dim
    proj = {"proj.weight": torch.randn(4 * cross, image_embed_dim, generator=g) * 0.2,
            "proj.bias": torch.randn(4 * cross, generator=g) * 0.1,
            "norm.weight": 1 + 0.1 * torch.randn(cross, generator=g),
            "norm.bias": 0.1 * torch.randn(cross, generator=g)}
    ip, key = {}, 1
    for name in unet.attn_processors:
        if name.endswith("attn1.processor"):
            continue
        if name.startswith("mid_block"):
            hs = unet.config.block_out_channels[-1]
        elif name.startswith("up_blocks"):
            hs = list(reversed(unet.config.block_out_channels))[int(name.split(".")[1])]
        else:
            hs = unet.config.block_out_channels[int(name.split(".")[1])]
        # Large enough that the image branch visibly moves eps in the tests.
        ip[f"{key}.to_k_ip.weight"] = torch.randn(hs, cross, generator=g) * 2 / cross ** 0.5
        ip[f"{key}.to_v_ip.weight"] = torch.randn(hs, cross, generator=g) * 2 / cross ** 0.5
        key += 2
    return {"image_proj": proj, "ip_adapter": ip}


def load_tiny(torch, a):
    """A diffusers pipeline of --family's shape with tiny random components: the same
    classes and wiring as the real models (UNet2DConditionModel, AutoencoderKL,
    ControlNetModel.from_unet, CLIP text and vision encoders, CLIPTokenizer, IP-Adapter
    via load_ip_adapter), seconds to export and small enough to commit."""
    import diffusers
    from transformers import (CLIPImageProcessor, CLIPTextConfig, CLIPTextModel,
                              CLIPTextModelWithProjection, CLIPVisionConfig,
                              CLIPVisionModelWithProjection)
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(1)
    sdxl = a.family == "sdxl"
    full = a.random == "full"
    tok, vocab, _ = tiny_tokenizer(torch, "<|endoftext|>")
    ids = dict(bos_token_id=vocab["<|startoftext|>"], eos_token_id=vocab["<|endoftext|>"],
               pad_token_id=vocab["<|endoftext|>"])

    def text_cfg(hidden, **kw):
        return CLIPTextConfig(vocab_size=len(vocab), hidden_size=hidden,
                              intermediate_size=2 * hidden, num_hidden_layers=2,
                              num_attention_heads=2, max_position_embeddings=77, **ids, **kw)

    if sdxl:
        # Two text encoders (hidden 24 + 40 = cross-attention 64; pooled 16 from the
        # second), SDXL's block layout: (Down, CrossAttn, CrossAttn), 2 layers per block,
        # 2 transformer layers in the last down block.
        te = CLIPTextModel(text_cfg(24))
        te2 = CLIPTextModelWithProjection(text_cfg(40, projection_dim=16))
        tok2, _, _ = tiny_tokenizer(torch, "!")
        unet = diffusers.UNet2DConditionModel(
            sample_size=8, in_channels=4, out_channels=4, layers_per_block=2,
            block_out_channels=(8, 16, 16),
            down_block_types=("DownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D"),
            up_block_types=("CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "UpBlock2D"),
            transformer_layers_per_block=(1, 1, 2), cross_attention_dim=64,
            attention_head_dim=2, norm_num_groups=4, addition_embed_type="text_time",
            addition_time_embed_dim=8, projection_class_embeddings_input_dim=16 + 6 * 8)
        scaling, force_upcast = 0.13025, True
    elif full:
        # SD 1.5's sizes: CLIP ViT-L/14 text encoder (its 49,408-token embedding table;
        # the tiny tokenizer uses the first ids), the 860M-parameter UNet.
        te = CLIPTextModel(CLIPTextConfig(
            vocab_size=49408, hidden_size=768, intermediate_size=3072, num_hidden_layers=12,
            num_attention_heads=12, max_position_embeddings=77, hidden_act="quick_gelu",
            projection_dim=768, **ids))
        unet = diffusers.UNet2DConditionModel(sample_size=64, cross_attention_dim=768)
        scaling, force_upcast = 0.18215, True
    else:
        te = CLIPTextModel(text_cfg(16))
        unet = diffusers.UNet2DConditionModel(
            sample_size=8, in_channels=4, out_channels=4, layers_per_block=1,
            block_out_channels=(8, 16, 16, 16),
            down_block_types=("CrossAttnDownBlock2D",) * 3 + ("DownBlock2D",),
            up_block_types=("UpBlock2D",) + ("CrossAttnUpBlock2D",) * 3,
            cross_attention_dim=16, attention_head_dim=2, norm_num_groups=4)
        scaling, force_upcast = 0.18215, True
    vae = diffusers.AutoencoderKL(
        in_channels=3, out_channels=3, latent_channels=4,
        block_out_channels=(128, 256, 512, 512) if full else (4, 8, 8, 8),
        down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
        layers_per_block=2 if full else 1, norm_num_groups=32 if full else 4,
        scaling_factor=scaling, force_upcast=force_upcast)
    cond_ch = (16, 32, 96, 256) if full else (4, 8, 8, 16)
    controlnet = diffusers.ControlNetModel.from_unet(
        unet, conditioning_embedding_out_channels=cond_ch) if a.controlnet else None
    sched = diffusers.DDIMScheduler(beta_start=0.00085, beta_end=0.012,
                                    beta_schedule="scaled_linear", clip_sample=False,
                                    set_alpha_to_one=False)
    image_encoder = None
    if a.ip_adapter:
        # SDXL's default adapter pairs with a wider encoder than the ViT-H one (bigG:
        # 1280 vs 1024); the tiny one keeps the pairing distinct (20 vs 12).
        proj_dim = 20 if (sdxl and a.ip_adapter == "default") else 12
        image_encoder = CLIPVisionModelWithProjection(CLIPVisionConfig(
            hidden_size=16, intermediate_size=32, num_hidden_layers=2, num_attention_heads=2,
            image_size=32, patch_size=8, projection_dim=proj_dim))
    kw = dict(vae=vae, text_encoder=te, tokenizer=tok, unet=unet, scheduler=sched,
              image_encoder=image_encoder, feature_extractor=CLIPImageProcessor())
    if a.controlnet:
        kw["controlnet"] = controlnet
    if sdxl:
        kw.update(text_encoder_2=te2, tokenizer_2=tok2)
    else:
        kw.update(safety_checker=None, requires_safety_checker=False)
    pipe = pipeline_class(sdxl, a.controlnet)(**kw)
    if a.ip_adapter:
        state = tiny_ip_adapter_state(torch, unet, image_encoder.config.projection_dim, g)
        pipe.load_ip_adapter(state, subfolder="", weight_name="", image_encoder_folder=None)
    # Random init leaves several layers at zero (zero-initialised ControlNet outputs,
    # conv_out...): give every parameter a small random value so that each path of the
    # graphs is exercised by the comparisons.
    with torch.no_grad():
        for m in [unet, vae, controlnet]:
            if m is None:
                continue
            for name, p in m.named_parameters():
                if p.abs().max() == 0:
                    p.copy_(torch.randn(p.shape, generator=g) * 0.05)
    return pipe


# ---------------------------------------------------------------------- IP routing

def ip_layers(pipe):
    """Names of the UNet's IP-Adapter attention processors, in diffusers' order."""
    from diffusers.models.attention_processor import IPAdapterAttnProcessor2_0
    return [n for n, p in pipe.unet.attn_processors.items()
            if isinstance(p, IPAdapterAttnProcessor2_0)]


def scale_vector(pipe, cfg):
    """Per-layer scales that diffusers' set_ip_adapter_scale(cfg) assigns."""
    pipe.set_ip_adapter_scale(cfg)
    procs = pipe.unet.attn_processors
    return [float(procs[n].scale[0]) for n in ip_layers(pipe)]


def install_routed_ip(torch, pipe):
    """Replace diffusers' IP-Adapter processors by ones whose image scale is a tensor
    `route.scale[:, layer]` (one value per batch row), and feed already-projected tokens
    past the image projection. Returns the holder whose `.scale` the UNet wrapper sets."""
    import torch.nn.functional as F
    from diffusers.models.attention_processor import IPAdapterAttnProcessor2_0
    nn = torch.nn

    class Route:
        scale = None

    route = Route()

    class RoutedIPAttn(nn.Module):
        """Decoupled cross-attention (IP-Adapter): softmax(QK_text)V_text +
        s_b * softmax(QK_img)V_img, with s_b the row's scale for this layer."""

        def __init__(self, src, index):
            super().__init__()
            self.to_k_ip, self.to_v_ip = src.to_k_ip[0], src.to_v_ip[0]
            self.index = index

        def __call__(self, attn, hidden_states, encoder_hidden_states=None,
                     attention_mask=None, temb=None, **_):
            text, ip = encoder_hidden_states
            ip = ip[0] if isinstance(ip, (list, tuple)) else ip
            residual = hidden_states
            four_d = hidden_states.ndim == 4
            if four_d:
                b, c, h, w = hidden_states.shape
                hidden_states = hidden_states.view(b, c, h * w).transpose(1, 2)
            b = hidden_states.shape[0]
            if attn.group_norm is not None:
                hidden_states = attn.group_norm(hidden_states.transpose(1, 2)).transpose(1, 2)
            q = attn.to_q(hidden_states)
            if attn.norm_cross:
                text = attn.norm_encoder_hidden_states(text)
            heads = attn.heads

            def attend(k, v):
                d = k.shape[-1] // heads
                qh = q.view(b, -1, heads, d).transpose(1, 2)
                kh = k.view(b, -1, heads, d).transpose(1, 2)
                vh = v.view(b, -1, heads, d).transpose(1, 2)
                o = F.scaled_dot_product_attention(qh, kh, vh)
                return o.transpose(1, 2).reshape(b, -1, heads * d).to(q.dtype)

            out = attend(attn.to_k(text), attn.to_v(text))
            s = route.scale[:, self.index].to(out.dtype).view(b, 1, 1)
            out = out + s * attend(self.to_k_ip(ip), self.to_v_ip(ip))
            out = attn.to_out[1](attn.to_out[0](out))
            if four_d:
                out = out.transpose(-1, -2).reshape(b, c, h, w)
            if attn.residual_connection:
                out = out + residual
            return out / attn.rescale_output_factor

    procs = dict(pipe.unet.attn_processors)
    for i, name in enumerate(ip_layers(pipe)):
        assert isinstance(procs[name], IPAdapterAttnProcessor2_0)
        procs[name] = RoutedIPAttn(procs[name], i)
    pipe.unet.set_attn_processor(procs)

    class PassThrough(nn.Module):
        def forward(self, image_embeds):
            return image_embeds

    pipe.unet.encoder_hid_proj = PassThrough()
    return route


# ------------------------------------------------------------------------- wrappers

def build_wrappers(torch, pipe, sdxl, n_down, route, dtypes):
    """nn.Modules with the graphs' I/O. `dtypes[name]` is the dtype a component runs in;
    floating-point inputs and outputs are float32 at every graph boundary."""
    nn = torch.nn
    unet, vae, cn = pipe.unet, pipe.vae, getattr(pipe, "controlnet", None)

    def cast(x, name):
        return x.to(dtypes[name]) if x.is_floating_point() else x

    class VaeEncoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.vae = vae

        def forward(self, sample):
            return self.vae.encode(cast(sample, "vae")).latent_dist.mean.float()

    class VaeDecoder(nn.Module):
        def __init__(self):
            super().__init__()
            self.vae = vae

        def forward(self, latent_sample):
            return self.vae.decode(cast(latent_sample, "vae")).sample.float()

    class TextEncoder(nn.Module):
        """SD 1.5: the CLIP text encoder's last hidden state. SDXL: the penultimate hidden
        states of both encoders, concatenated, and the second's projected pooled output
        (what diffusers' encode_prompt computes)."""

        def __init__(self):
            super().__init__()
            self.te = pipe.text_encoder
            self.te2 = getattr(pipe, "text_encoder_2", None)

        def forward(self, input_ids, *rest):
            if not sdxl:
                return self.te(input_ids)[0].float()
            h1 = self.te(input_ids, output_hidden_states=True).hidden_states[-2]
            o2 = self.te2(rest[0], output_hidden_states=True)
            return torch.cat([h1, o2.hidden_states[-2]], dim=-1).float(), o2[0].float()

    class Unet(nn.Module):
        def __init__(self):
            super().__init__()
            self.unet = unet

        def forward(self, sample, timestep, encoder_hidden_states, *rest):
            rest = list(rest)
            added = {}
            if sdxl:
                added["text_embeds"] = cast(rest.pop(0), "unet")
                added["time_ids"] = cast(rest.pop(0), "unet")
            if route is not None:
                added["image_embeds"] = [cast(rest.pop(0), "unet")]
                route.scale = rest.pop(0)
            down = mid = None
            if cn is not None:
                down = [cast(r, "unet") for r in rest[:n_down]]
                mid = cast(rest[n_down], "unet")
            out = self.unet(cast(sample, "unet"), timestep,
                            cast(encoder_hidden_states, "unet"),
                            added_cond_kwargs=added or None,
                            down_block_additional_residuals=down,
                            mid_block_additional_residual=mid).sample
            return out.float()

    class ControlNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.cn = cn

        def forward(self, sample, timestep, encoder_hidden_states, controlnet_cond, *rest):
            added = None
            if sdxl:
                added = {"text_embeds": cast(rest[0], "controlnet"),
                         "time_ids": cast(rest[1], "controlnet")}
            down, mid = self.cn(cast(sample, "controlnet"), timestep,
                                cast(encoder_hidden_states, "controlnet"),
                                cast(controlnet_cond, "controlnet"),
                                added_cond_kwargs=added, return_dict=False)
            return tuple(d.float() for d in down) + (mid.float(),)

    class ImageEncoder(nn.Module):
        """CLIP image embedding -> IP-Adapter projection: the image tokens."""

        def __init__(self, proj):
            super().__init__()
            self.clip, self.proj = pipe.image_encoder, proj

        def forward(self, image):
            emb = self.clip(cast(image, "image_encoder")).image_embeds
            return self.proj(emb).float()

    return VaeEncoder, VaeDecoder, TextEncoder, Unet, ControlNet, ImageEncoder


# ---------------------------------------------------------------------------- export

def weight_bytes(model):
    from onnx import numpy_helper  # noqa: F401
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


# ------------------------------------------------------------------------ reference

REF_PROMPTS = [
    "a watercolour painting of a tree",
    "Bright  ORANGE sunset,\tover the river!",
    "an ink sketch of 3 stone bridges -- high-quality, detailed",
    " ".join(["a golden painting of the house"] * 14),  # longer than 77 tokens: truncated
]


def write_reference(torch, pipe, ref, sdxl, size, routing, dtypes, null_e, null_p):
    """Eager-diffusers outputs on fixed inputs, computed with the pipeline's own
    machinery (encode_prompt, prepare_ip_adapter_image_embeds, set_ip_adapter_scale,
    the ControlNet and UNet forward as the pipelines call them), before any export
    rewiring. Also the token ids of REF_PROMPTS from the independent BPE in
    scripts/reference/clip_bpe_ref.py, checked here against the transformers tokenizer."""
    from clip_bpe_ref import ClipBpe
    os.makedirs(ref, exist_ok=True)
    g = torch.Generator().manual_seed(7)
    img = torch.rand(1, 3, size, size, generator=g)
    z = torch.randn(2, 4, size // 8, size // 8, generator=g)
    ctrl = torch.rand(2, 3, size, size, generator=g)
    isz = int(pipe.image_encoder.config.image_size) if routing is not None else 224
    style = torch.rand(1, 3, isz, isz, generator=g)
    t = 321
    unet, vae = pipe.unet, pipe.vae
    cn = getattr(pipe, "controlnet", None)
    prompt = REF_PROMPTS[0]  # the run-time prompt of the tests (not pre-embedded)
    files = {}

    # Token ids: independent BPE vs the tokenizer diffusers uses.
    tokens = {"prompts": []}
    for d, tok in [("tokenizer", pipe.tokenizer), ("tokenizer_2", getattr(pipe, "tokenizer_2", None))]:
        if tok is None:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            # vocab.json + merges.txt in CLIP's format, for the independent reference.
            vocab = tok.get_vocab()
            merges = json.loads(tok.backend_tokenizer.to_str())["model"]["merges"]
            with open(os.path.join(tmp, "vocab.json"), "w") as f:
                json.dump(vocab, f)
            with open(os.path.join(tmp, "merges.txt"), "w") as f:
                f.write("#version: 0.2\n")
                for m in merges:
                    f.write((m if isinstance(m, str) else " ".join(m)) + "\n")
            bpe = ClipBpe.load(tmp, specials=tok.all_special_tokens)
        for k, p in enumerate(REF_PROMPTS):
            mine = bpe.encode(p, tok.model_max_length, tok.pad_token_id)
            theirs = tok(p, padding="max_length", truncation=True,
                         max_length=tok.model_max_length).input_ids
            if mine != theirs:
                sys.exit(f"reference: tokenizer {d} disagrees with clip_bpe_ref on {p!r}:\n"
                         f"{theirs}\n{mine}")
            if d == "tokenizer":
                tokens["prompts"].append({"text": p, "input_ids": mine})
            else:
                tokens["prompts"][k]["input_ids_2"] = mine

    mean = torch.tensor(CLIP_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(CLIP_STD).view(1, 3, 1, 1)
    with torch.no_grad():
        vd = dtypes["vae"]
        files["latents"] = vae.encode((img * 2 - 1).to(vd)).latent_dist.mean.float() \
            * vae.config.scaling_factor
        files["decoded"] = (vae.decode((z[:1] / vae.config.scaling_factor).to(vd))
                            .sample.float() + 1) / 2
        hid, pooled = encode_text(torch, pipe, sdxl, prompt)
        files["text_hidden"] = torch.from_numpy(hid)
        if pooled is not None:
            files["text_pooled"] = torch.from_numpy(pooled)
        ud = dtypes["unet"]
        image_embeds = None
        if routing is not None:
            image_embeds = pipe.prepare_ip_adapter_image_embeds(
                ((style - mean) / std).to(dtypes["image_encoder"]), None, "cpu", 1, False)
            proj = unet.encoder_hid_proj(image_embeds)[0]  # [1, 1, 4, D]
            files["style_tokens"] = proj[:, 0].float()
        conds = {"null": (null_e, null_p, 0.0), "prompt": (hid, pooled, 0.0)}
        if routing is not None:
            conds["prompt_style"] = (hid, pooled, routing["style_blocks"])
            conds["content"] = (null_e, null_p, routing["content_blocks"])
        for name, (e, p, scale_cfg) in conds.items():
            ehs = torch.from_numpy(e).repeat(2, 1, 1).to(ud)
            added = {}
            if sdxl:
                added = {"text_embeds": torch.from_numpy(p).repeat(2, 1).to(ud),
                         "time_ids": torch.tensor([[size, size, 0, 0, size, size]] * 2,
                                                  dtype=ud)}
            down = mid = None
            if cn is not None:
                down, mid = cn(z.to(ud), torch.tensor([t] * 2), ehs, ctrl.to(ud),
                               added_cond_kwargs=added or None, return_dict=False)
            if image_embeds is not None:
                pipe.set_ip_adapter_scale(scale_cfg)
                added["image_embeds"] = [image_embeds[0].repeat(2, 1, 1)]
            files[f"eps_{name}"] = unet(z.to(ud), torch.tensor([t] * 2), ehs,
                                        added_cond_kwargs=added or None,
                                        down_block_additional_residuals=down,
                                        mid_block_additional_residual=mid).sample.float()
        if routing is not None:
            pipe.set_ip_adapter_scale(1.0)
            # The point of the routing: the image enters the style and content
            # conditionings differently.
            d = (files["eps_content"] - files["eps_null"]).abs().max()
            s = (files["eps_prompt_style"] - files["eps_prompt"]).abs().max()
            print(f"reference: |eps(content) - eps(null)| max {d:.3g}, "
                  f"|eps(prompt+style) - eps(prompt)| max {s:.3g}")
    files.update(images=img, z=z, control=ctrl, style=style)  # style: raw, in [0, 1]
    for k, v in files.items():
        np.save(os.path.join(ref, f"{k}.npy"), v.float().numpy().astype(np.float32))
    meta = {"t": t, "prompt": prompt, **tokens}
    with open(os.path.join(ref, "reference.json"), "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    print(f"export: wrote reference outputs to {ref}")


if __name__ == "__main__":
    main()
