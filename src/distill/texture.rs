//! A low-layer texture term inside the distillation loop (not part of FantasyStyle:
//! added because the CPU prior cannot carry a style's motifs on its own, see
//! BENCHMARKS.md "Texture").
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
//! the fill of its own colours ([`super::fill`]), the image the prior sees too; the fill
//! is held fixed, so dL/d(render) is dL/d(image) on covered pixels.
//!
//! Cost: one forward and backward of VGG16 up to relu2_2 on the object's bounding box
//! (plus 8 px) per view and iteration.

use crate::imageio::Image;
use crate::metrics::gram::gram;
use crate::vgg::{Layer, Tensor3, Vgg16};
use crate::{Error, Result};
use ndarray::{Array2, linalg::general_mat_mul};

/// Margin around the object's bounding box, pixels.
const MARGIN: usize = 8;

/// The texture term: the network, the style's Gram matrices, the weight.
#[derive(Debug)]
pub struct TextureTerm {
    vgg: Vgg16,
    layers: Vec<Layer>,
    /// Row-major `C x C` per layer.
    targets: Vec<Vec<f64>>,
    /// Weight of the term's gradient against the colour loss's.
    pub weight: f32,
}

/// One view's texture loss and its gradient `[H, W, 3]` (zero outside the crop).
#[derive(Debug, Clone)]
pub struct TextureGrad {
    pub loss: f64,
    pub grad: Vec<f32>,
}

impl TextureTerm {
    /// The style's Gram matrices at `layers` (the style image as given: the caller sizes
    /// it, which sets the motif scale against the render's pixels).
    pub fn new(vgg: Vgg16, style: &Image, layers: &[Layer], weight: f32) -> Result<Self> {
        if layers.is_empty() {
            return Err(Error::param("texture term: at least one layer"));
        }
        if !(weight.is_finite() && weight >= 0.0) {
            return Err(Error::param(format!(
                "texture weight must be finite and >= 0, got {weight}"
            )));
        }
        let deepest = *layers.iter().max().expect("non-empty");
        let f = vgg.forward(&style.data, style.height, style.width, deepest)?;
        let targets = layers.iter().map(|&l| gram(f.get(l))).collect();
        Ok(TextureTerm {
            vgg,
            layers: layers.to_vec(),
            targets,
            weight,
        })
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
        let Some((y0, y1, x0, x1)) = crop_box(alpha, h, w, &self.layers) else {
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
        let deepest = *self.layers.iter().max().expect("non-empty");
        let fw = self.vgg.forward(&crop, ch, cw, deepest)?;
        let scale = 1.0 / self.layers.len() as f32;
        let mut loss = 0.0;
        let mut grads: Vec<(Layer, Tensor3)> = Vec::new();
        for (l, target) in self.layers.iter().zip(&self.targets) {
            let f = fw.get(*l);
            let m = pooled_mask(&mask, ch, cw, f.h, f.w);
            let (v, g) = masked_gram_loss_grad(f, &m, target, scale);
            loss += v * scale as f64;
            grads.push((*l, g));
        }
        let refs: Vec<(Layer, &Tensor3)> = grads.iter().map(|(l, g)| (*l, g)).collect();
        let gc = self.vgg.backward(&fw, &refs)?;
        for y in 0..ch {
            let dst = ((y0 + y) * w + x0) * 3;
            grad[dst..dst + cw * 3].copy_from_slice(&gc[y * cw * 3..(y + 1) * cw * 3]);
        }
        Ok(TextureGrad { loss, grad })
    }
}

/// The object's bounding box (alpha > 0.01) plus [`MARGIN`], as `(y0, y1, x0, x1)`,
/// grown to a multiple of 2^pools of the deepest layer (and to at least that many
/// pixels) within the frame; `None` with no covered pixel.
fn crop_box(
    alpha: &[f32],
    h: usize,
    w: usize,
    layers: &[Layer],
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
    let unit = 1usize << layers.iter().map(|l| l.pools()).max().unwrap_or(0);
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
    // G via the crate's Gram of F sqrt(m), rescaled from 1/(HW) to 1/sum(m).
    let mut fs = f.clone();
    let mut fd = f.clone();
    for ch in 0..c {
        for p in 0..hw {
            fs.data[ch * hw + p] *= m[p].sqrt();
            fd.data[ch * hw + p] *= m[p];
        }
    }
    let rescale = hw as f64 / msum;
    let g: Vec<f64> = gram(&fs).iter().map(|v| v * rescale).collect();
    let c2 = (c * c) as f64;
    let d64: Vec<f64> = g.iter().zip(target).map(|(a, b)| a - b).collect();
    let loss = d64.iter().map(|d| d * d).sum::<f64>() / c2;
    let diff =
        Array2::from_shape_vec((c, c), d64.iter().map(|&d| d as f32).collect()).expect("C x C");
    let mut grad = Array2::zeros((c, hw));
    let k = (scale as f64 * 4.0 / (c2 * msum)) as f32;
    general_mat_mul(k, &diff, &fd.matrix(), 0.0, &mut grad);
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

    #[test]
    fn crop_box_covers_the_object_and_fits_the_pooling() {
        let (h, w) = (40, 50);
        let mut alpha = vec![0.0f32; h * w];
        for y in 10..20 {
            for x in 30..33 {
                alpha[y * w + x] = 1.0;
            }
        }
        let (y0, y1, x0, x1) = crop_box(&alpha, h, w, &[Layer::Relu2_2]).unwrap();
        assert!(y0 <= 10 && y1 >= 20 && x0 <= 30 && x1 >= 33);
        assert_eq!((y1 - y0) % 2, 0);
        assert_eq!((x1 - x0) % 2, 0);
        assert!(y1 <= h && x1 <= w);
        assert!(crop_box(&vec![0.0; h * w], h, w, &[Layer::Relu2_2]).is_none());
    }
}
