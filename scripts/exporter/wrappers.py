"""The graphs' I/O as nn.Modules: float32 at every graph boundary, each component in its
own dtype inside."""


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
