//! The NNFM baseline: ARF's nearest-neighbour feature matching (Zhang et al. 2022, Eq. 1;
//! the matching is the method's, [`crate::terms::nnfm`]) over the relu3 block, plus a
//! content loss: mean squared error at relu3_3 against the original render. ARF's colour
//! pre-transfer is not done.

use super::{Objective, Terms, content_loss_grad};
use crate::imageio::Image;
use crate::terms::nnfm::{NNFM_LAYERS, StyleColumns, normalised_style, split_stacked, stacked};
use crate::vgg::{Layer, Tensor3, Vgg16};
use crate::{Error, Result};

/// Settings of the NNFM baseline.
#[derive(Debug, Clone, PartialEq)]
pub struct NnfmConfig {
    pub style_weight: f64,
    pub content_weight: f64,
}

impl Default for NnfmConfig {
    fn default() -> Self {
        NnfmConfig {
            style_weight: 1.0,
            content_weight: 0.005,
        }
    }
}

/// The NNFM baseline's objective over a fixed set of views.
#[derive(Debug)]
pub struct NnfmObjective<'a> {
    vgg: &'a Vgg16,
    cfg: NnfmConfig,
    /// Normalised style features `[C_total, N_style]`.
    style: StyleColumns,
    content: Vec<Tensor3>,
}

impl<'a> NnfmObjective<'a> {
    pub fn new(
        vgg: &'a Vgg16,
        cfg: NnfmConfig,
        style: &Image,
        originals: &[Image],
    ) -> Result<Self> {
        super::check_views(originals)?;
        let fw = vgg.forward(&style.data, style.height, style.width, Layer::Relu3_3)?;
        let s = StyleColumns::new(
            normalised_style(&fw, &NNFM_LAYERS),
            vgg.onnxruntime_threads(),
        )?;
        let content = originals
            .iter()
            .map(|v| {
                let f = vgg.forward(&v.data, v.height, v.width, Layer::Relu3_3)?;
                Ok(f.get(Layer::Relu3_3).clone())
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(NnfmObjective {
            vgg,
            cfg,
            style: s,
            content,
        })
    }
}

impl Objective for NnfmObjective<'_> {
    fn eval(&self, view: usize, img: &Image) -> Result<Terms> {
        let c0 = self
            .content
            .get(view)
            .ok_or_else(|| Error::param(format!("view {view} out of range")))?;
        let fw = self
            .vgg
            .forward(&img.data, img.height, img.width, Layer::Relu3_3)?;
        let f3 = fw.get(Layer::Relu3_3);
        if (f3.c, f3.h, f3.w) != (c0.c, c0.h, c0.w) {
            return Err(Error::param(format!(
                "view {view} is {}x{}, its original render had another size",
                img.width, img.height
            )));
        }
        let f = stacked(&fw, &NNFM_LAYERS);
        let (style, g) = self
            .style
            .loss_grad(f.view(), None, self.cfg.style_weight as f32)?;
        let (content, gc) = content_loss_grad(f3, c0, self.cfg.content_weight as f32);
        let mut grads = split_stacked(&fw, &NNFM_LAYERS, &g);
        grads.push((Layer::Relu3_3, gc));
        let refs: Vec<(Layer, &Tensor3)> = grads.iter().map(|(l, g)| (*l, g)).collect();
        let grad = self.vgg.backward(&fw, &refs)?;
        Ok(Terms {
            style,
            content,
            total: self.cfg.style_weight * style + self.cfg.content_weight * content,
            grad,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objective_runs_and_content_is_zero_at_the_original() {
        let vgg = Vgg16::random(5, 16);
        let mut r = crate::rng::Rng::new(1);
        let mut img = |h: usize, w: usize| Image {
            width: w,
            height: h,
            data: (0..h * w * 3).map(|_| r.uniform() as f32).collect(),
        };
        let style = img(32, 32);
        let orig = img(16, 20);
        let obj = NnfmObjective::new(
            &vgg,
            NnfmConfig::default(),
            &style,
            std::slice::from_ref(&orig),
        )
        .unwrap();
        let t = obj.eval(0, &orig).unwrap();
        assert_eq!(t.content, 0.0);
        assert!(t.style > 0.0 && t.grad.iter().any(|&g| g != 0.0));
        assert!(obj.eval(1, &orig).is_err());
    }
}
