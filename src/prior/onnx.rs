//! The ONNX diffusion prior: VAE, UNet (eps or v prediction), optional ControlNet and
//! optional IP-Adapter-style image-prompt encoder, all described by a model manifest
//! ([`super::manifest`]), run with onnxruntime through [`crate::runtime`].
//!
//! * `encode`: images in [0,1] -> 2x-1 -> VAE encoder -> posterior mean x scaling factor.
//! * `decode`: latents / scaling factor -> VAE decoder -> (x+1)/2.
//! * `predict_eps`: classifier-free guidance batched into one UNet call (FantasyStyle
//!   Sec. 3.3 needs eps under up to four conditionings): for conditionings c_1..c_k and
//!   latents `[B,C,h,w]`, the UNet sees a batch of k*B, rows `i*B..(i+1)*B` carrying c_i.
//!   With a ControlNet, one ControlNet call on the same batch produces the residuals fed
//!   to the UNet (times `scale`). A v-prediction output is converted to eps.
//!
//! Conditioning (text tokens from `.npy` files, image tokens from the image encoder run
//! once on the style image at construction):
//!
//! | Cond | text | image tokens |
//! |---|---|---|
//! | Null | null | "no image" tokens (`uncond_tokens`, else zeros) |
//! | Prompt | prompt | "no image" tokens |
//! | PromptStyle | prompt | style tokens |
//! | Content | null | content tokens |
//!
//! Loading checks every graph's inputs and outputs against the manifest with
//! [`super::session::Graph::check`]: each named input exists, ranks and static dimensions
//! agree with what we feed, floating-point I/O is float32, and the graph has no input we
//! would not feed. Errors name the file, the graph and the input.

use super::manifest::{Family, ImageEncoderGraph, ModelDir, ModelManifest};
use super::preprocess::{check_finite, check_images, fit_square};
use super::session::{Graph, Kind, f32_value, input};
use super::{Cond, Prior, PriorInfo, PriorOptions};
use crate::runtime::SessionConfig;
use crate::scheduler::Schedule;
use crate::{Error, Result};
use fantasystyle_schemas::read_npy_f32;
use ndarray::{Array, Array2, Array3, Array4, ArrayD, ArrayView4, Axis, concatenate};
use ort::value::ValueType;
use std::path::Path;

/// A text conditioning: hidden states `[1,L,D]` and an optional pooled embedding `[1,P]`.
#[derive(Debug, Clone)]
struct Text {
    hidden: Array3<f32>,
    pooled: Option<Array2<f32>>,
}

/// Image-prompt tokens `[1,N,D']`.
#[derive(Debug, Clone)]
struct ImageTokens {
    uncond: Array3<f32>,
    style: Option<Array3<f32>>,
    content: Option<Array3<f32>>,
}

/// A diffusion prior backed by ONNX graphs.
pub struct OnnxPrior {
    info: PriorInfo,
    md: ModelDir,
    schedule: Schedule,
    scaling: f32,
    vae_batch: usize,
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

fn load_npy3(md: &ModelDir, what: &str, file: &str) -> Result<Array3<f32>> {
    let a = read_npy_f32(&md.file(file))?;
    let p = md.file(file);
    if a.shape.len() != 3 || a.shape[0] != 1 {
        return Err(Error::input(
            &p,
            format!("{what}: expected shape [1, L, D], found {:?}", a.shape),
        ));
    }
    if a.data.iter().any(|x| !x.is_finite()) {
        return Err(Error::input(
            &p,
            format!("{what}: contains NaN or infinity"),
        ));
    }
    Array3::from_shape_vec((1, a.shape[1], a.shape[2]), a.data)
        .map_err(|e| Error::input(&p, e.to_string()))
}

fn load_npy2(md: &ModelDir, what: &str, file: &str) -> Result<Array2<f32>> {
    let p = md.file(file);
    let a = read_npy_f32(&p)?;
    if a.shape.len() != 2 || a.shape[0] != 1 || a.data.iter().any(|x| !x.is_finite()) {
        return Err(Error::input(
            &p,
            format!(
                "{what}: expected finite values of shape [1, P], found {:?}",
                a.shape
            ),
        ));
    }
    Array2::from_shape_vec((1, a.shape[1]), a.data).map_err(|e| Error::input(&p, e.to_string()))
}

impl OnnxPrior {
    /// Open the model in `dir` (must be an ONNX family, not `stylizer`).
    pub fn open(dir: &Path, opts: &PriorOptions) -> Result<Self> {
        Self::from_model_dir(ModelManifest::load(dir)?, opts)
    }

    /// Build from a loaded manifest: load and validate every session, read the text
    /// embeddings, run the image-prompt encoder on the style image.
    pub fn from_model_dir(md: ModelDir, opts: &PriorOptions) -> Result<Self> {
        let m = md.manifest.clone();
        if m.family == Family::Stylizer {
            return Err(md.err("family `stylizer` is not an ONNX diffusion model"));
        }
        let cfg = SessionConfig {
            threads: opts.threads,
            optimization: opts.optimization,
        };
        let c = m.latent_channels;
        let (ve, vd, u) = (
            m.vae_encoder.as_ref().expect("validated"),
            m.vae_decoder.as_ref().expect("validated"),
            m.unet.as_ref().expect("validated"),
        );
        let text_cfg = m.text.as_ref().expect("validated");

        // Text embeddings.
        let read_text = |file: &str, pooled: &Option<String>, what: &str| -> Result<Text> {
            Ok(Text {
                hidden: load_npy3(&md, what, file)?,
                pooled: pooled
                    .as_ref()
                    .map(|p| load_npy2(&md, what, p))
                    .transpose()?,
            })
        };
        let null = read_text(&text_cfg.null.file, &text_cfg.null.pooled, "text.null")?;
        let entry = match &opts.prompt {
            None => &text_cfg.prompts[0],
            Some(want) => text_cfg
                .prompts
                .iter()
                .find(|p| &p.text == want)
                .ok_or_else(|| {
                    md.err(format!(
                    "no embedding for prompt {want:?}; exported prompts: {:?} (export more with \
                     scripts/export_models.py --prompt)",
                    text_cfg.prompts.iter().map(|p| &p.text).collect::<Vec<_>>()
                ))
                })?,
        };
        let prompt = read_text(&entry.file, &entry.pooled, "text.prompts")?;
        if prompt.hidden.shape() != null.hidden.shape()
            || prompt.pooled.as_ref().map(|p| p.dim()) != null.pooled.as_ref().map(|p| p.dim())
        {
            return Err(md.err(format!(
                "prompt embedding {} has shape {:?}, the null embedding {:?}: they must agree",
                entry.file,
                prompt.hidden.shape(),
                null.hidden.shape()
            )));
        }
        let (l, d) = (null.hidden.dim().1, null.hidden.dim().2);

        // VAE.
        let vae_encoder = Graph::load(&md, "vae_encoder", &ve.file, &cfg)?;
        vae_encoder.check(false, &ve.input, Kind::F32(&[4]), &[(1, 3)])?;
        vae_encoder.check(true, &ve.output, Kind::F32(&[4]), &[])?;
        vae_encoder.check_all_fed(&[&ve.input])?;
        if let Some(ch) = vae_encoder
            .session
            .outputs()
            .iter()
            .find(|o| o.name() == ve.output)
            .and_then(|o| match o.dtype() {
                ValueType::Tensor { shape, .. } => shape.get(1).copied(),
                _ => None,
            })
            && ch >= 0
            && ch as usize != c
            && ch as usize != 2 * c
        {
            return Err(vae_encoder.err(format_args!(
                "output `{}` has {ch} channels, expected {c} (mean) or {} (mean and logvar)",
                ve.output,
                2 * c
            )));
        }
        let vae_decoder = Graph::load(&md, "vae_decoder", &vd.file, &cfg)?;
        vae_decoder.check(false, &vd.input, Kind::F32(&[4]), &[(1, c)])?;
        vae_decoder.check(true, &vd.output, Kind::F32(&[4]), &[(1, 3)])?;
        vae_decoder.check_all_fed(&[&vd.input])?;

        // Image-prompt encoder.
        let image_tokens = match &m.image_encoder {
            None => None,
            Some(ie) => Some(Self::image_tokens(
                &md,
                ie,
                &cfg,
                opts.style_image.as_ref(),
            )?),
        };

        // UNet.
        let unet = Graph::load(&md, "unet", &u.file, &cfg)?;
        let mut fed: Vec<&str> = vec![&u.sample, &u.timestep, &u.encoder_hidden_states];
        unet.check(false, &u.sample, Kind::F32(&[4]), &[(1, c)])?;
        unet.check(false, &u.timestep, Kind::Timestep, &[])?;
        unet.check(
            false,
            &u.encoder_hidden_states,
            Kind::F32(&[3]),
            &[(1, l), (2, d)],
        )?;
        unet.check(true, &u.output, Kind::F32(&[4]), &[(1, c)])?;
        if let Some(te) = &u.text_embeds {
            let p = null.pooled.as_ref().expect("validated").dim().1;
            unet.check(false, te, Kind::F32(&[2]), &[(1, p)])?;
            fed.push(te);
        }
        if let Some(ti) = &u.time_ids {
            unet.check(false, ti, Kind::F32(&[2]), &[(1, 6)])?;
            fed.push(ti);
        }
        match (&u.image_tokens, &image_tokens) {
            (Some(it), Some(tok)) => {
                let (_, n, dd) = tok.uncond.dim();
                unet.check(false, it, Kind::F32(&[3]), &[(1, n), (2, dd)])?;
                fed.push(it);
            }
            (Some(it), None) => {
                return Err(unet.err(format_args!(
                    "input `{it}` (image tokens) needs an image_encoder graph in the manifest"
                )));
            }
            _ => {}
        }
        for r in &u.down_residuals {
            unet.check(false, r, Kind::F32(&[4]), &[])?;
            fed.push(r);
        }
        if let Some(r) = &u.mid_residual {
            unet.check(false, r, Kind::F32(&[4]), &[])?;
            fed.push(r);
        }
        unet.check_all_fed(&fed)?;

        // ControlNet.
        let controlnet = match &m.controlnet {
            None => None,
            Some(cn) => {
                let g = Graph::load(&md, "controlnet", &cn.file, &cfg)?;
                let mut fed: Vec<&str> = vec![
                    &cn.sample,
                    &cn.timestep,
                    &cn.encoder_hidden_states,
                    &cn.cond,
                ];
                g.check(false, &cn.sample, Kind::F32(&[4]), &[(1, c)])?;
                g.check(false, &cn.timestep, Kind::Timestep, &[])?;
                g.check(
                    false,
                    &cn.encoder_hidden_states,
                    Kind::F32(&[3]),
                    &[(1, l), (2, d)],
                )?;
                g.check(false, &cn.cond, Kind::F32(&[4]), &[(1, 3)])?;
                if let Some(te) = &cn.text_embeds {
                    g.check(false, te, Kind::F32(&[2]), &[])?;
                    fed.push(te);
                }
                if let Some(ti) = &cn.time_ids {
                    g.check(false, ti, Kind::F32(&[2]), &[(1, 6)])?;
                    fed.push(ti);
                }
                for o in cn.down_outputs.iter().chain([&cn.mid_output]) {
                    g.check(true, o, Kind::F32(&[4]), &[])?;
                }
                g.check_all_fed(&fed)?;
                Some(g)
            }
        };

        let schedule = Schedule::new(m.scheduler.clone()).map_err(|e| md.err(e.to_string()))?;
        Ok(OnnxPrior {
            info: PriorInfo {
                name: m.name.clone(),
                latent_channels: c,
                downsample: m.downsample,
                scheduler: m.scheduler.clone(),
                control: m.controlnet.as_ref().map(|cn| cn.control),
            },
            scaling: m.vae_scaling_factor,
            vae_batch: opts.vae_batch,
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

    /// Run the image encoder on the style image: (uncond, style, content) tokens.
    fn image_tokens(
        md: &ModelDir,
        ie: &ImageEncoderGraph,
        cfg: &SessionConfig,
        style: Option<&Array4<f32>>,
    ) -> Result<ImageTokens> {
        let mut g = Graph::load(md, "image_encoder", &ie.file, cfg)?;
        g.check(
            false,
            &ie.input,
            Kind::F32(&[4]),
            &[(1, 3), (2, ie.size), (3, ie.size)],
        )?;
        g.check(true, &ie.style_output, Kind::F32(&[3]), &[])?;
        g.check(true, &ie.content_output, Kind::F32(&[3]), &[])?;
        g.check_all_fed(&[&ie.input])?;
        let (style_t, content_t) = match style {
            None => (None, None),
            Some(img) => {
                if img.dim().0 != 1 {
                    return Err(Error::param(format!(
                        "style image: expected [1, 3, H, W], got {:?}",
                        img.shape()
                    )));
                }
                check_images(img.view(), 1, "style image")?;
                let mut x = fit_square(img.view(), ie.size);
                for (k, mut ch) in x.axis_iter_mut(Axis(1)).enumerate() {
                    ch.mapv_inplace(|v| (v - ie.mean[k]) / ie.std[k]);
                }
                let out = g.run(
                    vec![input(&ie.input, f32_value(x)?)],
                    &[&ie.style_output, &ie.content_output],
                )?;
                let to3 = |a: &ArrayD<f32>, o: &str| -> Result<Array3<f32>> {
                    a.clone()
                        .into_dimensionality()
                        .ok()
                        .filter(|a: &Array3<f32>| a.dim().0 == 1)
                        .ok_or_else(|| {
                            g.err(format_args!(
                                "output `{o}` has shape {:?}, expected [1, N, D]",
                                a.shape()
                            ))
                        })
                };
                (
                    Some(to3(&out[0], &ie.style_output)?),
                    Some(to3(&out[1], &ie.content_output)?),
                )
            }
        };
        let uncond = match (&ie.uncond_tokens, &style_t) {
            (Some(f), _) => load_npy3(md, "image_encoder.uncond_tokens", f)?,
            (None, Some(s)) => Array3::zeros(s.dim()),
            (None, None) => {
                // No style image: zeros shaped like the encoder's static output, else one token.
                let shape = g
                    .session
                    .outputs()
                    .iter()
                    .find(|o| o.name() == ie.style_output)
                    .and_then(|o| match o.dtype() {
                        ValueType::Tensor { shape, .. } => Some(shape.to_vec()),
                        _ => None,
                    })
                    .unwrap_or_default();
                let n = shape.get(1).copied().filter(|&d| d > 0).unwrap_or(1) as usize;
                let d = shape.get(2).copied().filter(|&d| d > 0).ok_or_else(|| {
                    g.err("the token width is dynamic: give a style image or uncond_tokens")
                })? as usize;
                Array3::zeros((1, n, d))
            }
        };
        for (what, t) in [("style", &style_t), ("content", &content_t)] {
            if let Some(t) = t
                && t.dim() != uncond.dim()
            {
                return Err(g.err(format_args!(
                    "{what} tokens have shape {:?}, the no-image tokens {:?}: they must agree",
                    t.shape(),
                    uncond.shape()
                )));
            }
        }
        Ok(ImageTokens {
            uncond,
            style: style_t,
            content: content_t,
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

    /// Text and image tokens of one conditioning.
    fn cond_parts(&self, cond: Cond) -> Result<(&Text, Option<&Array3<f32>>)> {
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
        Ok(match cond {
            Cond::Null => (&self.null, uncond),
            Cond::Prompt => (&self.prompt, uncond),
            Cond::PromptStyle => (&self.prompt, need(|t| &t.style)?),
            Cond::Content => (&self.null, need(|t| &t.content)?),
        })
    }

    /// Repeat `a` `[1, ...]` `n` times along axis 0.
    fn repeat<D: ndarray::RemoveAxis>(a: &Array<f32, D>, n: usize) -> Array<f32, D> {
        let views: Vec<_> = (0..n).map(|_| a.view()).collect();
        concatenate(Axis(0), &views).expect("same shapes")
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
        let f = self.info.downsample;
        let (ih, iw) = (h * f, w * f);
        let u = self.md.manifest.unet.clone().expect("validated");

        // Batch: row block i carries conds[i].
        let mut texts = Vec::with_capacity(k);
        let mut pooled = Vec::with_capacity(k);
        let mut imgs = Vec::with_capacity(k);
        for &cd in conds {
            let (text, img) = self.cond_parts(cd)?;
            texts.push(Self::repeat(&text.hidden, b));
            if let Some(p) = &text.pooled {
                pooled.push(Self::repeat(p, b));
            }
            if let Some(i) = img {
                imgs.push(Self::repeat(i, b));
            }
        }
        let cat3 = |v: &[Array3<f32>]| -> Array3<f32> {
            let views: Vec<_> = v.iter().map(|a| a.view()).collect();
            concatenate(Axis(0), &views).expect("same shapes")
        };
        let ehs = cat3(&texts);
        let pooled = (!pooled.is_empty()).then(|| {
            let views: Vec<_> = pooled.iter().map(|a| a.view()).collect();
            concatenate(Axis(0), &views).expect("same shapes")
        });
        let zb = {
            let views: Vec<_> = (0..k).map(|_| z_t).collect();
            concatenate(Axis(0), &views).expect("same shapes")
        };
        let time_ids = Array2::from_shape_fn((k * b, 6), |(_, j)| [ih, iw, 0, 0, ih, iw][j] as f32);

        let mut feeds = vec![
            input(&u.sample, f32_value(zb.clone())?),
            input(
                &u.timestep,
                self.unet.timestep_value(&u.timestep, t, k * b)?,
            ),
            input(&u.encoder_hidden_states, f32_value(ehs.clone())?),
        ];
        if let (Some(name), Some(p)) = (&u.text_embeds, &pooled) {
            feeds.push(input(name, f32_value(p.clone())?));
        }
        if let Some(name) = &u.time_ids {
            feeds.push(input(name, f32_value(time_ids.clone())?));
        }
        if let Some(name) = &u.image_tokens {
            feeds.push(input(name, f32_value(cat3(&imgs))?));
        }

        if let (Some(cn_graph), Some(cn)) = (&mut self.controlnet, &self.md.manifest.controlnet) {
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
            let views: Vec<_> = (0..k).map(|_| ctrl).collect();
            let ctrl_b = concatenate(Axis(0), &views).expect("same shapes");
            let mut cfeeds = vec![
                input(&cn.sample, f32_value(zb)?),
                input(
                    &cn.timestep,
                    cn_graph.timestep_value(&cn.timestep, t, k * b)?,
                ),
                input(&cn.encoder_hidden_states, f32_value(ehs)?),
                input(&cn.cond, f32_value(ctrl_b)?),
            ];
            if let (Some(name), Some(p)) = (&cn.text_embeds, &pooled) {
                cfeeds.push(input(name, f32_value(p.clone())?));
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
        let out: Array4<f32> = out
            .into_iter()
            .next()
            .expect("one output")
            .into_dimensionality()
            .map_err(|e| self.unet.err(format_args!("output `{}`: {e}", u.output)))?;
        if out.dim() != (k * b, c, h, w) {
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
