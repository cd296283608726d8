//! The ONNX diffusion prior: VAE, UNet (eps or v prediction), optional ControlNet and
//! optional IP-Adapter-style image-prompt encoder, all described by a model manifest
//! ([`super::manifest`]), run with onnxruntime through [`crate::runtime`].
//!
//! * `encode`: images in `[0,1]` -> 2x-1 -> VAE encoder -> posterior mean x scaling factor.
//! * `decode`: latents / scaling factor -> VAE decoder -> (x+1)/2.
//! * `predict_eps`: classifier-free guidance batched into one UNet call (FantasyStyle
//!   Sec. 4 (CSD) needs eps under up to four conditionings): for conditionings c_1..c_k and
//!   latents `[B,C,h,w]`, the UNet sees a batch of k*B, rows `i*B..(i+1)*B` carrying c_i.
//!   With a ControlNet, one ControlNet call on the same batch produces the residuals fed
//!   to the UNet (times `scale`). A v-prediction output is converted to eps.
//!
//! Conditioning (text from `.npy` files or, for a prompt not exported, the model's text
//! encoder ([`super::text`]); image tokens from the image encoder run once on the style
//! image at construction; with `image_conditioning`, per-layer IP-Adapter scales fed as
//! the UNet's `image_scale` row, InstantStyle's routing):
//!
//! | Cond | text | image tokens | image scales |
//! |---|---|---|---|
//! | Null | null | "no image" tokens (`uncond_tokens`, else zeros) | 0 |
//! | Prompt | prompt | "no image" tokens | 0 |
//! | PromptStyle | prompt | style tokens | `image_conditioning.style` |
//! | Content | null | content tokens | `image_conditioning.content` |
//!
//! When the style and content conditionings carry the same tokens at the same scales
//! (plain IP-Adapter), [`PriorInfo::coinciding_style_content`] says so and CSD refuses
//! the term csd ([`crate::csd::check_mode`]).
//!
//! Loading checks every graph's inputs and outputs against the manifest with
//! [`super::session::Graph::check`]: each named input exists, ranks and static dimensions
//! agree with what we feed, floating-point I/O is float32, and the graph has no input we
//! would not feed. Errors name the file, the graph and the input.

use super::manifest::{
    ControlNetGraph, ImageConditioning, ImageEncoderGraph, ModelDir, ModelManifest, SimpleGraph,
    TextConfig, UnetGraph,
};
use super::preprocess::{check_finite, check_images, fit_square};
use super::session::{Graph, Kind, f32_value, input};
use super::text::{Text, TextEncoder};
use super::{Cond, Prior, PriorInfo, PriorOptions};
use crate::runtime::SessionConfig;
use crate::scheduler::Schedule;
use crate::{Error, Result};
use fantasystyle_schemas::read_npy_f32;
use ndarray::{Array, Array1, Array2, Array3, Array4, ArrayD, ArrayView4, Axis, concatenate};
use ort::value::ValueType;
use std::ops::Range;
use std::path::Path;

mod load;

/// Image-prompt tokens `[1,N,D']` and, with `image_conditioning`, the per-layer scales
/// `[1,K]` of each conditioning.
#[derive(Debug, Clone)]
struct ImageTokens {
    uncond: Array3<f32>,
    style: Option<Array3<f32>>,
    content: Option<Array3<f32>>,
    scales: Option<Scales>,
}

/// What one conditioning feeds: text, image tokens `[1,N,D']`, image scales `[1,K]`.
struct CondParts<'a> {
    text: &'a Text,
    tokens: Option<&'a Array3<f32>>,
    scales: Option<&'a Array2<f32>>,
}

/// Every input row of one `predict_eps` call (rows = conditionings x latents), sliced
/// into UNet calls of at most `unet_batch` rows.
struct Rows {
    z: Array4<f32>,
    ehs: Array3<f32>,
    pooled: Option<Array2<f32>>,
    time_ids: Array2<f32>,
    image_tokens: Option<Array3<f32>>,
    image_scale: Option<Array2<f32>>,
    control: Option<Array4<f32>>,
}

/// Concatenate along axis 0.
fn cat<A: Clone, D: ndarray::RemoveAxis>(v: &[ndarray::ArrayView<'_, A, D>]) -> Array<A, D> {
    concatenate(Axis(0), v).expect("same shapes")
}

/// Rows of `[a..b]` of `x` along axis 0, owned.
fn rows_of<D: ndarray::RemoveAxis>(x: &Array<f32, D>, r: &Range<usize>) -> Array<f32, D> {
    x.slice_axis(Axis(0), ndarray::Slice::from(r.clone()))
        .to_owned()
}

/// Attention scores per call at which [`PriorOptions::unet_batch`] `0` stops adding rows:
/// 2^31 floats (8 GiB would be one SD 1.5 call of 16 rows at 64x64 latents).
pub const AUTO_UNET_SCORES: usize = 1 << 31;

/// Rows per UNet call when not given: as many as keep the first level's self-attention
/// scores (8 heads, SD's first level, x (h w)^2 per row) within [`AUTO_UNET_SCORES`].
pub fn auto_unet_rows(h: usize, w: usize) -> usize {
    let per_row = 8 * (h * w) * (h * w);
    (AUTO_UNET_SCORES / per_row.max(1)).max(1)
}

/// Per-layer IP-Adapter scales `[1,K]`: none (no image), style, content.
#[derive(Debug, Clone)]
struct Scales {
    none: Array2<f32>,
    style: Array2<f32>,
    content: Array2<f32>,
}

impl ImageTokens {
    /// Why the style and content conditionings carry the same image information, if
    /// they do: the same tokens (as computed from the style image, else the same encoder
    /// output) at the same per-layer scales.
    fn coinciding(&self, m: &ModelManifest) -> Option<String> {
        let ie = m.image_encoder.as_ref()?;
        let same_tokens = match (&self.style, &self.content) {
            (Some(s), Some(c)) => s == c,
            _ => ie.style_output == ie.content_output,
        };
        let same_scales = self.scales.as_ref().is_none_or(|s| s.style == s.content);
        (same_tokens && same_scales).then(|| match &m.image_conditioning {
            Some(ic) => format!(
                "its style and content conditionings are the same image tokens at the same \
                 per-layer scales (image_conditioning scheme `{}`)",
                serde_json::to_value(ic.scheme)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_string))
                    .unwrap_or_default()
            ),
            None => "its style and content conditionings are the same image tokens (plain \
                     IP-Adapter, no image_conditioning routing)"
                .to_string(),
        })
    }
}

impl Scales {
    fn new(ic: &ImageConditioning) -> Self {
        let row = |v: &[f32]| Array1::from(v.to_vec()).insert_axis(Axis(0));
        Scales {
            none: Array2::zeros((1, ic.layers.len())),
            style: row(&ic.style),
            content: row(&ic.content),
        }
    }
}

/// A diffusion prior backed by ONNX graphs.
pub struct OnnxPrior {
    info: PriorInfo,
    md: ModelDir,
    schedule: Schedule,
    scaling: f32,
    vae_batch: usize,
    unet_batch: usize,
    vae_encoder: Graph,
    vae_decoder: Graph,
    unet: Graph,
    controlnet: Option<Graph>,
    null: Text,
    prompt: Text,
    image_tokens: Option<ImageTokens>,
}

impl std::fmt::Debug for OnnxPrior {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPrior")
            .field("info", &self.info)
            .field("dir", &self.md.dir)
            .finish()
    }
}

impl OnnxPrior {
    /// Open the model in `dir` (must be an ONNX diffusion family, see
    /// [`super::families::diffusion`]).
    pub fn open(dir: &Path, opts: &PriorOptions) -> Result<Self> {
        Self::from_model_dir(ModelManifest::load(dir)?, opts)
    }

    /// Build from a loaded manifest: load and validate every session, read the text
    /// embeddings, run the image-prompt encoder on the style image.
    pub fn from_model_dir(md: ModelDir, opts: &PriorOptions) -> Result<Self> {
        let m = md.manifest.clone();
        // The diffusion contract (any VAE scaling factor): what a diffusion family's
        // manifest was validated for, refused for the others.
        if let Err(e) = super::families::diffusion::validate(&md, None) {
            let why = match e {
                Error::Input { reason, .. } => reason,
                e => e.to_string(),
            };
            return Err(md.err(format!(
                "family `{}` is not an ONNX diffusion model: {why}",
                m.family
            )));
        }
        let cfg = opts.session_config();
        let c = m.latent_channels;
        let (ve, vd, u) = (
            m.vae_encoder.as_ref().expect("validated"),
            m.vae_decoder.as_ref().expect("validated"),
            m.unet.as_ref().expect("validated"),
        );
        let text_cfg = m.text.as_ref().expect("validated");

        let (null, prompt) = Self::texts(&md, text_cfg, opts, &cfg)?;
        let (l, d) = (null.hidden.dim().1, null.hidden.dim().2);
        let (vae_encoder, vae_decoder) = Self::vae(&md, ve, vd, c, &cfg)?;

        // Image-prompt encoder.
        let image_tokens = match &m.image_encoder {
            None => None,
            Some(ie) => Some(Self::image_tokens(
                &md,
                ie,
                m.image_conditioning.as_ref(),
                &cfg,
                opts.style_image.as_ref(),
            )?),
        };

        let unet = Self::unet(&md, u, (c, l, d), &null, image_tokens.as_ref(), &cfg)?;
        let controlnet = m
            .controlnet
            .as_ref()
            .map(|cn| Self::controlnet(&md, cn, (c, l, d), &cfg))
            .transpose()?;

        let schedule = Schedule::new(m.scheduler.clone()).map_err(|e| md.err(e.to_string()))?;
        let coinciding_style_content = image_tokens.as_ref().and_then(|t| t.coinciding(&m));
        Ok(OnnxPrior {
            info: PriorInfo {
                name: m.name.clone(),
                latent_channels: c,
                downsample: m.downsample,
                scheduler: m.scheduler.clone(),
                control: m.controlnet.as_ref().map(|cn| cn.control),
                coinciding_style_content,
            },
            scaling: m.vae_scaling_factor,
            vae_batch: opts.vae_batch,
            unet_batch: opts.unet_batch,
            schedule,
            vae_encoder,
            vae_decoder,
            unet,
            controlnet,
            null,
            prompt,
            image_tokens,
            md,
        })
    }

    /// The model directory and manifest.
    pub fn model(&self) -> &ModelDir {
        &self.md
    }

    /// The noise schedule.
    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    fn check_latents(&self, z: ArrayView4<'_, f32>, what: &str) -> Result<()> {
        if z.dim().0 == 0
            || z.dim().1 != self.info.latent_channels
            || z.dim().2 == 0
            || z.dim().3 == 0
        {
            return Err(Error::param(format!(
                "{what}: expected latents [B>=1, {}, h, w], got {:?}",
                self.info.latent_channels,
                z.shape()
            )));
        }
        check_finite(z, what)
    }

    /// The UNet's input rows for `conds` on the batch `z_t`: row block i carries
    /// conds[i] (text, pooled text, image tokens and scales), with the control image when
    /// the model has a ControlNet.
    fn rows(
        &self,
        z_t: ArrayView4<'_, f32>,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Rows> {
        let (b, _, h, w) = z_t.dim();
        let k = conds.len();
        let f = self.info.downsample;
        let (ih, iw) = (h * f, w * f);

        // Batch: row block i carries conds[i].
        let mut texts = Vec::with_capacity(k);
        let mut pooled = Vec::with_capacity(k);
        let mut imgs = Vec::with_capacity(k);
        let mut scales = Vec::with_capacity(k);
        for &cd in conds {
            let CondParts {
                text,
                tokens: img,
                scales: scale,
            } = self.cond_parts(cd)?;
            texts.push(Self::repeat(&text.hidden, b));
            if let Some(p) = &text.pooled {
                pooled.push(Self::repeat(p, b));
            }
            if let Some(i) = img {
                imgs.push(Self::repeat(i, b));
            }
            if let Some(s) = scale {
                scales.push(Self::repeat(s, b));
            }
        }
        let ctrl = match &self.md.manifest.controlnet {
            None => None,
            Some(cn) => {
                let ctrl = control.ok_or_else(|| {
                    Error::param(format!(
                        "model `{}` has a ControlNet: predict_eps needs a {:?} control image",
                        self.info.name, cn.control
                    ))
                })?;
                if ctrl.dim() != (b, 3, ih, iw) {
                    return Err(Error::param(format!(
                        "control image has shape {:?}, expected [{b}, 3, {ih}, {iw}]",
                        ctrl.shape()
                    )));
                }
                check_finite(ctrl, "control image")?;
                Some(cat(&vec![ctrl; k]))
            }
        };
        Ok(Rows {
            z: cat(&vec![z_t; k]),
            ehs: cat(&texts.iter().map(|a| a.view()).collect::<Vec<_>>()),
            pooled: (!pooled.is_empty())
                .then(|| cat(&pooled.iter().map(|a| a.view()).collect::<Vec<_>>())),
            time_ids: Array2::from_shape_fn((k * b, 6), |(_, j)| [ih, iw, 0, 0, ih, iw][j] as f32),
            image_tokens: (!imgs.is_empty())
                .then(|| cat(&imgs.iter().map(|a| a.view()).collect::<Vec<_>>())),
            image_scale: (!scales.is_empty())
                .then(|| cat(&scales.iter().map(|a| a.view()).collect::<Vec<_>>())),
            control: ctrl,
        })
    }

    /// Text, image tokens and image scales of one conditioning.
    fn cond_parts(&self, cond: Cond) -> Result<CondParts<'_>> {
        let need =
            |pick: fn(&ImageTokens) -> &Option<Array3<f32>>| -> Result<Option<&Array3<f32>>> {
                match &self.image_tokens {
                    None => Err(Error::param(format!(
                        "conditioning {cond:?} needs image-prompt tokens, and model `{}` has no \
                     image_encoder",
                        self.info.name
                    ))),
                    Some(t) => pick(t).as_ref().map(Some).ok_or_else(|| {
                        Error::param(format!(
                            "conditioning {cond:?} needs the style image, and the prior was opened \
                         without one"
                        ))
                    }),
                }
            };
        let uncond = self.image_tokens.as_ref().map(|t| &t.uncond);
        let scales = self.image_tokens.as_ref().and_then(|t| t.scales.as_ref());
        let (text, tokens, scales) = match cond {
            Cond::Null => (&self.null, uncond, scales.map(|s| &s.none)),
            Cond::Prompt => (&self.prompt, uncond, scales.map(|s| &s.none)),
            Cond::PromptStyle => (&self.prompt, need(|t| &t.style)?, scales.map(|s| &s.style)),
            Cond::Content => (
                &self.null,
                need(|t| &t.content)?,
                scales.map(|s| &s.content),
            ),
        };
        Ok(CondParts {
            text,
            tokens,
            scales,
        })
    }

    /// Repeat `a` `[1, ...]` `n` times along axis 0.
    fn repeat<D: ndarray::RemoveAxis>(a: &Array<f32, D>, n: usize) -> Array<f32, D> {
        let views: Vec<_> = (0..n).map(|_| a.view()).collect();
        concatenate(Axis(0), &views).expect("same shapes")
    }

    /// One ControlNet + UNet call on rows `r` of `x`: the raw UNet output `[rows, C, h, w]`.
    fn run_rows(&mut self, x: &Rows, r: Range<usize>, t: usize) -> Result<Array4<f32>> {
        let u = self.md.manifest.unet.as_ref().expect("validated");
        let n = r.len();
        let z = rows_of(&x.z, &r);
        let ehs = rows_of(&x.ehs, &r);
        let pooled = x.pooled.as_ref().map(|p| rows_of(p, &r));
        let time_ids = rows_of(&x.time_ids, &r);
        let mut feeds = vec![
            input(&u.sample, f32_value(z.clone())?),
            input(&u.timestep, self.unet.timestep_value(&u.timestep, t, n)?),
            input(&u.encoder_hidden_states, f32_value(ehs.clone())?),
        ];
        if let (Some(name), Some(p)) = (&u.text_embeds, &pooled) {
            feeds.push(input(name, f32_value(p.clone())?));
        }
        if let Some(name) = &u.time_ids {
            feeds.push(input(name, f32_value(time_ids.clone())?));
        }
        if let (Some(name), Some(i)) = (&u.image_tokens, &x.image_tokens) {
            feeds.push(input(name, f32_value(rows_of(i, &r))?));
        }
        if let (Some(name), Some(s)) = (&u.image_scale, &x.image_scale) {
            feeds.push(input(name, f32_value(rows_of(s, &r))?));
        }
        if let (Some(cn_graph), Some(cn), Some(ctrl)) = (
            &mut self.controlnet,
            &self.md.manifest.controlnet,
            &x.control,
        ) {
            let mut cfeeds = vec![
                input(&cn.sample, f32_value(z)?),
                input(&cn.timestep, cn_graph.timestep_value(&cn.timestep, t, n)?),
                input(&cn.encoder_hidden_states, f32_value(ehs)?),
                input(&cn.cond, f32_value(rows_of(ctrl, &r))?),
            ];
            if let (Some(name), Some(p)) = (&cn.text_embeds, pooled) {
                cfeeds.push(input(name, f32_value(p)?));
            }
            if let Some(name) = &cn.time_ids {
                cfeeds.push(input(name, f32_value(time_ids)?));
            }
            let names: Vec<&str> = cn
                .down_outputs
                .iter()
                .chain([&cn.mid_output])
                .map(|s| s.as_str())
                .collect();
            let res = cn_graph.run(cfeeds, &names)?;
            let targets = u.down_residuals.iter().chain(u.mid_residual.as_ref());
            for (name, r) in targets.zip(res) {
                feeds.push(input(name, f32_value(r.mapv(|v| v * cn.scale))?));
            }
        }
        let out = self.unet.run(feeds, &[&u.output])?;
        out.into_iter()
            .next()
            .expect("one output")
            .into_dimensionality()
            .map_err(|e| self.unet.err(format_args!("output `{}`: {e}", u.output)))
    }

    fn run_vae(&mut self, encode: bool, x: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        let b = x.dim().0;
        let chunk = if self.vae_batch == 0 {
            b
        } else {
            self.vae_batch
        };
        let m = &self.md.manifest;
        let (g, io) = if encode {
            (
                &mut self.vae_encoder,
                m.vae_encoder.as_ref().expect("validated"),
            )
        } else {
            (
                &mut self.vae_decoder,
                m.vae_decoder.as_ref().expect("validated"),
            )
        };
        let mut parts = Vec::new();
        for start in (0..b).step_by(chunk.max(1)) {
            let end = (start + chunk).min(b);
            let xi = x.slice(ndarray::s![start..end, .., .., ..]).to_owned();
            let out = g.run(vec![input(&io.input, f32_value(xi)?)], &[&io.output])?;
            let o: Array4<f32> = out
                .into_iter()
                .next()
                .expect("one output")
                .into_dimensionality()
                .map_err(|e| g.err(format_args!("output `{}`: {e}", io.output)))?;
            parts.push(o);
        }
        let views: Vec<_> = parts.iter().map(|p| p.view()).collect();
        Ok(concatenate(Axis(0), &views).expect("same shapes"))
    }
}

impl Prior for OnnxPrior {
    fn info(&self) -> &PriorInfo {
        &self.info
    }

    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        let f = self.info.downsample;
        check_images(images, f, "encode")?;
        let (b, _, h, w) = images.dim();
        let c = self.info.latent_channels;
        let x = images.mapv(|v| 2.0 * v - 1.0);
        let out = self.run_vae(true, x.view())?;
        let (ob, oc, oh, ow) = out.dim();
        if ob != b || (oc != c && oc != 2 * c) || oh != h / f || ow != w / f {
            return Err(self.vae_encoder.err(format_args!(
                "output has shape {:?}, expected [{b}, {c}, {}, {}]",
                out.shape(),
                h / f,
                w / f
            )));
        }
        let s = self.scaling;
        Ok(out.slice(ndarray::s![.., ..c, .., ..]).mapv(|v| v * s))
    }

    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        self.check_latents(latents, "decode")?;
        let (b, _, h, w) = latents.dim();
        let f = self.info.downsample;
        let s = self.scaling;
        let out = self.run_vae(false, latents.mapv(|v| v / s).view())?;
        if out.dim() != (b, 3, h * f, w * f) {
            return Err(self.vae_decoder.err(format_args!(
                "output has shape {:?}, expected [{b}, 3, {}, {}]",
                out.shape(),
                h * f,
                w * f
            )));
        }
        Ok(out.mapv(|v| (v + 1.0) * 0.5))
    }

    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        self.check_latents(z_t, "predict_eps")?;
        self.schedule.alpha_bar(t)?;
        if conds.is_empty() {
            return Ok(Vec::new());
        }
        let (b, c, h, w) = z_t.dim();
        let k = conds.len();
        let rows = self.rows(z_t, conds, control)?;
        // Rows per call: the attention scores of the first UNet level grow with the
        // square of the latent pixels (SD 1.5 at 64x64 latents: 0.5 GB per row).
        let per_call = match self.unet_batch {
            0 => auto_unet_rows(h, w),
            n => n,
        };
        let mut parts = Vec::new();
        for start in (0..k * b).step_by(per_call) {
            parts.push(self.run_rows(&rows, start..(start + per_call).min(k * b), t)?);
        }
        let out = cat(&parts.iter().map(|a| a.view()).collect::<Vec<_>>());
        if out.dim() != (k * b, c, h, w) {
            let u = self.md.manifest.unet.as_ref().expect("validated");
            return Err(self.unet.err(format_args!(
                "output `{}` has shape {:?}, expected [{}, {c}, {h}, {w}]",
                u.output,
                out.shape(),
                k * b
            )));
        }
        (0..k)
            .map(|i| {
                let chunk = out
                    .slice(ndarray::s![i * b..(i + 1) * b, .., .., ..])
                    .to_owned();
                self.schedule.to_eps(z_t, chunk, t)
            })
            .collect()
    }
}
