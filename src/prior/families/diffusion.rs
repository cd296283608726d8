//! The ONNX diffusion families (`sd15`, `sd21`, `sdxl`, `custom`): VAE encoder and
//! decoder, UNet, optional ControlNet, IP-Adapter image encoder and text encoder, all
//! described by the manifest ([`crate::prior::manifest`] gives the graph contract) and
//! opened as an [`OnnxPrior`].
//!
//! Validation checks the values (positive latent sizes, the VAE scaling factor against
//! the family's: 0.18215 for SD 1.x/2.x, 0.13025 for SDXL, free for `custom`), that every
//! referenced file exists, and that the graphs agree with one another (ControlNet outputs
//! with UNet residual inputs, image encoder with image-token inputs, text encoder's pooled
//! output with the UNet's `text_embeds`). The graphs' inputs and outputs are checked
//! against the manifest when their sessions are created ([`crate::prior::onnx`]).

use crate::Result;
use crate::prior::manifest::{ModelDir, TimestepRange, check_file};
use crate::prior::{OnnxPrior, Prior, PriorOptions};

/// Validate an ONNX diffusion manifest; `expect` is the family's VAE scaling factor
/// (`None`: any positive one).
pub fn validate(md: &ModelDir, expect: Option<f32>) -> Result<()> {
    validate_vae(md, expect)?;
    validate_graphs(md)?;
    validate_image(md)?;
    validate_text(md)
}

/// The diffusion families draw from the scheduler's default timestep set.
pub fn timesteps(_: &ModelDir) -> Result<Option<TimestepRange>> {
    Ok(None)
}

/// Open an [`OnnxPrior`].
pub fn open(md: ModelDir, opts: &PriorOptions) -> Result<Box<dyn Prior>> {
    Ok(Box::new(OnnxPrior::from_model_dir(md, opts)?))
}

/// The latent shape and the VAE's scaling factor (checked against `expect`, the
/// family's, when it has one).
fn validate_vae(md: &ModelDir, expect: Option<f32>) -> Result<()> {
    let m = &md.manifest;
    if m.latent_channels == 0 || m.downsample == 0 {
        return Err(md.err("latent_channels and downsample must be positive"));
    }
    if !(m.vae_scaling_factor.is_finite() && m.vae_scaling_factor > 0.0) {
        return Err(md.err(format!(
            "vae_scaling_factor is {}, must be positive (0.18215 for SD 1.x/2.x, 0.13025 \
             for SDXL)",
            m.vae_scaling_factor
        )));
    }
    if let Some(x) = expect
        && (m.vae_scaling_factor - x).abs() > 1e-6
    {
        return Err(md.err(format!(
            "vae_scaling_factor {} does not match family {} (expected {x}); use family \
             `custom` for other VAEs",
            m.vae_scaling_factor, m.family
        )));
    }
    Ok(())
}

/// The required graphs (VAE encoder and decoder, UNet) and the ControlNet's agreement with the UNet.
fn validate_graphs(md: &ModelDir) -> Result<()> {
    let m = &md.manifest;
    let required = [
        ("vae_encoder", m.vae_encoder.as_ref().map(|g| &g.file)),
        ("vae_decoder", m.vae_decoder.as_ref().map(|g| &g.file)),
        ("unet", m.unet.as_ref().map(|g| &g.file)),
    ];
    for (name, file) in required {
        let file = file.ok_or_else(|| md.err(format!("graph `{name}` is missing")))?;
        check_file(md, name, file)?;
    }
    if let Some(c) = &m.controlnet {
        check_file(md, "controlnet", &c.file)?;
        let unet = m.unet.as_ref().expect("checked");
        if unet.down_residuals.len() != c.down_outputs.len() || unet.mid_residual.is_none() {
            return Err(md.err(format!(
                "graph `controlnet` has {} down outputs and a mid output; graph `unet` \
                 names {} down_residuals and {} mid_residual",
                c.down_outputs.len(),
                unet.down_residuals.len(),
                if unet.mid_residual.is_some() {
                    "a"
                } else {
                    "no"
                }
            )));
        }
        if !(c.scale.is_finite()) {
            return Err(md.err("controlnet.scale must be finite"));
        }
    }
    Ok(())
}

/// The image encoder and the image conditioning's scales, with the UNet inputs they need.
fn validate_image(md: &ModelDir) -> Result<()> {
    let m = &md.manifest;
    if let Some(ie) = &m.image_encoder {
        check_file(md, "image_encoder", &ie.file)?;
        if ie.size == 0 || ie.std.iter().any(|s| *s <= 0.0) {
            return Err(md.err("image_encoder: size and std must be positive"));
        }
        if let Some(u) = &ie.uncond_tokens {
            check_file(md, "image_encoder.uncond_tokens", u)?;
        }
        if m.unet
            .as_ref()
            .and_then(|u| u.image_tokens.as_ref())
            .is_none()
        {
            return Err(md.err(
                "graph `image_encoder` is given but graph `unet` names no image_tokens input",
            ));
        }
    }
    let scale_input = m.unet.as_ref().and_then(|u| u.image_scale.as_ref());
    match (&m.image_conditioning, scale_input) {
        (None, None) => {}
        (Some(_), None) | (None, Some(_)) => {
            return Err(md.err(
                "`image_conditioning` and graph `unet`'s image_scale input go together: \
                 give both or neither",
            ));
        }
        (Some(ic), Some(_)) => {
            if m.image_encoder.is_none() {
                return Err(md.err("`image_conditioning` needs graph `image_encoder`"));
            }
            let k = ic.layers.len();
            if k == 0 || ic.style.len() != k || ic.content.len() != k {
                return Err(md.err(format!(
                    "image_conditioning: {k} layers, {} style and {} content scales; \
                     they must agree and be at least one",
                    ic.style.len(),
                    ic.content.len()
                )));
            }
            if ic.style.iter().chain(&ic.content).any(|x| !x.is_finite()) {
                return Err(md.err("image_conditioning: scales must be finite"));
            }
        }
    }
    Ok(())
}

/// The text encoder and the text embeddings (null and prompts, pooled where the UNet takes them).
fn validate_text(md: &ModelDir) -> Result<()> {
    let m = &md.manifest;
    if let Some(enc) = m.text.as_ref().and_then(|t| t.encoder.as_ref()) {
        check_file(md, "text.encoder", &enc.file)?;
        if enc.tokenizers.is_empty() {
            return Err(md.err("text.encoder.tokenizers is empty"));
        }
        for t in &enc.tokenizers {
            check_file(md, "text.encoder.tokenizers", &t.tokenizer)?;
            if t.max_length < 2 {
                return Err(md.err(format!(
                    "text.encoder.tokenizers: max_length {} leaves no room for the start \
                     and end marks",
                    t.max_length
                )));
            }
        }
        let unet_pooled = m.unet.as_ref().is_some_and(|u| u.text_embeds.is_some());
        if unet_pooled != enc.pooled_output.is_some() {
            return Err(md.err(format!(
                "graph `unet` {} text_embeds, graph `text_encoder` {} pooled_output",
                if unet_pooled { "takes" } else { "takes no" },
                if enc.pooled_output.is_some() {
                    "names a"
                } else {
                    "names no"
                }
            )));
        }
    }
    let text = m
        .text
        .as_ref()
        .ok_or_else(|| md.err("`text` (null and prompt embeddings) is missing"))?;
    check_file(md, "text.null", &text.null.file)?;
    if text.prompts.is_empty() {
        return Err(md.err("text.prompts is empty: export at least one prompt embedding"));
    }
    for p in &text.prompts {
        check_file(md, "text.prompts", &p.file)?;
    }
    let unet = m.unet.as_ref().expect("checked");
    let pooled_needed = unet.text_embeds.is_some();
    let all_pooled = std::iter::once(&text.null.pooled)
        .chain(text.prompts.iter().map(|p| &p.pooled))
        .all(|p| p.is_some());
    if pooled_needed && !all_pooled {
        return Err(
            md.err("graph `unet` takes text_embeds: every text embedding needs a `pooled` file")
        );
    }
    let pooled_files = std::iter::once(&text.null.pooled)
        .chain(text.prompts.iter().map(|p| &p.pooled))
        .flatten();
    for f in pooled_files {
        check_file(md, "text pooled embedding", f)?;
    }
    Ok(())
}
