"""The diffusers pipelines the exporter reads: the real ones (Hugging Face ids below) and
`--random`'s tiny or full-sized random ones built from the same classes and wiring."""


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
