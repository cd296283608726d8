//! Baselines users compare FantasyStyle against, run through the same renderer, colour
//! fit and evaluation (issue: baselines; the paper's comparisons in its experiments).
//!
//! * [`gram`](mod@gram): Gram-matrix style loss (Gatys et al. 2016) over VGG16 relu1_2, relu2_2,
//!   relu3_3, relu4_3 at image scales 1 and 1/2, plus a content loss at relu4_3 against
//!   the original render — the loss SGSST-style 3DGS stylization optimises.
//! * [`nnfm`]: nearest-neighbour feature matching (ARF, Zhang et al. 2022): every
//!   relu3-block feature of a render is pulled toward its nearest style feature by
//!   cosine distance, plus a content loss at relu3_3.
//! * per-view 2D stylize + refit ([`run`]): each original view is stylized by the
//!   2D stylizer on its own, then colours are fitted to those images; no MVFC, no
//!   distillation.
//! * colour transfer ([`run`]): the object's colour mean and covariance moved onto
//!   the style image's (linear Monge-Kantorovich map on the SH colours), no texture, no
//!   optimisation: the method's colour start and finish alone
//!   ([`crate::transfer::colour`]).
//! * projection ([`run`]): the style image texture-mapped onto the object
//!   (triplanar projection along each Gaussian's normal, at the texture term's motif
//!   scale), no optimisation: the method's projected start alone
//!   ([`crate::transfer::projection`]).
//!
//! A run of any of them, start to end (objective, monitor, fit under a budget,
//! checkpoints), is [`run`]; the `stylize-baseline` stage reads the inputs and writes
//! what it produced.
//!
//! The VGG losses are image-space objectives ([`Objective`]): per view they return the
//! loss and dL/d(rgb) as an `[H, W, 3]` image, which the colour fit chains through the
//! renderer's colour backward pass into the SH coefficients. Geometry never changes.
//!
//! Style images: read as RGB (grayscale expanded to three channels, alpha dropped, see
//! [`crate::imageio`]) and sized for VGG16 by [`crate::vgg::prepare_style`].

pub mod fit;
pub mod gram;
pub mod nnfm;
pub mod run;

use crate::imageio::Image;
use crate::maths::gram::gram;
use crate::vgg::{Layer, Tensor3, Vgg16};
use crate::{Error, Result};
use ndarray::{Array2, linalg::general_mat_mul};

/// Smallest accepted render side for the VGG baselines: relu4_3 must have 2x2 positions
/// at the coarsest scale (three 2x2 poolings).
pub const MIN_VIEW_SIDE: usize = 16;

/// Loss terms of one view and the gradient of `total` w.r.t. the view's pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Terms {
    pub style: f64,
    pub content: f64,
    /// `style_weight * style + content_weight * content`.
    pub total: f64,
    /// dL_total/d(rgb), `[H, W, 3]`.
    pub grad: Vec<f32>,
}

/// An image-space objective over a fixed set of views.
pub trait Objective: Sync {
    /// Loss and gradient for view `view` rendered as `img`.
    fn eval(&self, view: usize, img: &Image) -> Result<Terms>;
}

/// Mean squared difference of two Gram matrices, `||G - A||^2 / C^2` (f64; `G` from
/// [`crate::maths::gram::gram`], `target` = A row-major `C x C`), and the gradient
/// w.r.t. the features `F` that made `G`, scaled by `scale`:
/// `scale * 4 (G - A) F / (C^2 H W)` (G - A is symmetric).
pub fn gram_loss_grad(f: &Tensor3, target: &[f64], scale: f32) -> (f64, Tensor3) {
    let g = gram(f);
    let c2 = (f.c * f.c) as f64;
    let d64: Vec<f64> = g.iter().zip(target).map(|(a, b)| a - b).collect();
    let loss = d64.iter().map(|d| d * d).sum::<f64>() / c2;
    let diff =
        Array2::from_shape_vec((f.c, f.c), d64.iter().map(|&d| d as f32).collect()).expect("C x C");
    let mut grad = Array2::zeros((f.c, f.hw()));
    let k = scale * 4.0 / (c2 as f32 * f.hw() as f32);
    general_mat_mul(k, &diff, &f.matrix(), 0.0, &mut grad);
    (
        loss,
        Tensor3 {
            c: f.c,
            h: f.h,
            w: f.w,
            data: grad.into_raw_vec_and_offset().0,
        },
    )
}

/// Mean squared error between features and the original's, and its gradient scaled by
/// `scale`: `scale * 2 (F - F0) / n`.
pub fn content_loss_grad(f: &Tensor3, f0: &Tensor3, scale: f32) -> (f64, Tensor3) {
    let n = f.data.len() as f64;
    let loss = f
        .data
        .iter()
        .zip(&f0.data)
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum::<f64>()
        / n;
    let k = scale * 2.0 / n as f32;
    let data = f
        .data
        .iter()
        .zip(&f0.data)
        .map(|(&a, &b)| k * (a - b))
        .collect();
    (
        loss,
        Tensor3 {
            c: f.c,
            h: f.h,
            w: f.w,
            data,
        },
    )
}

/// Check the views' sizes for the VGG baselines.
pub fn check_views(views: &[Image]) -> Result<()> {
    if views.is_empty() {
        return Err(Error::param("the view set is empty: nothing to stylize"));
    }
    for (i, v) in views.iter().enumerate() {
        if v.height.min(v.width) < MIN_VIEW_SIDE {
            return Err(Error::param(format!(
                "view {i} is {}x{}; the VGG baselines need at least {MIN_VIEW_SIDE}x{MIN_VIEW_SIDE}",
                v.width, v.height
            )));
        }
        if v.data.len() != v.height * v.width * 3 {
            return Err(Error::param(format!(
                "view {i} has a wrong number of values"
            )));
        }
    }
    Ok(())
}

/// Gram distance of an image to a style (the evaluation measure the issue asks to fall):
/// mean over relu1_2, relu2_2, relu3_3, relu4_3 at scale 1 of `||G - A||^2 / C^2`.
/// Uses [`gram::GramTargets`] built once for the style.
pub fn gram_distance(vgg: &Vgg16, targets: &gram::GramTargets, img: &Image) -> Result<f64> {
    let f = vgg.forward(&img.data, img.height, img.width, Layer::Relu4_3)?;
    let layers = &targets.layers;
    let mut s = 0.0;
    for (li, &l) in layers.iter().enumerate() {
        s += gram_loss_grad(f.get(l), &targets.grams[0][li], 0.0).0;
    }
    Ok(s / layers.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_view_set_is_refused() {
        assert!(check_views(&[]).is_err());
    }
}
