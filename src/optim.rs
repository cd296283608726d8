//! Fitting SH colours to target images with geometry frozen (issue: update-gaussians).
//!
//! Loss (Kerbl et al. 2023, Eq. 7): `L = (1 - lambda) L1 + lambda (1 - SSIM)`, lambda =
//! 0.2, with SSIM as in the 3DGS code: 11x11 Gaussian window, sigma 1.5, zero "same"
//! padding, `C1 = 0.01^2`, `C2 = 0.03^2`, averaged over pixels and channels (Wang et al.
//! 2004). The optional alpha mask multiplies both the render and the target by the
//! rendered alpha (constant, geometry is frozen) before the loss, so uncovered pixels
//! carry no loss. [`loss_and_grad`] returns the loss and its exact gradient w.r.t. the
//! rendered image.
//!
//! Optimiser: Adam (Kingma & Ba 2015) with beta1 = 0.9, beta2 = 0.999 and eps = 1e-15
//! as in 3DGS, and separate learning rates for `f_dc` and `f_rest` (3DGS uses
//! `f_rest = f_dc / 20`). One step of [`fit_colours`] renders every view, sums the
//! per-view losses' gradients (divided by the number of views) and updates once; the
//! loss recorded per step is the mean over views before the update.

use crate::render::backward::{colour_grad_uncached, sh_backward};
use crate::render::{
    CacheMode, ViewCache, clamp_colours, composite, project, raw_colours, validate_camera,
    validate_scene,
};
use crate::{Camera, Error, Result, Scene};
use rayon::prelude::*;

/// SSIM constants of 3DGS.
pub const SSIM_C1: f32 = 0.01 * 0.01;
pub const SSIM_C2: f32 = 0.03 * 0.03;
const WIN: usize = 11;
const HALF: usize = WIN / 2;

fn gauss_window() -> [f32; WIN] {
    let mut k = [0.0f32; WIN];
    let mut s = 0.0;
    for (i, v) in k.iter_mut().enumerate() {
        let d = i as f32 - HALF as f32;
        *v = (-d * d / (2.0 * 1.5 * 1.5)).exp();
        s += *v;
    }
    k.iter_mut().for_each(|v| *v /= s);
    k
}

/// Separable 11-tap Gaussian blur of an `[h, w]` plane with zero padding (same size).
/// The kernel is symmetric, so this operator is its own transpose.
fn blur(src: &[f32], h: usize, w: usize, k: &[f32; WIN], tmp: &mut [f32], out: &mut [f32]) {
    // Horizontal: each row is copied into a zero-padded buffer, then accumulated tap by
    // tap over the whole row (a loop over x that vectorises).
    tmp.par_chunks_mut(w).zip(src.par_chunks(w)).for_each_init(
        || vec![0.0f32; w + 2 * HALF],
        |pad, (t, s)| {
            pad[HALF..HALF + w].copy_from_slice(s);
            t.fill(0.0);
            for (j, &kv) in k.iter().enumerate() {
                for (a, b) in t.iter_mut().zip(&pad[j..j + w]) {
                    *a += kv * b;
                }
            }
        },
    );
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        o.fill(0.0);
        let lo = y.saturating_sub(HALF);
        let hi = (y + HALF + 1).min(h);
        for yy in lo..hi {
            let kv = k[yy + HALF - y];
            let row = &tmp[yy * w..(yy + 1) * w];
            for (a, b) in o.iter_mut().zip(row) {
                *a += kv * b;
            }
        }
    });
}

/// Loss weights and options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossParams {
    /// lambda of the D-SSIM term, in [0, 1].
    pub ssim_weight: f32,
}

/// `(loss, dL/drender)` for `render` and `target` (`[h, w, 3]`), with an optional
/// `[h, w]` mask applied to both images.
pub fn loss_and_grad(
    render: &[f32],
    target: &[f32],
    mask: Option<&[f32]>,
    h: usize,
    w: usize,
    p: LossParams,
) -> (f32, Vec<f32>) {
    let npix = h * w;
    let n = (npix * 3) as f32;
    let lambda = p.ssim_weight;
    let m = |i: usize| mask.map_or(1.0, |m| m[i / 3]);
    // Masked images, planar per channel.
    let mut x = vec![0.0f32; npix * 3];
    let mut y = vec![0.0f32; npix * 3];
    for i in 0..npix * 3 {
        let c = i % 3;
        let pix = i / 3;
        x[c * npix + pix] = m(i) * render[i];
        y[c * npix + pix] = m(i) * target[i];
    }
    let mut grad_planar = vec![0.0f32; npix * 3];
    let mut l1 = 0.0f64;
    for i in 0..npix * 3 {
        let d = x[i] - y[i];
        l1 += d.abs() as f64;
        grad_planar[i] = (1.0 - lambda) * d.signum() * if d == 0.0 { 0.0 } else { 1.0 } / n;
    }
    let mut ssim_sum = 0.0f64;
    if lambda > 0.0 {
        let k = gauss_window();
        let mut tmp = vec![0.0f32; npix];
        let mut maps: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; npix]).collect();
        let mut prod = vec![0.0f32; npix];
        let mut d_mx = vec![0.0f32; npix];
        let mut d_pxx = vec![0.0f32; npix];
        let mut d_pxy = vec![0.0f32; npix];
        for c in 0..3 {
            let xs = &x[c * npix..(c + 1) * npix];
            let ys = &y[c * npix..(c + 1) * npix];
            let [mx, my, pxx, pyy, pxy] = &mut maps[..] else {
                unreachable!()
            };
            blur(xs, h, w, &k, &mut tmp, mx);
            blur(ys, h, w, &k, &mut tmp, my);
            prod.iter_mut().zip(xs).for_each(|(p, a)| *p = a * a);
            blur(&prod, h, w, &k, &mut tmp, pxx);
            prod.iter_mut().zip(ys).for_each(|(p, a)| *p = a * a);
            blur(&prod, h, w, &k, &mut tmp, pyy);
            prod.iter_mut()
                .zip(xs.iter().zip(ys))
                .for_each(|(p, (a, b))| *p = a * b);
            blur(&prod, h, w, &k, &mut tmp, pxy);
            // S = A1 A2 / (B1 B2) and its partials w.r.t. mu_x, E[x^2], E[xy].
            let g = -lambda / n;
            let mut s_sum = 0.0f64;
            for i in 0..npix {
                let (ux, uy) = (mx[i], my[i]);
                let a1 = 2.0 * ux * uy + SSIM_C1;
                let a2 = 2.0 * (pxy[i] - ux * uy) + SSIM_C2;
                let b1 = ux * ux + uy * uy + SSIM_C1;
                let b2 = (pxx[i] - ux * ux) + (pyy[i] - uy * uy) + SSIM_C2;
                let den = b1 * b2;
                let s = a1 * a2 / den;
                s_sum += s as f64;
                d_mx[i] = g
                    * ((2.0 * uy * a2 - 2.0 * uy * a1) / den - s * 2.0 * ux / b1
                        + s * 2.0 * ux / b2);
                d_pxx[i] = g * (-s / b2);
                d_pxy[i] = g * (2.0 * a1 / den);
            }
            ssim_sum += s_sum;
            // Back through the blurs (self-adjoint) and the products.
            let [bmx, bpxx, bpxy, _, _] = &mut maps[..] else {
                unreachable!()
            };
            blur(&d_mx, h, w, &k, &mut tmp, bmx);
            blur(&d_pxx, h, w, &k, &mut tmp, bpxx);
            blur(&d_pxy, h, w, &k, &mut tmp, bpxy);
            let gp = &mut grad_planar[c * npix..(c + 1) * npix];
            for i in 0..npix {
                gp[i] += bmx[i] + 2.0 * xs[i] * bpxx[i] + ys[i] * bpxy[i];
            }
        }
    }
    let ssim = if lambda > 0.0 {
        ssim_sum / n as f64
    } else {
        1.0
    };
    let loss = (1.0 - lambda as f64) * l1 / n as f64 + lambda as f64 * (1.0 - ssim);
    // Back to interleaved, through the mask.
    let mut grad = vec![0.0f32; npix * 3];
    for i in 0..npix * 3 {
        grad[i] = m(i) * grad_planar[(i % 3) * npix + i / 3];
    }
    (loss as f32, grad)
}

/// Mean SSIM of two `[h, w, 3]` images (3DGS window).
pub fn ssim(a: &[f32], b: &[f32], h: usize, w: usize) -> f32 {
    let (l, _) = loss_and_grad(a, b, None, h, w, LossParams { ssim_weight: 1.0 });
    1.0 - l
}

/// PSNR in dB of `a` against `b` (values in [0, 1]).
pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.len().max(1) as f64;
    -10.0 * mse.max(1e-20).log10()
}

/// The moments and step count of one [`Adam`].
#[derive(Debug, Clone, PartialEq)]
pub struct AdamState {
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub t: i32,
}

/// The state of a [`ColourFit`]'s optimizers (f_dc, f_rest).
#[derive(Debug, Clone, PartialEq)]
pub struct OptimizerState {
    pub dc: AdamState,
    pub rest: AdamState,
}

/// Adam state for one parameter vector.
#[derive(Debug, Clone)]
pub struct Adam {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl Adam {
    /// 3DGS settings: beta (0.9, 0.999), eps 1e-15.
    pub fn new(n: usize, lr: f32) -> Adam {
        Adam {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// The moments and step count.
    pub fn state(&self) -> AdamState {
        AdamState {
            m: self.m.clone(),
            v: self.v.clone(),
            t: self.t,
        }
    }

    /// Replace the moments and step count; `what` names the parameters in errors.
    pub fn set_state(&mut self, s: AdamState, what: &str) -> Result<()> {
        if s.m.len() != self.m.len() || s.v.len() != self.v.len() {
            return Err(Error::param(format!(
                "{what}: optimizer state holds {} / {} moments, the scene needs {}",
                s.m.len(),
                s.v.len(),
                self.m.len()
            )));
        }
        if s.t < 0 || s.m.iter().chain(&s.v).any(|x| !x.is_finite()) || s.v.iter().any(|x| *x < 0.0)
        {
            return Err(Error::param(format!(
                "{what}: optimizer state is not valid (negative step or second moment, or not finite)"
            )));
        }
        self.m = s.m;
        self.v = s.v;
        self.t = s.t;
        Ok(())
    }

    /// One update of `params` with gradient `grad`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t);
        let bc2 = 1.0 - self.beta2.powi(self.t);
        let (b1, b2, lr, eps) = (self.beta1, self.beta2, self.lr, self.eps);
        params
            .par_iter_mut()
            .zip(grad.par_iter())
            .zip(self.m.par_iter_mut().zip(self.v.par_iter_mut()))
            .for_each(|((p, &g), (m, v))| {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                let mh = *m / bc1;
                let vh = *v / bc2;
                *p -= lr * mh / (vh.sqrt() + eps);
            });
    }
}

/// Parameters of [`fit_colours`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitParams {
    /// Adam learning rate of `f_dc` (3DGS: 0.0025).
    pub lr_dc: f32,
    /// Adam learning rate of `f_rest` (3DGS: `lr_dc / 20`).
    pub lr_rest: f32,
    /// lambda of the D-SSIM term.
    pub ssim_weight: f32,
    /// Multiply render and target by the rendered alpha before the loss.
    pub mask_alpha: bool,
    pub cache: CacheMode,
    /// Background colour the renders are composited over.
    pub background: [f32; 3],
    /// Show a progress bar.
    pub progress: bool,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            lr_dc: 0.0025,
            lr_rest: 0.0025 / 20.0,
            ssim_weight: 0.2,
            mask_alpha: false,
            cache: CacheMode::On,
            background: [0.0; 3],
            progress: false,
        }
    }
}

/// What a fit did besides updating colours.
#[derive(Debug, Clone, PartialEq)]
pub struct FitReport {
    /// Mean loss over views, per step (before that step's update).
    pub losses: Vec<f32>,
    /// Views whose contributions were cached.
    pub cached_views: usize,
    /// Bytes held by the caches.
    pub cache_bytes: usize,
}

enum ViewState {
    Cached {
        cache: Box<ViewCache>,
        alpha: Vec<f32>,
    },
    Uncached,
}

fn check_params(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    steps: usize,
    p: &FitParams,
) -> Result<()> {
    validate_scene(scene)?;
    if steps == 0 {
        return Err(Error::param("steps must be at least 1"));
    }
    if cameras.is_empty() {
        return Err(Error::param("no cameras to fit to"));
    }
    if targets.len() != cameras.len() {
        return Err(Error::param(format!(
            "{} target images for {} cameras",
            targets.len(),
            cameras.len()
        )));
    }
    for (i, (c, t)) in cameras.iter().zip(targets).enumerate() {
        validate_camera(c)?;
        let want = c.width as usize * c.height as usize * 3;
        if t.len() != want {
            return Err(Error::param(format!(
                "target {i} has {} values; camera {:?} is {}x{} (needs {want})",
                t.len(),
                c.name,
                c.width,
                c.height
            )));
        }
        if let Some(j) = t.iter().position(|v| !v.is_finite()) {
            return Err(Error::param(format!(
                "target {i} has a non-finite value at index {j}"
            )));
        }
    }
    check_options(p)
}

/// Learning rates, SSIM weight and background of a fit.
fn check_options(p: &FitParams) -> Result<()> {
    let lr_ok = |v: f32| v.is_finite() && v >= 0.0;
    if !(lr_ok(p.lr_dc) && lr_ok(p.lr_rest)) {
        return Err(Error::param(format!(
            "learning rates must be finite and >= 0 (lr_dc {}, lr_rest {})",
            p.lr_dc, p.lr_rest
        )));
    }
    if !(0.0..=1.0).contains(&p.ssim_weight) {
        return Err(Error::param(format!(
            "ssim weight {} is outside [0, 1]",
            p.ssim_weight
        )));
    }
    if !p.background.iter().all(|v| v.is_finite()) {
        return Err(Error::param("background colour is not finite"));
    }
    Ok(())
}

/// Fit the SH colours (`f_dc`, `f_rest`) of `scene` so that its renders from `cameras`
/// match `targets` (`[H, W, 3]` per camera), for `steps` Adam steps. Every other field
/// of the returned scene is the input's, bit for bit.
///
/// A view in which no Gaussian blends is kept (its loss counts, it gives no gradient)
/// with a warning; if no view sees any Gaussian, this is an error (nothing to fit).
pub fn fit_colours(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    steps: usize,
    p: &FitParams,
) -> Result<(Scene, FitReport)> {
    check_params(scene, cameras, targets, steps, p)?;
    let mut fit = ColourFit::new(scene, cameras, targets, p)?;
    let bar = if p.progress {
        indicatif::ProgressBar::new(steps as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("fit colours");
    for _ in 0..steps {
        let loss = fit.step();
        bar.set_message(format!("fit colours, loss {loss:.5}"));
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(fit.finish())
}

/// A per-view loss for [`ColourFit::step_with`]: `(view, rgb, alpha) -> (loss, dL/drgb)`.
pub type ViewLoss<'a> = dyn FnMut(usize, &[f32], Option<&[f32]>) -> Result<(f64, Vec<f32>)> + 'a;

/// The state of a colour fit: per-view caches (or not), Adam moments, the current
/// scene. [`fit_colours`] drives it; benchmarks time [`ColourFit::step`] alone.
pub struct ColourFit<'a> {
    cameras: &'a [Camera],
    targets: Option<&'a [Vec<f32>]>,
    params: FitParams,
    states: Vec<ViewState>,
    scene: Scene,
    dc: Vec<f32>,
    adam_dc: Adam,
    adam_rest: Adam,
    grad_dc: Vec<[f32; 3]>,
    grad_rest: Vec<f32>,
    losses: Vec<f32>,
    cached_views: usize,
    cache_bytes: usize,
}

impl<'a> ColourFit<'a> {
    /// Validate the inputs and plan the views: build the caches that the mode allows.
    pub fn new(
        scene: &Scene,
        cameras: &'a [Camera],
        targets: &'a [Vec<f32>],
        p: &FitParams,
    ) -> Result<ColourFit<'a>> {
        check_params(scene, cameras, targets, 1, p)?;
        let mut fit = Self::without_targets(scene, cameras, p)?;
        fit.targets = Some(targets);
        Ok(fit)
    }

    /// A fit whose per-step losses the caller supplies ([`Self::step_views`],
    /// [`Self::step_with`]); it has no targets, so [`Self::step`] must not be called.
    pub fn without_targets(
        scene: &Scene,
        cameras: &'a [Camera],
        p: &FitParams,
    ) -> Result<ColourFit<'a>> {
        validate_scene(scene)?;
        if cameras.is_empty() {
            return Err(Error::param("no cameras to fit to"));
        }
        for c in cameras {
            validate_camera(c)?;
        }
        check_options(p)?;
        let mut states = Vec::with_capacity(cameras.len());
        let mut cache_bytes = 0usize;
        let mut any_visible = false;
        for cam in cameras {
            let cache = ViewCache::from_frame(&project(scene, cam));
            if cache.blends() == 0 {
                tracing::warn!("camera {:?}: no Gaussian is visible", cam.name);
            } else {
                any_visible = true;
            }
            let keep = match p.cache {
                CacheMode::On => true,
                CacheMode::Off => false,
                CacheMode::Budget(b) => cache_bytes + cache.bytes() <= b,
            };
            if keep {
                cache_bytes += cache.bytes();
                let alpha = if p.mask_alpha {
                    cache.alpha()
                } else {
                    Vec::new()
                };
                states.push(ViewState::Cached {
                    cache: Box::new(cache),
                    alpha,
                });
            } else {
                states.push(ViewState::Uncached);
            }
        }
        if !any_visible {
            return Err(Error::param(format!(
                "no Gaussian of the scene ({} Gaussians) is visible from any of the {} cameras",
                scene.len(),
                cameras.len()
            )));
        }
        let cached_views = states
            .iter()
            .filter(|s| matches!(s, ViewState::Cached { .. }))
            .count();
        tracing::info!(
            "fitting colours of {} Gaussians (SH degree {}) to {} views, {} cached ({:.1} MB)",
            scene.len(),
            scene.sh_degree,
            cameras.len(),
            cached_views,
            cache_bytes as f64 / 1e6
        );
        let k = scene.rest_per_channel();
        let n = scene.len();
        Ok(ColourFit {
            cameras,
            targets: None,
            params: p.clone(),
            states,
            scene: scene.clone(),
            dc: scene.sh_dc.iter().flatten().copied().collect(),
            adam_dc: Adam::new(n * 3, p.lr_dc),
            adam_rest: Adam::new(n * k * 3, p.lr_rest),
            grad_dc: vec![[0.0; 3]; n],
            grad_rest: vec![0.0; n * k * 3],
            losses: Vec::new(),
            cached_views,
            cache_bytes,
        })
    }

    /// Views whose contributions are cached, and the bytes the caches hold.
    pub fn cache_stats(&self) -> (usize, usize) {
        (self.cached_views, self.cache_bytes)
    }

    /// One Adam step over all views; returns the mean loss over views before the update.
    pub fn step(&mut self) -> f32 {
        let lp = LossParams {
            ssim_weight: self.params.ssim_weight,
        };
        let cameras = self.cameras;
        let targets = self
            .targets
            .expect("ColourFit::step needs the targets given to ColourFit::new");
        let mut loss = |v: usize, rgb: &[f32], alpha: Option<&[f32]>| -> Result<(f64, Vec<f32>)> {
            let (h, w) = (cameras[v].height as usize, cameras[v].width as usize);
            let (l, g) = loss_and_grad(rgb, &targets[v], alpha, h, w, lp);
            Ok((l as f64, g))
        };
        self.step_with(&mut loss)
            .expect("the L1 + D-SSIM loss cannot fail") as f32
    }

    /// The image-gradient hook (added for the VGG baselines): one Adam step over all
    /// views like [`ColourFit::step`], with the per-view loss supplied by the caller.
    /// `view_loss(v, rgb, alpha)` gets camera `v`'s render `[H, W, 3]` (and its alpha
    /// when `mask_alpha` is set) and returns the loss and dL/d(rgb); the gradient is
    /// chained through the colour backward pass. Returns the mean loss over views before
    /// the update; the targets given to [`ColourFit::new`] are not used.
    pub fn step_with(&mut self, view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_views(&all, view_loss)
    }

    /// One Adam step over the cameras `views` only (indices into the cameras given to
    /// [`Self::new`]): the per-view losses' gradients are summed, divided by
    /// `views.len()`, and applied once. Returns the mean loss over `views` before the
    /// update. Distillation ([`crate::distill`]) steps on a few adjacent views at a time.
    pub fn step_views(&mut self, views: &[usize], view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        if views.is_empty() || views.iter().any(|&v| v >= self.cameras.len()) {
            return Err(Error::param(format!(
                "step_views: views {views:?} for {} cameras",
                self.cameras.len()
            )));
        }
        let p = &self.params;
        let out = &self.scene;
        let (grad_dc, grad_rest) = (&mut self.grad_dc, &mut self.grad_rest);
        grad_dc.iter_mut().for_each(|g| *g = [0.0; 3]);
        grad_rest.iter_mut().for_each(|g| *g = 0.0);
        let mut loss_sum = 0.0f64;
        for &v in views {
            let (cam, state) = (&self.cameras[v], &self.states[v]);
            let centre = cam.center();
            match state {
                ViewState::Cached { cache, alpha } => {
                    let ids = cache.gaussians();
                    let raw = raw_colours(out, ids, centre);
                    let rgb = cache.forward(&clamp_colours(&raw), p.background);
                    let mask = p.mask_alpha.then_some(&alpha[..]);
                    let (l, g) = view_loss(v, &rgb, mask)?;
                    loss_sum += l;
                    let gc = cache.backward(&g);
                    sh_backward(out, ids, centre, &raw, &gc, grad_dc, grad_rest);
                }
                ViewState::Uncached => {
                    let frame = project(out, cam);
                    let ids = &frame.splats.ids;
                    let raw = raw_colours(out, ids, centre);
                    let r = composite(&frame, &clamp_colours(&raw), p.background);
                    let mask = p.mask_alpha.then_some(&r.alpha[..]);
                    let (l, g) = view_loss(v, &r.rgb, mask)?;
                    loss_sum += l;
                    let gc = colour_grad_uncached(&frame, &g);
                    sh_backward(out, ids, centre, &raw, &gc, grad_dc, grad_rest);
                }
            }
        }
        let nv = views.len() as f32;
        let gdc: Vec<f32> = grad_dc.iter().flatten().map(|g| g / nv).collect();
        grad_rest.iter_mut().for_each(|g| *g /= nv);
        self.adam_dc.step(&mut self.dc, &gdc);
        self.adam_rest.step(&mut self.scene.sh_rest, grad_rest);
        let dc = &self.dc;
        for (i, c) in self.scene.sh_dc.iter_mut().enumerate() {
            *c = [dc[i * 3], dc[i * 3 + 1], dc[i * 3 + 2]];
        }
        let loss = loss_sum / views.len() as f64;
        self.losses.push(loss as f32);
        Ok(loss)
    }

    /// Camera `v`'s render `[H, W, 3]` with the current colours (the cached forward
    /// pass where the view is cached, a full rasterization otherwise).
    pub fn render_view(&self, v: usize) -> Vec<f32> {
        let cam = &self.cameras[v];
        let centre = cam.center();
        match &self.states[v] {
            ViewState::Cached { cache, .. } => {
                let raw = raw_colours(&self.scene, cache.gaussians(), centre);
                cache.forward(&clamp_colours(&raw), self.params.background)
            }
            ViewState::Uncached => {
                let frame = project(&self.scene, cam);
                let raw = raw_colours(&self.scene, &frame.splats.ids, centre);
                composite(&frame, &clamp_colours(&raw), self.params.background).rgb
            }
        }
    }

    /// The optimizer's state (Adam moments and step counts), for checkpoints.
    pub fn optimizer_state(&self) -> OptimizerState {
        OptimizerState {
            dc: self.adam_dc.state(),
            rest: self.adam_rest.state(),
        }
    }

    /// Restore a state saved by [`Self::optimizer_state`] for this scene (same number
    /// of Gaussians and SH degree), so a resumed fit continues bit for bit.
    pub fn set_optimizer_state(&mut self, s: OptimizerState) -> Result<()> {
        self.adam_dc.set_state(s.dc, "f_dc")?;
        self.adam_rest.set_state(s.rest, "f_rest")
    }

    /// The scene as of the last step (geometry as given, colours updated).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The fitted scene and the report.
    pub fn finish(self) -> (Scene, FitReport) {
        (
            self.scene,
            FitReport {
                losses: self.losses,
                cached_views: self.cached_views,
                cache_bytes: self.cache_bytes,
            },
        )
    }
}

#[cfg(test)]
mod tests;
