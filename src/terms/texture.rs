//! The VGG texture terms of the colour step, `nnfm` and `gram` (not part of FantasyStyle:
//! added because the CPU prior cannot carry a style's motifs on its own, see
//! docs/texture-term.md).
//!
//! The 2D stylizer draws strokes where each view's own content puts them, so views that
//! see a surface from 22-45 degrees apart ask for strokes in different places, and the
//! colour fit averages them into blobs of the style's colours. A texture statistic says
//! nothing about *where* a motif goes, only how often edges, dots and strokes of each
//! kind and colour occur; every view can agree with it at once, which is why the VGG
//! Gram baseline draws motifs. This term adds that statistic to the loop at the cost of
//! the first two VGG16 blocks only: the masked Gram loss (Gatys et al. 2016, Eq. 3-5)
//!
//! ```text
//! L_tex = 1/|L| sum_l ||G_l(x) - G_l(s)||^2 / C_l^2,   G_l(x) = F_l D_l F_l^T / sum(m_l)
//! ```
//!
//! over the layers `L` (default relu1_2 and relu2_2, where the motifs' scale lives), with
//! `F_l` the `[C, HW]` features of the view's object crop and `D_l = diag(m_l)` its
//! coverage (alpha, 2x2-averaged per pooling), so that the background and the fill
//! around the object count for nothing. The image the network sees is the object over
//! the fill of its own colours ([`crate::render::fill`]), the image the prior sees too; the fill
//! is held fixed, so dL/d(render) is dL/d(image) on covered pixels.
//!
//! With the term `nnfm` the statistic is instead ARF's nearest-neighbour feature
//! matching (Zhang et al. 2022, Eq. 1; [`super::nnfm`]) over the stacked features of one
//! VGG block (default relu3_1..relu3_3, receptive field 40 px): each covered position is
//! pulled toward its most similar style feature by cosine distance, weighted by its
//! coverage, `L = sum_i m_i (1 - cos(f_i, s_j*(i))) / sum_i m_i`. The Gram statistic keeps
//! only how often each feature occurs; matching whole relu3 features keeps local
//! arrangements of 20-40 px (a brick's corner, a ring's arc), which is what a regular
//! pattern's motif is made of. Cosine distance is nearly blind to colour, so the `arf`
//! preset pairs it with a start that brings the style's colours (docs/texture-term.md "A texture
//! term that carries arrangement"). `nnfm` and `gram` together add their losses (their
//! layers' gradients sum in one VGG backward, nnfm's first), each with its weight from
//! the configuration's `terms` ([`Statistic::weight`]): at equal weights the Gram
//! gradient is much the larger and decides the picture; the `arf` preset's NNFM at 1 with
//! Gram at 0.1 keeps NNFM's arrangements and adds more, smaller motifs in more of the
//! style's colours (docs/texture-term.md "NNFM plus a light Gram statistic").
//!
//! Cost: one forward and backward of VGG16 up to the deepest layer used (relu2_2 for
//! Gram, relu3_3 for NNFM, about twice the Gram cost with the nearest-neighbour search) on
//! the object's bounding box (plus 8 px) per view and iteration; the stages run the VGG
//! and the NNFM search on onnxruntime ([`crate::vgg`], [`StyleColumns`]). With
//! `downsample` D > 1 the crop, its coverage and the style image are box-averaged D x D
//! before the network (D^2 times fewer pixels; the motif scale on screen is kept, since
//! crop and style shrink alike) and the gradient is spread back evenly over each D x D
//! block (the exact adjoint of the average): the term then constrains the texture at
//! periods of 2D pixels and longer, and leaves finer detail to the prior.

use super::nnfm::{StyleColumns, normalised_style, split_stacked, stacked};
use crate::imageio::Image;
use crate::maths::gram::gram;
use crate::vgg::{Layer, Tensor3, Vgg16};
use crate::{Error, Result};
use ndarray::{Array2, Axis, linalg::general_mat_mul};
use rayon::prelude::*;

/// Margin around the object's bounding box, pixels.
const MARGIN: usize = 8;

/// The settings of the VGG texture terms (`nnfm`, `gram`): the `[texture]` section of the
/// method's configuration ([`crate::config`]; the field docs are its help).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TextureParams {
    /// The style image is resized so its shorter side is this many pixels for the texture
    /// terms and the projected start (sets the motif scale against the render's pixels).
    #[arg(long, default_value_t = 256)]
    pub style_size: usize,
    /// The terms see the object crop and the style box-averaged this many times smaller
    /// (motif scale on screen kept; D^2 times cheaper; periods under 2D pixels are left to
    /// the prior). 1 = full resolution; at most 8.
    #[arg(long, default_value_t = 1)]
    pub downsample: usize,
    /// The terms on this many of each iteration's views (rotating; scaled so that the
    /// gradient is the same in expectation); 0 = every view. 1 looked the same as every
    /// view at about 0.7x the CPU (docs/texture-term.md).
    #[arg(long, default_value_t = 1)]
    pub views: usize,
    /// VGG16 layers matched, with one VGG term (receptive fields: relu1_2 5 px, relu2_2
    /// 14 px, relu3_3 40 px); empty: relu1_2,relu2_2 for gram, relu3_1,relu3_2,relu3_3 for
    /// nnfm (one block).
    #[arg(long, value_delimiter = ',')]
    pub layers: Vec<Layer>,
    /// VGG16 weights (empty: lpips/vgg16 in the models directory).
    #[arg(long)]
    pub vgg: Option<std::path::PathBuf>,
}

impl Default for TextureParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl TextureParams {
    /// Shortest accepted style side: a level-8 synthesis pixel then still covers a 4 px
    /// style patch, and the motif scale means something.
    pub const MIN_STYLE_SIZE: usize = 32;

    /// Refuse a style size out of [32, 8192] px and a downsampling out of [1, 8].
    pub fn validate(&self) -> Result<()> {
        if !(Self::MIN_STYLE_SIZE..=8192).contains(&self.style_size) {
            return Err(Error::param(format!(
                "texture.style_size must lie in [{}, 8192] px, got {}",
                Self::MIN_STYLE_SIZE,
                self.style_size
            )));
        }
        if !(1..=8).contains(&self.downsample) {
            return Err(Error::param(format!(
                "texture.downsample must lie in [1, 8], got {}",
                self.downsample
            )));
        }
        Ok(())
    }
}

/// The statistic a VGG texture term matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TextureLoss {
    /// Masked Gram matrices (Gatys et al.): how often each feature occurs.
    Gram,
    /// Nearest-neighbour feature matching (ARF) over one VGG block's stacked features:
    /// local arrangements of the block's receptive field.
    Nnfm,
}

impl TextureLoss {
    /// The layers used when none are given: relu1_2 and relu2_2 for Gram, the relu3
    /// block for NNFM (as ARF).
    pub fn default_layers(self) -> Vec<Layer> {
        match self {
            TextureLoss::Gram => vec![Layer::Relu1_2, Layer::Relu2_2],
            TextureLoss::Nnfm => super::nnfm::NNFM_LAYERS.to_vec(),
        }
    }
}

/// One statistic of the term as the caller asks for it: what it matches, at which layers,
/// and its weight within the term (the parts' weighted losses add).
#[derive(Debug, Clone, PartialEq)]
pub struct Statistic {
    pub loss: TextureLoss,
    pub layers: Vec<Layer>,
    pub weight: f32,
}

impl Statistic {
    /// `loss` at `layers` with weight 1.
    pub fn new(loss: TextureLoss, layers: Vec<Layer>) -> Self {
        Statistic {
            loss,
            layers,
            weight: 1.0,
        }
    }
}

/// What the style is matched against: its Gram matrices or its normalised features.
#[derive(Debug)]
enum Targets {
    /// Row-major `C x C` per layer.
    Gram(Vec<Vec<f64>>),
    /// Unit-length stacked style features `[C_total, N_style]`.
    Nnfm(StyleColumns),
}

/// One statistic of the term at its layers; the term's loss is the sum over its parts.
#[derive(Debug)]
struct Part {
    layers: Vec<Layer>,
    weight: f32,
    targets: Targets,
}

/// The texture term: the network, the style's statistics, the weight.
#[derive(Debug)]
pub struct TextureTerm {
    vgg: Vgg16,
    parts: Vec<Part>,
    /// Every part's layers (the crop's pooling and the forward's depth).
    layers: Vec<Layer>,
    /// Box-average factor of crop and style before the network (1 = full resolution).
    downsample: usize,
    /// Views of each window that get the term (0 = all; see [`Self::views_per_iter`]).
    pub views: usize,
}

/// One view's texture loss and its gradient `[H, W, 3]` (zero outside the crop).
#[derive(Debug, Clone)]
pub struct TextureGrad {
    pub loss: f64,
    pub grad: Vec<f32>,
}

impl TextureTerm {
    /// The style's statistics: for each part, Gram matrices or
    /// normalised stacked features at those layers (the style image as given at the
    /// render's scale: the caller sizes it, which sets the motif scale against the
    /// render's pixels; it is box-averaged by `downsample` like the crops).
    pub fn new(vgg: Vgg16, style: &Image, parts: &[Statistic], downsample: usize) -> Result<Self> {
        if !(1..=8).contains(&downsample) {
            return Err(Error::param(format!(
                "texture downsample must be 1..=8, got {downsample}"
            )));
        }
        let style = &crate::imageio::downsample(style, downsample);
        if parts.is_empty() || parts.iter().any(|p| p.layers.is_empty()) {
            return Err(Error::param("texture term: at least one layer per loss"));
        }
        if let Some(p) = parts
            .iter()
            .find(|p| !(p.weight.is_finite() && p.weight >= 0.0))
        {
            return Err(Error::param(format!(
                "texture loss weights must be finite and >= 0, got {} for {:?}",
                p.weight, p.loss
            )));
        }
        for Statistic { loss, layers, .. } in parts {
            if *loss == TextureLoss::Nnfm && layers.iter().any(|l| l.pools() != layers[0].pools()) {
                return Err(Error::param(format!(
                    "texture loss nnfm stacks its layers' features, so they must come from \
                     one VGG block (same resolution); got {}",
                    layers
                        .iter()
                        .map(|l| l.name())
                        .collect::<Vec<_>>()
                        .join(",")
                )));
            }
        }
        let mut all: Vec<Layer> = parts
            .iter()
            .flat_map(|p| p.layers.iter().copied())
            .collect();
        all.sort();
        all.dedup();
        let deepest = *all.last().expect("non-empty");
        let f = vgg.forward(&style.data, style.height, style.width, deepest)?;
        let parts = parts
            .iter()
            .map(
                |Statistic {
                     loss,
                     layers,
                     weight,
                 }| {
                    let targets = match loss {
                        TextureLoss::Gram => {
                            Targets::Gram(layers.iter().map(|&l| gram(f.get(l))).collect())
                        }
                        TextureLoss::Nnfm => Targets::Nnfm(StyleColumns::new(
                            normalised_style(&f, layers),
                            vgg.onnxruntime_threads(),
                        )?),
                    };
                    Ok(Part {
                        layers: layers.clone(),
                        weight: *weight,
                        targets,
                    })
                },
            )
            .collect::<Result<Vec<_>>>()?;
        Ok(TextureTerm {
            vgg,
            parts,
            layers: all,
            downsample,
            views: 0,
        })
    }

    /// How many of a window's `n` views get the term in one iteration: `views` (0 = all),
    /// at most `n`. The caller rotates which ones with the iteration and scales the term
    /// by `n / k`, so its gradient is the same in expectation over a full rotation.
    pub fn views_per_iter(&self, n: usize) -> usize {
        if self.views == 0 {
            n
        } else {
            self.views.min(n)
        }
    }

    /// Whether the view at `position` of an `n`-view window gets the term in iteration
    /// `iteration`, and the factor `n / k` it is scaled by: positions `it mod n` ..
    /// `it mod n + k - 1` (cyclically), so over `n` consecutive iterations every position
    /// gets it exactly `k` times.
    pub fn applies(&self, position: usize, n: usize, iteration: u64) -> Option<f32> {
        let k = self.views_per_iter(n);
        let chosen = k > 0 && (position + n - (iteration % n as u64) as usize) % n < k;
        chosen.then(|| n as f32 / k as f32)
    }

    /// Loss and dL/d(image) of `image` (`[H, W, 3]`, the object over its fill) with
    /// coverage `alpha` (`[H, W]`). A view with no covered pixel has loss 0 and gradient 0.
    pub fn view_grad(
        &self,
        image: &[f32],
        alpha: &[f32],
        h: usize,
        w: usize,
    ) -> Result<TextureGrad> {
        let mut grad = vec![0.0f32; h * w * 3];
        let d = self.downsample;
        let Some((y0, y1, x0, x1)) = crop_box(alpha, h, w, &self.layers, d) else {
            return Ok(TextureGrad { loss: 0.0, grad });
        };
        let (ch, cw) = (y1 - y0, x1 - x0);
        let mut crop = vec![0.0f32; ch * cw * 3];
        let mut mask = vec![0.0f32; ch * cw];
        for y in 0..ch {
            let src = ((y0 + y) * w + x0) * 3;
            crop[y * cw * 3..(y + 1) * cw * 3].copy_from_slice(&image[src..src + cw * 3]);
            for x in 0..cw {
                mask[y * cw + x] = alpha[(y0 + y) * w + x0 + x].clamp(0.0, 1.0);
            }
        }
        // What the network sees: the crop and its coverage box-averaged d x d (the
        // project's image downsample and the feature-grid mask pooling).
        let (sh, sw) = (ch / d, cw / d);
        let (small, small_mask) = if d > 1 {
            let img = Image {
                width: cw,
                height: ch,
                data: crop,
            };
            let small = crate::imageio::downsample(&img, d).data;
            (small, pooled_mask(&mask, ch, cw, sh, sw))
        } else {
            (crop, mask)
        };
        let deepest = *self.layers.iter().max().expect("non-empty");
        let ph = crate::timing::span("vgg forward");
        let fw = self.vgg.forward(&small, sh, sw, deepest)?;
        drop(ph);
        let ph = crate::timing::span("statistic");
        let mut loss = 0.0;
        let mut grads: Vec<(Layer, Tensor3)> = Vec::new();
        for part in &self.parts {
            match &part.targets {
                Targets::Gram(targets) => {
                    let scale = part.weight / part.layers.len() as f32;
                    for (l, target) in part.layers.iter().zip(targets) {
                        let f = fw.get(*l);
                        let m = pooled_mask(&small_mask, sh, sw, f.h, f.w);
                        let (v, g) = masked_gram_loss_grad(f, &m, target, scale);
                        loss += v * scale as f64;
                        grads.push((*l, g));
                    }
                }
                Targets::Nnfm(style) => {
                    let f0 = fw.get(part.layers[0]);
                    let m = pooled_mask(&small_mask, sh, sw, f0.h, f0.w);
                    let f = stacked(&fw, &part.layers);
                    let (v, g) = style.loss_grad(f.view(), Some(&m), part.weight)?;
                    loss += v * part.weight as f64;
                    grads.extend(split_stacked(&fw, &part.layers, &g));
                }
            }
        }
        drop(ph);
        let ph = crate::timing::span("vgg backward");
        let refs: Vec<(Layer, &Tensor3)> = grads.iter().map(|(l, g)| (*l, g)).collect();
        let gc = self.vgg.backward(&fw, &refs)?;
        drop(ph);
        // The adjoint of the D x D average: each pixel of a block gets 1/D^2 of its gradient.
        let inv = 1.0 / (d * d) as f32;
        for y in 0..ch {
            for x in 0..cw {
                let (src, dst) = (((y / d) * sw + x / d) * 3, ((y0 + y) * w + x0 + x) * 3);
                for k in 0..3 {
                    grad[dst + k] = gc[src + k] * inv;
                }
            }
        }
        Ok(TextureGrad { loss, grad })
    }
}

/// The object's bounding box (alpha > 0.01) plus [`MARGIN`], as `(y0, y1, x0, x1)`,
/// grown to a multiple of `downsample` x 2^pools of the deepest layer (and to at least
/// that many pixels) within the frame; `None` with no covered pixel.
fn crop_box(
    alpha: &[f32],
    h: usize,
    w: usize,
    layers: &[Layer],
    downsample: usize,
) -> Option<(usize, usize, usize, usize)> {
    let (mut y0, mut y1, mut x0, mut x1) = (h, 0, w, 0);
    for y in 0..h {
        for x in 0..w {
            if alpha[y * w + x] > 0.01 {
                y0 = y0.min(y);
                y1 = y1.max(y + 1);
                x0 = x0.min(x);
                x1 = x1.max(x + 1);
            }
        }
    }
    if y1 == 0 {
        return None;
    }
    let unit = downsample << layers.iter().map(|l| l.pools()).max().unwrap_or(0);
    let grow = |lo: usize, hi: usize, n: usize| -> (usize, usize) {
        let (mut lo, mut hi) = (lo.saturating_sub(MARGIN), (hi + MARGIN).min(n));
        let want = (hi - lo).max(unit).next_multiple_of(unit).min(n - n % unit);
        while hi - lo < want {
            if hi < n {
                hi += 1;
            } else {
                lo -= 1;
            }
        }
        (lo, hi - (hi - lo) % unit)
    };
    let (y0, y1) = grow(y0, y1, h);
    let (x0, x1) = grow(x0, x1, w);
    (y1 > y0 && x1 > x0).then_some((y0, y1, x0, x1))
}

/// `mask` (`[h, w]`) averaged down to `[fh, fw]` (each feature position the mean of its
/// `h/fh x w/fw` block).
fn pooled_mask(mask: &[f32], h: usize, w: usize, fh: usize, fw: usize) -> Vec<f32> {
    let (by, bx) = (h / fh.max(1), w / fw.max(1));
    let mut out = vec![0.0f32; fh * fw];
    for y in 0..fh {
        for x in 0..fw {
            let mut s = 0.0;
            for dy in 0..by {
                for dx in 0..bx {
                    s += mask[(y * by + dy) * w + x * bx + dx];
                }
            }
            out[y * fw + x] = s / (by * bx).max(1) as f32;
        }
    }
    out
}

/// Masked Gram loss `||G - A||^2 / C^2` with `G = F D F^T / sum(m)`, and its gradient
/// w.r.t. `F` scaled by `scale`: `scale * 4 (G - A) F D / (C^2 sum(m))`.
pub fn masked_gram_loss_grad(f: &Tensor3, m: &[f32], target: &[f64], scale: f32) -> (f64, Tensor3) {
    let (c, hw) = (f.c, f.hw());
    let msum: f64 = m.iter().map(|&v| v as f64).sum();
    if msum <= 0.0 {
        return (0.0, Tensor3::zeros(c, f.h, f.w));
    }
    // G = (F D) F^T / sum(m) as one f32 GEMM (a loss gradient, not a reported measure:
    // the metrics' bitwise-reproducible f64 `gram` cost 54 ms per iteration at relu1_2 +
    // relu2_2 of a 256x256 crop, this a few).
    let mut fd = f.clone();
    for ch in 0..c {
        for p in 0..hw {
            fd.data[ch * hw + p] *= m[p];
        }
    }
    // Both GEMMs split the positions into one block per thread (the Gram as a sum of
    // per-block Grams, the gradient block by block).
    let block = hw.div_ceil(rayon::current_num_threads()).max(1);
    let (fdm, fm) = (fd.matrix(), f.matrix());
    let blocks: Vec<_> = fdm
        .axis_chunks_iter(Axis(1), block)
        .zip(fm.axis_chunks_iter(Axis(1), block))
        .collect();
    let g32 = blocks
        .par_iter()
        .map(|(a, b)| {
            let mut g = Array2::<f32>::zeros((c, c));
            general_mat_mul((1.0 / msum) as f32, a, &b.t(), 0.0, &mut g);
            g
        })
        .reduce(|| Array2::zeros((c, c)), |a, b| a + b);
    let g: Vec<f64> = g32.iter().map(|&v| v as f64).collect();
    let c2 = (c * c) as f64;
    let d64: Vec<f64> = g.iter().zip(target).map(|(a, b)| a - b).collect();
    let loss = d64.iter().map(|d| d * d).sum::<f64>() / c2;
    let diff =
        Array2::from_shape_vec((c, c), d64.iter().map(|&d| d as f32).collect()).expect("C x C");
    let mut grad = Array2::zeros((c, hw));
    let k = (scale as f64 * 4.0 / (c2 * msum)) as f32;
    let out: Vec<_> = grad
        .axis_chunks_iter_mut(Axis(1), block)
        .zip(fdm.axis_chunks_iter(Axis(1), block))
        .collect();
    out.into_par_iter()
        .for_each(|(mut g, a)| general_mat_mul(k, &diff, &a, 0.0, &mut g));
    (
        loss,
        Tensor3 {
            c,
            h: f.h,
            w: f.w,
            data: grad.into_raw_vec_and_offset().0,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The masked Gram gradient against central differences (f32 features, f64 loss).
    #[test]
    fn masked_gram_gradient_matches_finite_differences() {
        let mut rng = crate::rng::Rng::derive(7, "tex");
        let (c, h, w) = (3, 4, 5);
        let f = Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(|_| rng.uniform() as f32).collect(),
        };
        let m: Vec<f32> = (0..h * w)
            .map(|i| {
                if i % 3 == 0 {
                    0.0
                } else {
                    0.5 + 0.5 * rng.uniform() as f32
                }
            })
            .collect();
        // A Gram target is symmetric.
        let r: Vec<f64> = (0..c * c).map(|_| rng.uniform() * 0.2).collect();
        let target: Vec<f64> = (0..c * c).map(|i| r[i] + r[(i % c) * c + i / c]).collect();
        let (_, g) = masked_gram_loss_grad(&f, &m, &target, 1.0);
        let eps = 1e-3f32;
        for i in 0..f.data.len() {
            let mut a = f.clone();
            a.data[i] += eps;
            let mut b = f.clone();
            b.data[i] -= eps;
            let fd = (masked_gram_loss_grad(&a, &m, &target, 1.0).0
                - masked_gram_loss_grad(&b, &m, &target, 1.0).0)
                / (2.0 * eps as f64);
            let an = g.data[i] as f64;
            assert!(
                (fd - an).abs() <= 2e-3 * an.abs().max(1e-2),
                "entry {i}: finite difference {fd}, analytic {an}"
            );
            if m[i % (h * w)] == 0.0 {
                assert_eq!(an, 0.0, "a masked-out position gets no gradient");
            }
        }
    }

    /// The f32 GEMM Gram of the loss against the metrics' f64 `gram` (an independent
    /// computation: strip sums in f64), with every position fully covered so both define
    /// the same G: loss within 1e-5 relative on 4096 positions of 32 channels.
    #[test]
    fn gemm_gram_matches_the_f64_gram() {
        let mut rng = crate::rng::Rng::derive(11, "tex-gram");
        let (c, h, w) = (32, 64, 64);
        let f = Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(|_| rng.uniform() as f32 * 2.0).collect(),
        };
        let target: Vec<f64> = (0..c * c)
            .map(|i| if i % (c + 1) == 0 { 0.5 } else { 0.1 })
            .collect();
        let (loss, _) = masked_gram_loss_grad(&f, &vec![1.0; h * w], &target, 1.0);
        let reference = gram(&f)
            .iter()
            .zip(&target)
            .map(|(g, a)| (g - a) * (g - a))
            .sum::<f64>()
            / (c * c) as f64;
        assert!(
            (loss - reference).abs() <= 1e-5 * reference,
            "GEMM {loss} vs f64 {reference}"
        );
    }

    #[test]
    fn crop_box_covers_the_object_and_fits_the_pooling() {
        let (h, w) = (40, 50);
        let mut alpha = vec![0.0f32; h * w];
        for y in 10..20 {
            for x in 30..33 {
                alpha[y * w + x] = 1.0;
            }
        }
        for d in [1, 2, 3] {
            let (y0, y1, x0, x1) = crop_box(&alpha, h, w, &[Layer::Relu2_2], d).unwrap();
            assert!(y0 <= 10 && y1 >= 20 && x0 <= 30 && x1 >= 33);
            assert_eq!((y1 - y0) % (2 * d), 0);
            assert_eq!((x1 - x0) % (2 * d), 0);
            assert!(y1 <= h && x1 <= w);
            assert!(crop_box(&vec![0.0; h * w], h, w, &[Layer::Relu2_2], d).is_none());
        }
    }

    /// Over n consecutive iterations each window position gets the term exactly k times,
    /// k per iteration, scaled by n / k; k = 0 means every view.
    #[test]
    fn the_views_that_get_the_term_rotate_evenly() {
        let style = Image {
            width: 8,
            height: 8,
            data: vec![0.5; 8 * 8 * 3],
        };
        let mut term = TextureTerm::new(
            Vgg16::random(1, 16),
            &style,
            &[Statistic::new(TextureLoss::Gram, vec![Layer::Relu1_2])],
            1,
        )
        .unwrap();
        for (views, n) in [(1, 4), (2, 4), (3, 5), (0, 4), (6, 4)] {
            term.views = views;
            let k = term.views_per_iter(n);
            assert_eq!(k, if views == 0 { n } else { views.min(n) });
            let mut count = vec![0; n];
            for it in 7..7 + n as u64 {
                let chosen: Vec<_> = (0..n).filter_map(|i| term.applies(i, n, it)).collect();
                assert_eq!(chosen.len(), k, "iteration {it}");
                assert!(chosen.iter().all(|&s| s == n as f32 / k as f32));
                for (i, c) in count.iter_mut().enumerate() {
                    *c += term.applies(i, n, it).is_some() as usize;
                }
            }
            assert_eq!(count, vec![k; n], "views {views}, n {n}");
        }
    }

    #[test]
    fn nnfm_needs_the_layers_of_one_block() {
        let style = Image {
            width: 16,
            height: 16,
            data: vec![0.3; 16 * 16 * 3],
        };
        let layers = vec![Layer::Relu1_2, Layer::Relu2_2];
        let term = |loss| {
            TextureTerm::new(
                Vgg16::random(1, 8),
                &style,
                &[Statistic::new(loss, layers.clone())],
                1,
            )
        };
        let err = term(TextureLoss::Nnfm).unwrap_err().to_string();
        assert!(
            err.contains("one") && err.contains("relu1_2,relu2_2"),
            "{err}"
        );
        assert!(term(TextureLoss::Gram).is_ok());
    }

    /// The whole term's image gradient (crop, optional D x D average, VGG forward and
    /// backward, masked Gram or coverage-weighted NNFM, the average's adjoint) against central differences of its
    /// loss, with a small random-weight VGG; pixels outside the crop get exactly 0.
    #[test]
    fn view_gradient_matches_finite_differences_at_full_and_half_resolution() {
        let (h, w) = (28, 24);
        let mut rng = crate::rng::Rng::derive(3, "tex-view");
        let style = Image {
            width: 20,
            height: 20,
            data: (0..20 * 20 * 3).map(|_| rng.uniform() as f32).collect(),
        };
        let image: Vec<f32> = (0..h * w * 3).map(|_| rng.uniform() as f32).collect();
        let mut alpha = vec![0.0f32; h * w];
        for y in 6..20 {
            for x in 5..15 {
                alpha[y * w + x] = if (x + y) % 4 == 0 { 0.6 } else { 1.0 };
            }
        }
        let gram = Statistic::new(TextureLoss::Gram, vec![Layer::Relu1_2, Layer::Relu2_2]);
        let nnfm = Statistic::new(TextureLoss::Nnfm, vec![Layer::Relu2_1, Layer::Relu2_2]);
        // Unequal weights in the mix: each part's gradient carries its own weight.
        let light_gram = Statistic {
            weight: 0.3,
            ..gram.clone()
        };
        let cases = [
            (vec![gram.clone()], 1usize),
            (vec![gram.clone()], 2),
            (vec![nnfm.clone()], 1),
            (vec![gram, nnfm.clone()], 2),
            (vec![light_gram, nnfm], 1),
        ];
        for (parts, d) in cases {
            let vgg = Vgg16::random(5, 16);
            let term = TextureTerm::new(vgg, &style, &parts, d).unwrap();
            let layers = &term.layers;
            let g = term.view_grad(&image, &alpha, h, w).unwrap();
            assert!(g.loss > 0.0);
            let (y0, y1, x0, x1) = crop_box(&alpha, h, w, layers, d).unwrap();
            let loss = |img: &[f32]| term.view_grad(img, &alpha, h, w).unwrap().loss;
            let eps = 1e-3f32;
            // Relative L2 error of the sampled gradient: f32 features make single small
            // entries noisy (and ReLU kinks can flip one), the vector is not.
            let (mut checked, mut num, mut den) = (0, 0.0f64, 0.0f64);
            for q in (0..h * w * 3).step_by(7) {
                let (y, x) = ((q / 3) / w, (q / 3) % w);
                if !(y0..y1).contains(&y) || !(x0..x1).contains(&x) {
                    assert_eq!(g.grad[q], 0.0, "outside the crop: no gradient");
                    continue;
                }
                let (mut a, mut b) = (image.clone(), image.clone());
                a[q] += eps;
                b[q] -= eps;
                let fd = (loss(&a) - loss(&b)) / (2.0 * eps as f64);
                num += (fd - g.grad[q] as f64).powi(2);
                den += fd * fd;
                checked += 1;
            }
            assert!(checked > 50, "{checked} pixels checked");
            let rel = (num / den).sqrt();
            assert!(
                rel < 1e-2,
                "{parts:?}, downsample {d}: relative L2 error {rel}"
            );
        }
    }
}
