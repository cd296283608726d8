//! The weight-free patch prior: a diffusion model of the style image's patches whose
//! denoiser is exact and closed-form ([`denoise`]; Kamb & Ganguli, ICML 2025), so that the
//! paper's distillation (FantasyStyle Sec. 4, MVFC then CSD) runs with a real diffusion
//! model on a CPU and with no pretrained weights. Score distillation with it is an
//! annealed form of texture optimization (Kwatra et al., SIGGRAPH 2005): it draws the
//! style's motifs, not its layout.
//!
//! **Latent space** ([`latent`]): pixels at 1/f of the render's resolution, in `[-1, 1]`
//! (f = the manifest's `downsample`; the default prior, `priors/patch`, works at f = 1:
//! at f = 2 the strokes came out blurred, docs/patch-prior.md). The schedule is the
//! manifest's (SD's scaled-linear betas).
//!
//! **Patch size per timestep**: k(t) grows with the noise, from `patch_min` at the set's
//! smallest timestep to `patch_max` at its largest (linear in sqrt(1 - ab), odd sizes),
//! as the trained UNets' effective receptive field does in the ELS calibration.
//! **Coarse to fine**: from `coarse_from` up, the style model matches `patch_max`
//! patches of the latents and the style pooled `coarse_scale` times (4 x 9 = 36 render
//! pixels on the default), so the large timesteps place the style's motifs at their
//! scale and the small ones draw their strokes (Kwatra et al. 2005; GPNN).
//!
//! **Balanced use** ([`denoise::Search::balance`]): the style model's posterior over
//! its patches is replaced by an entropic optimal-transport coupling between the
//! window's noisy patches and the style's (Sinkhorn over k-means cells of the bank),
//! so that every part of the style is used about equally over the object (bidirectional
//! similarity, Simakov et al. 2008; Houdard et al. 2021). Without it the flat patches
//! win everywhere and the object goes to one colour.
//!
//! **Object only**: the prior's control image is the source view with its coverage
//! (`ControlKind::SourceAlpha`); only the object's latent pixels are queried (the
//! background keeps z_t's own estimate), so the fill around the object takes none of
//! the style's patches.
//!
//! **The conditionings** (the paper's CSD, eq. 7-9: Phi_tgt = beta (eps(z_tgt, [P, style]) -
//! eps(z_tgt, content)), Phi_src = beta (eps(z_src, P) - eps(z_src, null))), each a
//! different model of the same form:
//!
//! | Cond | the model | its patches |
//! |---|---|---|
//! | PromptStyle `[P, style]` | the style's texture | the style image's k(t) patches, balanced, optionally with the structure guide |
//! | Content | the style image's content | `content: identity` (the default): the exact unconditional model, so negative guidance is zero; `layout`: a per-pixel mixture of that and the style image's layout (its patches at 1/`content_scale`, weighed by responsibility against a PPCA model of generic patches), so negative guidance pushes away from copying the style image's large structures |
//! | Prompt `P` | the scene's own look | each source view's own k(t) patches within `source_radius` of the pixel (a local model of that view, [`denoise::denoise_local`]) |
//! | Null | no condition | `null: identity` (the default): the exact unconditional model, whose prediction CSD takes as the noise itself (as for the 2D stylizer); `gaussian`: the moment-matched pixel Gaussian ([`latent::PixelGaussian`]), which diverged: its shrinkage towards the mean turned into a push away from the source |
//!
//! With the defaults CSD's gradient is beta (eps([P, style], z_tgt) - eps(P, z_src)): the
//! style's patch model on the current render minus the scene's own patch model on the
//! source render, with the same noise; the source branch cancels what the style term
//! would ask of a scene that already looks like itself. eps(z_t, c) = (z_t - sqrt(ab)
//! x0_c) / sqrt(1 - ab). Beta only scales that difference (no unguided term), so CSD is
//! insensitive to it up to the step size (docs/patch-prior.md, CFG).
//!
//! **Structure** (the ControlNet's role): with `guide_weight` > 0 the style model compares
//! a noise-free structure channel of the source view (band-passed luminance) with the
//! same channel of the style ([`denoise::Guide`]), so an edge of the scene picks style
//! patches with an edge.
//!
//! **Strength** s: the style model's clean estimate is s times the style's plus 1 - s
//! times the source views' patch model's.

pub mod bank;
mod clean;
pub mod denoise;
pub mod latent;

use super::manifest::ModelDir;
use super::{Cond, ControlKind, Prior, PriorInfo, PriorOptions};
use crate::scheduler::Schedule;
use crate::{Error, Result};
use bank::{Bank, Pca, patches, patches_at};
use denoise::{Guide, Level, Search};
use latent::PixelGaussian;
use ndarray::{Array2, Array3, Array4, ArrayView3, ArrayView4, Axis};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

use clean::Window;

/// The `patch` section of a patch prior's `model.json` (its latent downsampling is the
/// manifest's `downsample`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchConfig {
    /// The style image's shorter side in render pixels: the motif scale (a style pixel
    /// per render pixel at 256 on a 256-pixel view).
    pub style_size: usize,
    /// Patch side (latent pixels, odd) at the smallest timestep of the set.
    pub patch_min: usize,
    /// Patch side at the largest timestep.
    pub patch_max: usize,
    /// The content model's scale: it sees latents and the style pooled this many times
    /// (its k(t) patches then cover this many times more of the image).
    pub content_scale: usize,
    /// Step of the grid the style's patches are taken on (1: every pixel).
    pub style_stride: usize,
    /// PCA dimensions of the candidate search (0: the full patch space).
    pub pca_dims: usize,
    /// Inverted-file cells of the style bank (0: no index, every patch scanned).
    pub cells: usize,
    /// Cells searched per pixel.
    pub probe: usize,
    /// Candidates per pixel (0: the whole bank, the exact posterior).
    pub shortlist: usize,
    /// Sinkhorn iterations balancing the style patches' use (0: the plain posterior).
    pub balance: usize,
    /// Radius (latent pixels) of the source model's local window.
    pub source_radius: usize,
    /// Weight of the structure guide (0: none).
    pub guide_weight: f32,
    /// The unconditional model: `identity` (the ideal generic model, which returns any
    /// clean image unchanged: CSD takes its prediction exactly) or `gaussian` (the
    /// moment-matched pixel Gaussian).
    pub null: NullModel,
    /// The content model: `identity`, `coarse` (the style's patches at
    /// `content_scale`), or `layout` (identity and coarse mixed by responsibility).
    pub content: ContentModel,
    /// Prior probability of the layout component in the `layout` mixture.
    pub layout_prior: f32,
    /// Coarse-to-fine: at timesteps from `coarse_from` up, the style model sees the
    /// latents and the style pooled `coarse_scale` times (its `patch_max` patches then
    /// cover that many times more of the image) and passes the finer detail of z_t / sa
    /// through; 1 = one scale.
    pub coarse_scale: usize,
    /// The smallest timestep of the coarse scale.
    pub coarse_from: usize,
    /// The source model goes coarse too at those timesteps (then CSD's difference cancels
    /// the fine band's noise that the coarse style model passes through; without it the
    /// coarse steps inject that noise, which the fine steps turn into the style's strokes).
    pub coarse_source: bool,
    /// The timestep set distillation draws from.
    pub timesteps: crate::prior::manifest::TimestepRange,
}

/// The patch prior's unconditional model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NullModel {
    Identity,
    Gaussian,
}

/// The patch prior's content model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContentModel {
    /// The exact unconditional model: negative guidance is off.
    Identity,
    /// The style's layout alone (its patches at `content_scale`).
    Coarse,
    /// The mixture of the identity and the style's layout, weighed per pixel by their
    /// posterior responsibility ([`PatchPrior::layout`]).
    Layout,
}

impl PatchConfig {
    fn validate(&self) -> Result<()> {
        let odd = |k: usize| k % 2 == 1;
        if !(odd(self.patch_min) && odd(self.patch_max) && self.patch_min <= self.patch_max) {
            return Err(Error::param(format!(
                "patch sizes {}..{}: odd, min <= max",
                self.patch_min, self.patch_max
            )));
        }
        if self.style_size < 8
            || self.content_scale == 0
            || self.style_stride == 0
            || self.coarse_scale == 0
        {
            return Err(Error::param(
                "style_size >= 8, content_scale and style_stride >= 1",
            ));
        }
        if !(self.guide_weight.is_finite() && self.guide_weight >= 0.0) {
            return Err(Error::param("guide_weight must be finite and >= 0"));
        }
        if !(self.layout_prior > 0.0 && self.layout_prior < 1.0) {
            return Err(Error::param("layout_prior must lie in (0, 1)"));
        }
        Ok(())
    }

    fn search(&self, balance: bool) -> Search {
        Search {
            shortlist: self.shortlist,
            probe: self.probe,
            balance: if balance { self.balance } else { 0 },
        }
    }
}

/// The patch prior (module docs).
pub struct PatchPrior {
    info: PriorInfo,
    schedule: Schedule,
    config: PatchConfig,
    /// The style image in latent space, `[3, h, w]`.
    style: Array3<f32>,
    /// Its structure channel `[1, h, w]`.
    style_guide: Array3<f32>,
    /// Whether a style image was given (else only encode and decode work).
    has_style: bool,
    strength: f32,
    /// Banks by (scale, patch side): the style model's; by patch side: the content model's.
    style_banks: HashMap<(usize, usize), Bank>,
    content_banks: HashMap<usize, Bank>,
    /// The smallest and largest noise std of the timestep set.
    sb_range: (f64, f64),
}

impl std::fmt::Debug for PatchPrior {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PatchPrior")
            .field("info", &self.info)
            .field("config", &self.config)
            .finish()
    }
}

/// PCA subspace iterations.
const PCA_ITERS: usize = 12;

/// A latent pixel is the object's when its pooled coverage exceeds this.
const OBJECT_ALPHA: f32 = 0.02;

impl PatchPrior {
    /// The prior of model directory `md` (family `patch`) with the style image of `opts`.
    pub fn open(md: &ModelDir, opts: &PriorOptions) -> Result<PatchPrior> {
        let m = &md.manifest;
        let config: PatchConfig = serde_json::from_value(m.patch.clone().unwrap_or_default())
            .map_err(|e| md.err(format!("patch: {e}")))?;
        config.validate().map_err(|e| md.err(e.to_string()))?;
        if m.latent_channels != 3 {
            return Err(md.err("a patch prior's latents are pixels: latent_channels 3"));
        }
        // Without a style image (`encode-latents`, which only encodes) the prior encodes
        // and decodes; its predictions refuse ([`PatchPrior::predict_eps`]).
        let has_style = opts.style_image.is_some();
        let style = match opts.style_image.as_ref() {
            Some(s) => style_latent(s.view(), config.style_size, m.downsample)?,
            None => Array3::zeros((3, 8, 8)),
        };
        let schedule = Schedule::new(m.scheduler.clone()).map_err(|e| md.err(e.to_string()))?;
        let tr = config.timesteps;
        let sb = |t: usize| schedule.coefficients(t).map(|c| c.1);
        let sb_range = (sb(tr.t_min)?, sb(tr.t_max)?);
        let info = PriorInfo {
            name: m.name.clone(),
            latent_channels: 3,
            downsample: m.downsample,
            scheduler: m.scheduler.clone(),
            control: Some(ControlKind::SourceAlpha),
            coinciding_style_content: None,
        };
        let strength = opts.strength.unwrap_or(1.0);
        if !(0.0..=1.0).contains(&strength) {
            return Err(Error::param(format!(
                "strength {strength} is not in [0, 1]"
            )));
        }
        Ok(PatchPrior {
            info,
            schedule,
            style_guide: structure(style.view()),
            has_style,
            style,
            config,
            strength,
            style_banks: HashMap::new(),
            content_banks: HashMap::new(),
            sb_range,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PatchConfig {
        &self.config
    }

    /// The style image in latent space `[3, h, w]`.
    pub fn style(&self) -> &Array3<f32> {
        &self.style
    }

    /// The style model's patch side at timestep `t`.
    pub fn patch_size(&self, t: usize) -> Result<usize> {
        let (_, sb) = self.schedule.coefficients(t)?;
        let (lo, hi) = self.sb_range;
        let f = if hi > lo {
            ((sb - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (a, b) = (self.config.patch_min, self.config.patch_max);
        Ok(a + 2 * ((f * (b - a) as f64 / 2.0).round() as usize))
    }

    /// The style bank of side `k` at scale `scale` (the style pooled that many times;
    /// made on first use).
    pub fn style_bank(&mut self, scale: usize, k: usize) -> Result<&Bank> {
        if !self.style_banks.contains_key(&(scale, k)) {
            let (stride, cells) = (self.config.style_stride, self.config.cells);
            let pooled = latent::pool(self.style.view().insert_axis(Axis(0)), scale);
            let stride = (stride / scale).max(1);
            let b = self.make_bank(pooled.index_axis(Axis(0), 0), k, stride, cells)?;
            self.style_banks.insert((scale, k), b);
        }
        Ok(&self.style_banks[&(scale, k)])
    }

    /// The style model's scale at timestep `t`.
    pub fn style_scale(&self, t: usize) -> usize {
        if self.config.coarse_scale > 1 && t >= self.config.coarse_from {
            self.config.coarse_scale
        } else {
            1
        }
    }

    /// The content bank of side `k`: the style pooled `content_scale` times.
    pub fn content_bank(&mut self, k: usize) -> Result<&Bank> {
        if !self.content_banks.contains_key(&k) {
            let s = self.config.content_scale;
            let pooled = latent::pool(self.style.view().insert_axis(Axis(0)), s);
            let b = self.make_bank(pooled.index_axis(Axis(0), 0), k, 1, 0)?;
            self.content_banks.insert(k, b);
        }
        Ok(&self.content_banks[&k])
    }

    fn make_bank(
        &self,
        img: ArrayView3<'_, f32>,
        k: usize,
        stride: usize,
        cells: usize,
    ) -> Result<Bank> {
        let p = patches(img, k, stride);
        let d = self.config.pca_dims;
        let pca = if d == 0 || d >= p.ncols() {
            None
        } else {
            Some(Pca::fit(p.view(), d, PCA_ITERS)?)
        };
        Bank::new(p, k, 3, pca, cells)
    }
}

/// The style image `[1, 3, H, W]` in `[0, 1]` resized to `size` render pixels on its
/// shorter side, in latent space (`[3, h, w]`, downsampled `f` times).
fn style_latent(style: ArrayView4<'_, f32>, size: usize, f: usize) -> Result<Array3<f32>> {
    let img = crate::imageio::Image::from_chw(style.index_axis(Axis(0), 0));
    let side = (size / f.max(1)).max(4);
    let small = img.with_shorter_side(side);
    let chw = small.to_chw().insert_axis(Axis(0));
    let z = latent::encode(chw.view(), 1)?;
    Ok(z.index_axis(Axis(0), 0).to_owned())
}

/// The structure channel `[1, h, w]` of a latent image `[3, h, w]`: luminance minus its
/// 3x3 box mean (band-passed), normalised to unit variance over the image.
pub fn structure(img: ArrayView3<'_, f32>) -> Array3<f32> {
    let (_, h, w) = img.dim();
    let luma = Array2::from_shape_fn((h, w), |(y, x)| {
        0.299 * img[[0, y, x]] + 0.587 * img[[1, y, x]] + 0.114 * img[[2, y, x]]
    });
    let mut out = Array3::<f32>::zeros((1, h, w));
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for dy in -1isize..=1 {
                for dx in -1isize..=1 {
                    let (yy, xx) = (y as isize + dy, x as isize + dx);
                    s += luma[[bank::reflect(yy, h), bank::reflect(xx, w)]];
                }
            }
            out[[0, y, x]] = luma[[y, x]] - s / 9.0;
        }
    }
    let std = (out.mapv(|v| v * v).mean().unwrap_or(0.0)).sqrt().max(1e-6);
    out.mapv_inplace(|v| v / std);
    out
}

impl Prior for PatchPrior {
    fn info(&self) -> &PriorInfo {
        &self.info
    }

    /// The style image's size in latent pixels, the banks built so far (scale, patch
    /// side, patches, cells) and, per timestep of the model's set, the style model's patch
    /// side, scale and motif scale (the patch's extent in render pixels).
    fn describe(&self) -> Option<serde_json::Value> {
        let f = self.info.downsample;
        let tr = self.config.timesteps;
        let set =
            crate::scheduler::TimestepSet::new(&self.info.scheduler, tr.t_min, tr.t_max, tr.count)
                .ok()?;
        let steps: Vec<serde_json::Value> = set
            .steps()
            .iter()
            .filter_map(|&t| {
                let (k, sc) = (self.patch_size(t).ok()?, self.style_scale(t));
                let k = if sc > 1 { self.config.patch_max } else { k };
                Some(serde_json::json!({"t": t, "patch": k, "scale": sc, "motif_px": k * sc * f}))
            })
            .collect();
        let mut banks: Vec<_> = self.style_banks.iter().collect();
        banks.sort_by_key(|(key, _)| **key);
        let banks: Vec<serde_json::Value> = banks
            .into_iter()
            .map(|(&(scale, k), b)| {
                serde_json::json!({"scale": scale, "patch": k, "patches": b.len(), "cells": b.cells()})
            })
            .collect();
        let (_, h, w) = self.style.dim();
        Some(serde_json::json!({
            "family": "patch",
            "style_latent": [h, w],
            "style_banks": banks,
            "timesteps": steps,
        }))
    }

    fn unconditional_is_identity(&self) -> bool {
        self.config.null == NullModel::Identity
    }

    fn content_is_identity(&self) -> bool {
        match self.config.content {
            ContentModel::Identity => true,
            ContentModel::Layout => self.config.null == NullModel::Identity,
            ContentModel::Coarse => false,
        }
    }

    fn content_layout(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        _control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Option<(Array4<f32>, Array4<f32>)>> {
        if self.config.content != ContentModel::Layout {
            return Ok(None);
        }
        let _ph = crate::timing::span("patch layout");
        self.layout(z_t, t).map(Some)
    }

    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        latent::encode(images, self.info.downsample)
    }

    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        Ok(latent::decode(latents, self.info.downsample))
    }

    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        if z_t.dim().1 != 3 {
            return Err(Error::param(format!(
                "patch prior: latents of {} channels, expected 3",
                z_t.dim().1
            )));
        }
        if !self.has_style {
            return Err(Error::param("the patch prior needs the style image"));
        }
        let win = Window::of(control, self.info.downsample, z_t.dim())?;
        let mut out = Vec::with_capacity(conds.len());
        for &c in conds {
            let _ph = crate::timing::span(match c {
                Cond::Null => "patch null",
                Cond::Prompt => "patch source",
                Cond::PromptStyle => "patch style",
                Cond::Content => "patch content",
            });
            let x0 = self.clean(z_t, t, c, &win)?;
            out.push(self.schedule.eps_from_x0(z_t, x0.view(), t)?);
        }
        Ok(out)
    }
}
