"""IP-Adapter routed by layer and by batch row (InstantStyle's blocks as one scale per
IP-Adapter attention layer and per row, so one batched UNet call carries differently
routed rows)."""


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
