"""`--tiny`'s reference/: eager-diffusers outputs on fixed inputs, which the Rust tests
compare the ONNX graphs against."""
import json
import os
import sys
import tempfile

import numpy as np

from .graphs import encode_text
from .models import CLIP_MEAN, CLIP_STD


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
