//! Gram-matrix style loss (Gatys et al. 2016, "Image style transfer using CNNs", Eq. 3-5),
//! multi-layer and multi-scale as SGSST applies it to 3DGS, plus a content loss.
//!
//! For a render x and style image s, with `F_l(x)` the `[C, H W]` ReLU output of layer l
//! and `G_l(x) = F_l F_l^T / (H W)`:
//!
//! `L_style = 1 / (|S| |L|) * sum_{scale in S} sum_{l in L} ||G_l(x_scale) - G_l(s_scale)||^2 / C_l^2`
//!
//! where `x_scale` is the render box-downsampled by the scale's factor and `s_scale` the
//! style image likewise; `L_content = mean (F_c(x) - F_c(x_orig))^2` at one layer (relu4_3)
//! against the original (unstylized) render of the same view. The objective is
//! `style_weight * L_style + content_weight * L_content`.

use super::{Objective, Terms, content_loss_grad, gram_loss_grad};
use crate::imageio::{Image, downsample, downsample_adjoint_add};
use crate::maths::gram::gram;
use crate::vgg::{Layer, Tensor3, Vgg16};
use crate::{Error, Result};

/// Settings of the Gram baseline.
#[derive(Debug, Clone, PartialEq)]
pub struct GramConfig {
    /// Style layers (default relu1_2, relu2_2, relu3_3, relu4_3).
    pub layers: Vec<Layer>,
    /// Downsampling factors of the image scales (default 1 and 2, i.e. 1x and 0.5x).
    pub factors: Vec<usize>,
    /// Layer of the content loss (default relu4_3).
    pub content_layer: Layer,
    pub style_weight: f64,
    pub content_weight: f64,
}

impl Default for GramConfig {
    fn default() -> Self {
        GramConfig {
            layers: vec![
                Layer::Relu1_2,
                Layer::Relu2_2,
                Layer::Relu3_3,
                Layer::Relu4_3,
            ],
            factors: vec![1, 2],
            content_layer: Layer::Relu4_3,
            style_weight: 1.0,
            content_weight: 0.05,
        }
    }
}

/// The style's Gram matrices, per scale (outer) and layer (inner).
#[derive(Debug, Clone)]
pub struct GramTargets {
    pub layers: Vec<Layer>,
    pub factors: Vec<usize>,
    /// Row-major `C x C` (see [`crate::maths::gram::gram`]).
    pub grams: Vec<Vec<Vec<f64>>>,
}

impl GramTargets {
    /// Gram matrices of `style` at every scale and layer.
    pub fn new(vgg: &Vgg16, style: &Image, layers: &[Layer], factors: &[usize]) -> Result<Self> {
        if layers.is_empty() || factors.is_empty() {
            return Err(Error::param(
                "Gram loss needs at least one layer and one scale",
            ));
        }
        if factors.contains(&0) {
            return Err(Error::param("scale factors must be positive"));
        }
        let deepest = *layers.iter().max().expect("non-empty");
        let mut grams = Vec::new();
        for &f in factors {
            let s = downsample(style, f);
            let fw = vgg.forward(&s.data, s.height, s.width, deepest)?;
            grams.push(layers.iter().map(|&l| gram(fw.get(l))).collect());
        }
        Ok(GramTargets {
            layers: layers.to_vec(),
            factors: factors.to_vec(),
            grams,
        })
    }
}

/// The Gram baseline's objective over a fixed set of views.
#[derive(Debug)]
pub struct GramObjective<'a> {
    vgg: &'a Vgg16,
    cfg: GramConfig,
    targets: GramTargets,
    /// Content features of each original view at `cfg.content_layer`.
    content: Vec<Tensor3>,
}

impl<'a> GramObjective<'a> {
    /// Targets from `style` (already prepared, see [`crate::vgg::prepare_style`]) and content
    /// features from the original renders `originals`.
    pub fn new(
        vgg: &'a Vgg16,
        cfg: GramConfig,
        style: &Image,
        originals: &[Image],
    ) -> Result<Self> {
        super::check_views(originals)?;
        for &f in &cfg.factors {
            let min = originals
                .iter()
                .map(|v| v.height.min(v.width))
                .min()
                .unwrap_or(0);
            if f == 0 || min / f < 8 {
                return Err(Error::param(format!(
                    "scale factor {f} leaves views of side {min} too small for relu4_3 (needs >= 8 px after downsampling)"
                )));
            }
        }
        let targets = GramTargets::new(vgg, style, &cfg.layers, &cfg.factors)?;
        let content = originals
            .iter()
            .map(|v| {
                let f = vgg.forward(&v.data, v.height, v.width, cfg.content_layer)?;
                Ok(f.get(cfg.content_layer).clone())
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(GramObjective {
            vgg,
            cfg,
            targets,
            content,
        })
    }

    pub fn targets(&self) -> &GramTargets {
        &self.targets
    }
}

impl Objective for GramObjective<'_> {
    fn eval(&self, view: usize, img: &Image) -> Result<Terms> {
        let c0 = self
            .content
            .get(view)
            .ok_or_else(|| Error::param(format!("view {view} out of range")))?;
        let cfg = &self.cfg;
        let n_terms = (cfg.layers.len() * cfg.factors.len()) as f64;
        let sw = (cfg.style_weight / n_terms) as f32;
        let mut grad = vec![0.0f32; img.data.len()];
        let (mut style, mut content) = (0.0, 0.0);
        for (si, &factor) in cfg.factors.iter().enumerate() {
            let x = downsample(img, factor);
            let with_content = factor == 1;
            let mut deepest = *cfg.layers.iter().max().expect("validated");
            if with_content {
                deepest = deepest.max(cfg.content_layer);
            }
            let fw = self.vgg.forward(&x.data, x.height, x.width, deepest)?;
            let mut grads: Vec<(Layer, Tensor3)> = Vec::new();
            for (li, &l) in cfg.layers.iter().enumerate() {
                let (v, g) = gram_loss_grad(fw.get(l), &self.targets.grams[si][li], sw);
                style += v;
                grads.push((l, g));
            }
            if with_content {
                let f = fw.get(cfg.content_layer);
                if (f.c, f.h, f.w) != (c0.c, c0.h, c0.w) {
                    return Err(Error::param(format!(
                        "view {view} is {}x{}, its original render had another size",
                        img.width, img.height
                    )));
                }
                let (v, g) = content_loss_grad(f, c0, cfg.content_weight as f32);
                content += v;
                grads.push((cfg.content_layer, g));
            }
            let refs: Vec<(Layer, &Tensor3)> = grads.iter().map(|(l, g)| (*l, g)).collect();
            let gx = self.vgg.backward(&fw, &refs)?;
            if factor == 1 {
                for (a, b) in grad.iter_mut().zip(&gx) {
                    *a += b;
                }
            } else {
                downsample_adjoint_add(&gx, factor, img.height, img.width, &mut grad);
            }
        }
        style /= n_terms;
        Ok(Terms {
            style,
            content,
            total: cfg.style_weight * style + cfg.content_weight * content,
            grad,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rand_tensor(seed: u64, c: usize, h: usize, w: usize) -> Tensor3 {
        let mut r = crate::rng::Rng::new(seed);
        let mut t = Tensor3::zeros(c, h, w);
        t.data.iter_mut().for_each(|v| *v = r.uniform() as f32);
        t
    }

    /// The Gram loss gradient w.r.t. features vs central differences (the loss is a
    /// smooth quartic; f64 accumulation; tolerance 1e-3 relative to the largest entry).
    #[test]
    fn gram_gradient_matches_finite_differences() {
        let f = rand_tensor(1, 5, 4, 3);
        let a = gram(&rand_tensor(2, 5, 6, 6));
        let (_, g) = gram_loss_grad(&f, &a, 1.0);
        let gmax = g.data.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
        let eps = 1e-2;
        for i in 0..f.data.len() {
            let mut p = f.clone();
            p.data[i] += eps;
            let mut m = f.clone();
            m.data[i] -= eps;
            let fd = (gram_loss_grad(&p, &a, 1.0).0 - gram_loss_grad(&m, &a, 1.0).0)
                / (2.0 * eps as f64);
            assert!(
                (fd - g.data[i] as f64).abs() <= 1e-3 * gmax,
                "entry {i}: fd {fd} analytic {}",
                g.data[i]
            );
        }
    }

    #[test]
    fn content_gradient_matches_finite_differences() {
        let f = rand_tensor(3, 3, 4, 4);
        let f0 = rand_tensor(4, 3, 4, 4);
        let (_, g) = content_loss_grad(&f, &f0, 0.7);
        let eps = 1e-2;
        for i in 0..f.data.len() {
            let mut p = f.clone();
            p.data[i] += eps;
            let mut m = f.clone();
            m.data[i] -= eps;
            let fd = 0.7 * (content_loss_grad(&p, &f0, 1.0).0 - content_loss_grad(&m, &f0, 1.0).0)
                / (2.0 * eps as f64);
            assert!((fd - g.data[i] as f64).abs() <= 1e-5, "entry {i}");
        }
    }

    /// The whole objective (two scales, four layers, content) through the VGG backward:
    /// directional derivative along a sparse random direction vs central differences
    /// (f32 forward, so ReLU kinks limit the tolerance to 2%).
    #[test]
    fn objective_gradient_matches_finite_differences() {
        let vgg = Vgg16::random(7, 16);
        let mut r = crate::rng::Rng::new(8);
        let mut img = |h: usize, w: usize| Image {
            width: w,
            height: h,
            data: (0..h * w * 3).map(|_| r.uniform() as f32).collect(),
        };
        let style = img(40, 36);
        let orig = img(20, 18);
        let x = img(20, 18);
        let obj = GramObjective::new(&vgg, GramConfig::default(), &style, &[orig]).unwrap();
        let t = obj.eval(0, &x).unwrap();
        assert!(t.style > 0.0 && t.content > 0.0);
        let mut r = crate::rng::Rng::new(10);
        let mut checked = 0;
        for _ in 0..12 {
            let i = (r.next_u64() % x.data.len() as u64) as usize;
            let eps = 1e-3f32;
            let mut p = x.clone();
            p.data[i] += eps;
            let mut m = x.clone();
            m.data[i] -= eps;
            let fd = (obj.eval(0, &p).unwrap().total - obj.eval(0, &m).unwrap().total)
                / (2.0 * eps as f64);
            let gmax = t.grad.iter().fold(0f32, |a, v| a.max(v.abs())) as f64;
            assert!(
                (fd - t.grad[i] as f64).abs() <= 0.02 * gmax,
                "pixel {i}: fd {fd} analytic {} (max {gmax})",
                t.grad[i]
            );
            checked += 1;
        }
        assert_eq!(checked, 12);
    }

    #[test]
    fn bad_views_are_errors() {
        let vgg = Vgg16::random(7, 16);
        let style = Image {
            width: 96,
            height: 96,
            data: vec![0.3; 96 * 96 * 3],
        };
        let e = GramObjective::new(&vgg, GramConfig::default(), &style, &[]).unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
        let tiny = Image {
            width: 30,
            height: 12,
            data: vec![0.3; 12 * 30 * 3],
        };
        assert!(GramObjective::new(&vgg, GramConfig::default(), &style, &[tiny]).is_err());
    }
}
