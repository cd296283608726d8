//! Colour-only optimisation of a scene against an image-space [`Objective`]: the loop the
//! VGG baselines run. Geometry (positions, scales, rotations, opacities) is never written;
//! only `sh_dc` and `sh_rest` change.
//!
//! Each step renders every view with the current colours, evaluates the objective, chains
//! dL/d(rgb) through the renderer's colour backward pass into SH gradients (averaged over
//! views) and takes one Adam step (Kingma & Ba 2015) with separate learning rates for the
//! DC and higher-order coefficients, as 3DGS does. The renderer is reached through
//! [`ColourViews`], so the loop is independent of how views are cached.

use super::{Image, Objective, Terms};
use crate::render::{ViewCache, backward::sh_backward, clamp_colours, raw_colours};
use crate::{Camera, Error, Result, Scene};

/// A fixed set of views of a scene with frozen geometry: render the current colours, and
/// the colour backward pass (image gradient to SH gradients, added into the buffers).
pub trait ColourViews: Sync {
    fn count(&self) -> usize;
    fn render(&self, scene: &Scene, view: usize) -> Result<Image>;
    fn backward(
        &self,
        scene: &Scene,
        view: usize,
        grad_rgb: &[f32],
        grad_dc: &mut [[f32; 3]],
        grad_rest: &mut [f32],
    ) -> Result<()>;
}

/// The renderer's frozen-geometry caches ([`ViewCache`]) of a set of cameras: colour
/// forward is the cached sparse blend of `max(0, SH(d) + 0.5)`, the backward its
/// transpose followed by the SH chain rule ([`sh_backward`]); bit-identical to
/// [`crate::render::render`]'s RGB.
#[derive(Debug)]
pub struct CachedViews {
    caches: Vec<ViewCache>,
    centres: Vec<[f32; 3]>,
    background: [f32; 3],
}

impl CachedViews {
    /// Project and composite `scene` once per camera (geometry is frozen from here on).
    pub fn build(scene: &Scene, cameras: &[Camera], background: [f32; 3]) -> Result<Self> {
        let caches = cameras
            .iter()
            .map(|c| ViewCache::build(scene, c))
            .collect::<Result<Vec<_>>>()?;
        Ok(CachedViews {
            caches,
            centres: cameras.iter().map(|c| c.center()).collect(),
            background,
        })
    }
}

impl ColourViews for CachedViews {
    fn count(&self) -> usize {
        self.caches.len()
    }
    fn render(&self, scene: &Scene, view: usize) -> Result<Image> {
        let c = &self.caches[view];
        let raw = raw_colours(scene, c.gaussians(), self.centres[view]);
        Ok(Image {
            h: c.height,
            w: c.width,
            data: c.forward(&clamp_colours(&raw), self.background),
        })
    }
    fn backward(
        &self,
        scene: &Scene,
        view: usize,
        grad_rgb: &[f32],
        grad_dc: &mut [[f32; 3]],
        grad_rest: &mut [f32],
    ) -> Result<()> {
        let c = &self.caches[view];
        let centre = self.centres[view];
        let raw = raw_colours(scene, c.gaussians(), centre);
        let gc = c.backward(grad_rgb);
        sh_backward(scene, c.gaussians(), centre, &raw, &gc, grad_dc, grad_rest);
        Ok(())
    }
}

/// Mean absolute error to fixed target images (the per-view stylize + refit baseline's
/// fit; the style term is the L1 distance, content is zero).
#[derive(Debug)]
pub struct L1Objective {
    pub targets: Vec<Image>,
}

impl Objective for L1Objective {
    fn eval(&self, view: usize, img: &Image) -> Result<Terms> {
        let t = self
            .targets
            .get(view)
            .ok_or_else(|| Error::param(format!("view {view} out of range")))?;
        if t.data.len() != img.data.len() {
            return Err(Error::param(format!(
                "view {view}: target is {}x{}, render is {}x{}",
                t.w, t.h, img.w, img.h
            )));
        }
        let n = img.data.len() as f64;
        let k = (1.0 / n) as f32;
        let mut loss = 0.0;
        let grad = img
            .data
            .iter()
            .zip(&t.data)
            .map(|(&a, &b)| {
                loss += (a as f64 - b as f64).abs();
                if a > b {
                    k
                } else if a < b {
                    -k
                } else {
                    0.0
                }
            })
            .collect();
        Ok(Terms {
            style: loss / n,
            content: 0.0,
            total: loss / n,
            grad,
        })
    }
}

/// Settings of the colour fit.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    pub steps: usize,
    /// Adam learning rate of the DC coefficients.
    pub lr_dc: f32,
    /// Adam learning rate of the higher-order coefficients.
    pub lr_rest: f32,
    /// Evaluate the monitor (e.g. Gram distance) every this many steps (and at the ends).
    pub monitor_every: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            steps: 100,
            lr_dc: 0.01,
            lr_rest: 0.0005,
            monitor_every: 10,
        }
    }
}

/// One line of `loss.json`: the objective before the update of step `step`, and the
/// monitor on the same renders when it was evaluated. The last entry (step = steps) is
/// the final scene, after every update.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StepLog {
    pub step: usize,
    pub total: f64,
    pub style: f64,
    pub content: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gram_distance: Option<f64>,
}

/// Adam state over a flat parameter vector.
#[derive(Debug, Clone)]
pub struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl Adam {
    const B1: f32 = 0.9;
    const B2: f32 = 0.999;
    const EPS: f32 = 1e-15;

    pub fn new(n: usize) -> Self {
        Adam {
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }
    /// One update of `params` with gradient `grad` and learning rate `lr`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32], lr: f32) {
        self.t += 1;
        let c1 = 1.0 - Self::B1.powi(self.t);
        let c2 = 1.0 - Self::B2.powi(self.t);
        for i in 0..params.len() {
            self.m[i] = Self::B1 * self.m[i] + (1.0 - Self::B1) * grad[i];
            self.v[i] = Self::B2 * self.v[i] + (1.0 - Self::B2) * grad[i] * grad[i];
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            params[i] -= lr * mh / (vh.sqrt() + Self::EPS);
        }
    }
}

/// A measure of the current renders logged beside the loss (the Gram distance).
pub type Monitor<'a> = &'a dyn Fn(&[Image]) -> Result<f64>;

/// Optimise the colours of `scene` for `obj` over `views`. `monitor` maps the current
/// renders to a number logged as `gram_distance` (every `monitor_every` steps and at the
/// first and last entries). `on_step` is called after each step (progress bars).
pub fn fit_objective(
    scene: &mut Scene,
    views: &dyn ColourViews,
    obj: &dyn Objective,
    opts: &FitOptions,
    monitor: Option<Monitor<'_>>,
    on_step: &mut dyn FnMut(usize),
) -> Result<Vec<StepLog>> {
    let nv = views.count();
    if nv == 0 {
        return Err(Error::param("the view set is empty: nothing to stylize"));
    }
    let n = scene.len();
    let mut adam_dc = Adam::new(n * 3);
    let mut adam_rest = Adam::new(scene.sh_rest.len());
    let mut log = Vec::with_capacity(opts.steps + 1);
    for step in 0..=opts.steps {
        let imgs = (0..nv)
            .map(|v| views.render(scene, v))
            .collect::<Result<Vec<_>>>()?;
        let want_monitor = step == 0
            || step == opts.steps
            || (opts.monitor_every > 0 && step % opts.monitor_every == 0);
        let gram_distance = match monitor {
            Some(m) if want_monitor => Some(m(&imgs)?),
            _ => None,
        };
        let mut entry = StepLog {
            step,
            total: 0.0,
            style: 0.0,
            content: 0.0,
            gram_distance,
        };
        let mut grad_dc = vec![[0.0f32; 3]; n];
        let mut grad_rest = vec![0.0f32; scene.sh_rest.len()];
        for (v, img) in imgs.iter().enumerate() {
            let mut t = obj.eval(v, img)?;
            if !t.total.is_finite() {
                return Err(Error::Other(format!(
                    "the loss became {} at step {step}, view {v}",
                    t.total
                )));
            }
            entry.total += t.total / nv as f64;
            entry.style += t.style / nv as f64;
            entry.content += t.content / nv as f64;
            let inv = 1.0 / nv as f32;
            t.grad.iter_mut().for_each(|g| *g *= inv);
            if step < opts.steps {
                views.backward(scene, v, &t.grad, &mut grad_dc, &mut grad_rest)?;
            }
        }
        log.push(entry);
        if step == opts.steps {
            break;
        }
        let gdc: Vec<f32> = grad_dc.iter().flatten().copied().collect();
        let mut pdc: Vec<f32> = scene.sh_dc.iter().flatten().copied().collect();
        adam_dc.step(&mut pdc, &gdc, opts.lr_dc);
        for (d, c) in scene.sh_dc.iter_mut().zip(pdc.chunks_exact(3)) {
            *d = [c[0], c[1], c[2]];
        }
        adam_rest.step(&mut scene.sh_rest, &grad_rest, opts.lr_rest);
        on_step(step + 1);
    }
    Ok(log)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::baselines::gram::{GramConfig, GramObjective};
    use crate::vgg::Vgg16;

    /// A toy linear "renderer" for testing the loop without the rasterizer: pixel p of view
    /// v is `sum_i W_v[p, i] max(0, SH_C0 dc_i + 0.5)` per channel, with fixed weights.
    pub(crate) struct LinearViews {
        pub h: usize,
        pub w: usize,
        pub weights: Vec<Vec<f32>>,
    }

    impl ColourViews for LinearViews {
        fn count(&self) -> usize {
            self.weights.len()
        }
        fn render(&self, scene: &Scene, view: usize) -> Result<Image> {
            let n = scene.len();
            let wv = &self.weights[view];
            let mut data = vec![0.0; self.h * self.w * 3];
            for p in 0..self.h * self.w {
                for i in 0..n {
                    for c in 0..3 {
                        let col = (crate::scene::SH_C0 * scene.sh_dc[i][c] + 0.5).max(0.0);
                        data[p * 3 + c] += wv[p * n + i] * col;
                    }
                }
            }
            Ok(Image {
                h: self.h,
                w: self.w,
                data,
            })
        }
        fn backward(
            &self,
            scene: &Scene,
            view: usize,
            grad_rgb: &[f32],
            grad_dc: &mut [[f32; 3]],
            _grad_rest: &mut [f32],
        ) -> Result<()> {
            let n = scene.len();
            let wv = &self.weights[view];
            for p in 0..self.h * self.w {
                for i in 0..n {
                    for c in 0..3 {
                        if crate::scene::SH_C0 * scene.sh_dc[i][c] + 0.5 > 0.0 {
                            grad_dc[i][c] +=
                                crate::scene::SH_C0 * wv[p * n + i] * grad_rgb[p * 3 + c];
                        }
                    }
                }
            }
            Ok(())
        }
    }

    pub(crate) fn toy_scene(n: usize) -> Scene {
        let mut r = crate::rng::Rng::new(4);
        Scene {
            positions: (0..n).map(|i| [i as f32, 0.0, 1.0]).collect(),
            log_scales: vec![[-2.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![1.0; n],
            sh_degree: 0,
            sh_dc: (0..n)
                .map(|_| [r.normal() as f32 * 0.3, r.normal() as f32 * 0.3, 0.0])
                .collect(),
            sh_rest: vec![],
        }
    }

    /// Gram distance falls under the Gram objective on the toy renderer; geometry untouched.
    #[test]
    fn gram_fit_reduces_gram_distance_and_keeps_geometry() {
        let (h, w, n) = (16, 16, 24);
        let mut r = crate::rng::Rng::new(2);
        let weights: Vec<Vec<f32>> = (0..2)
            .map(|_| {
                (0..h * w * n)
                    .map(|_| if r.uniform() < 0.1 { 0.5 } else { 0.0 })
                    .collect()
            })
            .collect();
        let views = LinearViews { h, w, weights };
        let mut scene = toy_scene(n);
        let before = scene.clone();
        let vgg = Vgg16::random(1, 16);
        let style = Image {
            h: 32,
            w: 32,
            data: (0..32 * 32 * 3).map(|i| ((i % 7) as f32) / 7.0).collect(),
        };
        let orig: Vec<Image> = (0..2).map(|v| views.render(&scene, v).unwrap()).collect();
        let cfg = GramConfig {
            content_weight: 0.0,
            ..GramConfig::default()
        };
        let obj = GramObjective::new(&vgg, cfg, &style, &orig).unwrap();
        let targets = obj.targets().clone();
        let mon = |imgs: &[Image]| -> Result<f64> {
            let mut s = 0.0;
            for i in imgs {
                s += crate::baselines::gram_distance(&vgg, &targets, i)?;
            }
            Ok(s / imgs.len() as f64)
        };
        let opts = FitOptions {
            steps: 15,
            lr_dc: 0.05,
            monitor_every: 5,
            ..FitOptions::default()
        };
        let log = fit_objective(&mut scene, &views, &obj, &opts, Some(&mon), &mut |_| {}).unwrap();
        assert_eq!(log.len(), 16);
        let first = log[0].gram_distance.unwrap();
        let last = log[15].gram_distance.unwrap();
        assert!(last < 0.8 * first, "gram distance {first} -> {last}");
        assert_eq!(scene.positions, before.positions);
        assert_eq!(scene.log_scales, before.log_scales);
        assert_eq!(scene.rotations, before.rotations);
        assert_eq!(scene.opacity_logits, before.opacity_logits);
        assert_ne!(scene.sh_dc, before.sh_dc);
    }

    #[test]
    fn empty_view_set_is_an_error() {
        let views = LinearViews {
            h: 16,
            w: 16,
            weights: vec![],
        };
        let mut scene = toy_scene(3);
        struct Zero;
        impl Objective for Zero {
            fn eval(&self, _: usize, img: &Image) -> Result<crate::baselines::Terms> {
                Ok(crate::baselines::Terms {
                    style: 0.0,
                    content: 0.0,
                    total: 0.0,
                    grad: vec![0.0; img.data.len()],
                })
            }
        }
        let e = fit_objective(
            &mut scene,
            &views,
            &Zero,
            &FitOptions::default(),
            None,
            &mut |_| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("empty"));
    }
}
