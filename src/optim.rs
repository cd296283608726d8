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

use crate::render::backward::{ViewGrad, colour_grad_uncached, sh_backward_views};
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

/// Rows per parallel task of the pixel loops (a few thousand pixels per task at
/// typical sizes; the results do not depend on it).
const ROWS: usize = 8;
/// Pixels per chunk of the f64 loss sums: partial sums of fixed chunks, added in chunk
/// order, so the loss is the same for any thread count.
const SUM_CHUNK: usize = 1 << 14;

/// Separable 11-tap Gaussian blur of an `[h, w]` plane with zero padding (same size);
/// row `y` of the source is written by `src(y, row)`, so that products of planes need
/// no buffer of their own. The kernel is symmetric, so this operator is its own
/// transpose. Parallel over bands of rows; each output value is computed the same way
/// whatever the thread count.
fn blur_with(
    src: impl Fn(usize, &mut [f32]) + Sync,
    h: usize,
    w: usize,
    k: &[f32; WIN],
    tmp: &mut [f32],
    out: &mut [f32],
) {
    // Horizontal: each row is written into a zero-padded buffer, then accumulated tap
    // by tap over the whole row (a loop over x that vectorises).
    tmp[..h * w]
        .par_chunks_mut(w * ROWS)
        .enumerate()
        .for_each_init(
            || vec![0.0f32; w + 2 * HALF],
            |pad, (band, t)| {
                for (r, t) in t.chunks_mut(w).enumerate() {
                    src(band * ROWS + r, &mut pad[HALF..HALF + w]);
                    t.fill(0.0);
                    for (j, &kv) in k.iter().enumerate() {
                        for (a, b) in t.iter_mut().zip(&pad[j..j + w]) {
                            *a += kv * b;
                        }
                    }
                }
            },
        );
    let tmp = &tmp[..h * w];
    out[..h * w]
        .par_chunks_mut(w * ROWS)
        .enumerate()
        .for_each(|(band, o)| {
            for (r, o) in o.chunks_mut(w).enumerate() {
                let y = band * ROWS + r;
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
            }
        });
}

/// [`blur_with`] of a plane.
fn blur(src: &[f32], h: usize, w: usize, k: &[f32; WIN], tmp: &mut [f32], out: &mut [f32]) {
    blur_with(
        |y, row| row.copy_from_slice(&src[y * w..(y + 1) * w]),
        h,
        w,
        k,
        tmp,
        out,
    );
}

/// Loss weights and options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossParams {
    /// lambda of the D-SSIM term, in [0, 1].
    pub ssim_weight: f32,
}

/// The planes [`loss_and_grad_into`] works in, kept between calls so that a fit does
/// not fault in fresh memory for every view of every step.
#[derive(Debug, Default)]
pub struct LossScratch {
    /// Masked render and target, planar `[3][h w]`.
    x: Vec<f32>,
    y: Vec<f32>,
    /// dL/d(masked render), planar.
    gp: Vec<f32>,
    tmp: Vec<f32>,
    /// mu_x, mu_y, E[x^2], E[y^2], E[xy]; then the SSIM partials and their blurs.
    maps: [Vec<f32>; 6],
}

impl LossScratch {
    fn resize(&mut self, npix: usize) {
        for v in [&mut self.x, &mut self.y, &mut self.gp] {
            v.resize(3 * npix, 0.0);
        }
        self.tmp.resize(npix, 0.0);
        for m in &mut self.maps {
            m.resize(npix, 0.0);
        }
    }
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
    let mut grad = vec![0.0f32; h * w * 3];
    let loss = loss_and_grad_into(
        &mut LossScratch::default(),
        render,
        target,
        mask,
        h,
        w,
        p,
        &mut grad,
    );
    (loss, grad)
}

/// [`loss_and_grad`] with reusable planes, writing the gradient into `grad`
/// (`[h, w, 3]`, every value overwritten). Parallel over bands of pixels; the same bits
/// for any thread count.
pub fn loss_and_grad_into(
    s: &mut LossScratch,
    render: &[f32],
    target: &[f32],
    mask: Option<&[f32]>,
    h: usize,
    w: usize,
    p: LossParams,
    grad: &mut [f32],
) -> f32 {
    let npix = h * w;
    let n = (npix * 3) as f32;
    let lambda = p.ssim_weight;
    s.resize(npix);
    let m = |pix: usize| mask.map_or(1.0, |m| m[pix]);
    let l1 = masked_l1(s, render, target, &m, n, lambda);
    let mut ssim_sum = 0.0f64;
    if lambda > 0.0 {
        let k = gauss_window();
        for c in 0..3 {
            ssim_sum += ssim_channel(s, c, h, w, &k, -lambda / n);
        }
    }
    let ssim = if lambda > 0.0 {
        ssim_sum / n as f64
    } else {
        1.0
    };
    let loss = (1.0 - lambda as f64) * l1 / n as f64 + lambda as f64 * (1.0 - ssim);
    // Back to interleaved, through the mask.
    let gp = &s.gp;
    grad[..npix * 3]
        .par_chunks_mut(3 * SUM_CHUNK)
        .enumerate()
        .for_each(|(ci, out)| {
            for (j, px) in out.chunks_mut(3).enumerate() {
                let pix = ci * SUM_CHUNK + j;
                let mk = m(pix);
                for (ch, g) in px.iter_mut().enumerate() {
                    *g = mk * gp[ch * npix + pix];
                }
            }
        });
    loss as f32
}

/// The masked images, planar per channel (into `s.x` and `s.y`), and the L1 term: its
/// sum, returned, and its gradient, written into `s.gp`.
fn masked_l1(
    s: &mut LossScratch,
    render: &[f32],
    target: &[f32],
    m: &(impl Fn(usize) -> f32 + Sync),
    n: f32,
    lambda: f32,
) -> f64 {
    let npix = s.x.len() / 3;
    let [x0, x1, x2] = planes(&mut s.x, npix);
    let [y0, y1, y2] = planes(&mut s.y, npix);
    let [g0, g1, g2] = planes(&mut s.gp, npix);
    let sums: Vec<f64> = x0
        .par_chunks_mut(SUM_CHUNK)
        .zip(x1.par_chunks_mut(SUM_CHUNK))
        .zip(x2.par_chunks_mut(SUM_CHUNK))
        .zip(y0.par_chunks_mut(SUM_CHUNK))
        .zip(y1.par_chunks_mut(SUM_CHUNK))
        .zip(y2.par_chunks_mut(SUM_CHUNK))
        .zip(g0.par_chunks_mut(SUM_CHUNK))
        .zip(g1.par_chunks_mut(SUM_CHUNK))
        .zip(g2.par_chunks_mut(SUM_CHUNK))
        .enumerate()
        .map(|(c, ((((((((x0, x1), x2), y0), y1), y2), g0), g1), g2))| {
            let (xs, ys, gs) = ([x0, x1, x2], [y0, y1, y2], [g0, g1, g2]);
            let mut l1 = 0.0f64;
            let base = c * SUM_CHUNK;
            for k in 0..xs[0].len() {
                let pix = base + k;
                let mk = m(pix);
                for ch in 0..3 {
                    let i = pix * 3 + ch;
                    let (xv, yv) = (mk * render[i], mk * target[i]);
                    let d = xv - yv;
                    l1 += d.abs() as f64;
                    xs[ch][k] = xv;
                    ys[ch][k] = yv;
                    gs[ch][k] = (1.0 - lambda) * d.signum() * if d == 0.0 { 0.0 } else { 1.0 } / n;
                }
            }
            l1
        })
        .collect();
    sums.iter().sum()
}

/// The blurred product `a * b` of two `[h, w]` planes into `out`.
fn blur_product(
    a: &[f32],
    b: &[f32],
    h: usize,
    w: usize,
    k: &[f32; WIN],
    tmp: &mut [f32],
    out: &mut [f32],
) {
    blur_with(
        |y, r: &mut [f32]| {
            let (a, b) = (&a[y * w..(y + 1) * w], &b[y * w..(y + 1) * w]);
            for (o, (a, b)) in r.iter_mut().zip(a.iter().zip(b)) {
                *o = a * b;
            }
        },
        h,
        w,
        k,
        tmp,
        out,
    );
}

/// Channel `c`'s SSIM term: returns the sum of its per-pixel SSIM and adds its gradient
/// (scaled by `g` = -lambda / n) to `s.gp`'s plane `c`.
fn ssim_channel(s: &mut LossScratch, c: usize, h: usize, w: usize, k: &[f32; WIN], g: f32) -> f64 {
    let npix = h * w;
    let xs = &s.x[c * npix..(c + 1) * npix];
    let ys = &s.y[c * npix..(c + 1) * npix];
    let tmp = &mut s.tmp;
    let [mx, my, pxx, pyy, pxy, b6] = &mut s.maps;
    blur(xs, h, w, k, tmp, mx);
    blur(ys, h, w, k, tmp, my);
    blur_product(xs, xs, h, w, k, tmp, pxx);
    blur_product(ys, ys, h, w, k, tmp, pyy);
    blur_product(xs, ys, h, w, k, tmp, pxy);
    // S = A1 A2 / (B1 B2) and its partials w.r.t. mu_x, E[x^2], E[xy], written
    // over mu_x, E[x^2] and E[xy] (each is read at the same pixel first).
    let sums: Vec<f64> = mx
        .par_chunks_mut(SUM_CHUNK)
        .zip(my.par_chunks(SUM_CHUNK))
        .zip(pxx.par_chunks_mut(SUM_CHUNK))
        .zip(pyy.par_chunks(SUM_CHUNK))
        .zip(pxy.par_chunks_mut(SUM_CHUNK))
        .map(|((((mx, my), pxx), pyy), pxy)| {
            let mut s_sum = 0.0f64;
            for i in 0..mx.len() {
                let (ux, uy) = (mx[i], my[i]);
                let a1 = 2.0 * ux * uy + SSIM_C1;
                let a2 = 2.0 * (pxy[i] - ux * uy) + SSIM_C2;
                let b1 = ux * ux + uy * uy + SSIM_C1;
                let b2 = (pxx[i] - ux * ux) + (pyy[i] - uy * uy) + SSIM_C2;
                let den = b1 * b2;
                let s = a1 * a2 / den;
                s_sum += s as f64;
                mx[i] = g
                    * ((2.0 * uy * a2 - 2.0 * uy * a1) / den - s * 2.0 * ux / b1
                        + s * 2.0 * ux / b2);
                pxx[i] = g * (-s / b2);
                pxy[i] = g * (2.0 * a1 / den);
            }
            s_sum
        })
        .collect();
    // Back through the blurs (self-adjoint) and the products.
    blur(mx, h, w, k, tmp, my);
    blur(pxx, h, w, k, tmp, pyy);
    blur(pxy, h, w, k, tmp, b6);
    let (bmx, bpxx, bpxy) = (&*my, &*pyy, &*b6);
    s.gp[c * npix..(c + 1) * npix]
        .par_chunks_mut(SUM_CHUNK)
        .enumerate()
        .for_each(|(ci, gp)| {
            let o = ci * SUM_CHUNK;
            for (j, g) in gp.iter_mut().enumerate() {
                let i = o + j;
                *g += bmx[i] + 2.0 * xs[i] * bpxx[i] + ys[i] * bpxy[i];
            }
        });
    sums.iter().sum::<f64>()
}

/// The three `npix` planes of a planar `[3][npix]` buffer.
fn planes(v: &mut [f32], npix: usize) -> [&mut [f32]; 3] {
    let (a, rest) = v.split_at_mut(npix);
    let (b, c) = rest.split_at_mut(npix);
    [a, b, &mut c[..npix]]
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

impl OptimizerState {
    /// The state of a fit of `scene` that has not stepped yet (zero moments).
    pub fn zeros(scene: &Scene) -> OptimizerState {
        let z = |len: usize| AdamState {
            m: vec![0.0; len],
            v: vec![0.0; len],
            t: 0,
        };
        OptimizerState {
            dc: z(scene.len() * 3),
            rest: z(scene.len() * 3 * scene.rest_per_channel()),
        }
    }
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
        self.step_weighted(params, grad, None);
    }

    /// One update of `params` with gradient `grad`, each parameter's step scaled by the
    /// weight of its group (`weights`: one weight per `params.len() / weights.len()`
    /// consecutive parameters, a Gaussian's): weight 0 leaves the parameter's bits as
    /// they are, weight 1 (or no weights) is the plain Adam step. The moments follow the
    /// gradient either way.
    pub fn step_weighted(&mut self, params: &mut [f32], grad: &[f32], weights: Option<&[f32]>) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t);
        let bc2 = 1.0 - self.beta2.powi(self.t);
        let (b1, b2, lr, eps) = (self.beta1, self.beta2, self.lr, self.eps);
        let per = weights.map_or(1, |w| (params.len() / w.len().max(1)).max(1));
        params
            .par_iter_mut()
            .zip(grad.par_iter())
            .zip(self.m.par_iter_mut().zip(self.v.par_iter_mut()))
            .enumerate()
            .for_each(|(i, ((p, &g), (m, v)))| {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                let mh = *m / bc1;
                let vh = *v / bc2;
                let w = weights.map_or(1.0, |w| w[i / per]);
                if w == 1.0 {
                    *p -= lr * mh / (vh.sqrt() + eps);
                } else if w != 0.0 {
                    *p -= w * (lr * mh / (vh.sqrt() + eps));
                }
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

/// A view's loss inside a step: `loss(v, bufs, rgb, alpha)` reads the render from
/// `rgb`, or from `bufs.rgb` when `rgb` is `None` (cached views render into the
/// buffers), and leaves dL/drgb in `bufs.grad`.
type StepLoss<'a> =
    dyn Fn(usize, &mut ViewBufs, Option<&[f32]>, Option<&[f32]>) -> Result<f64> + Sync + 'a;
/// The same, called one view at a time.
type SeqLoss<'a> =
    dyn FnMut(usize, &mut ViewBufs, Option<&[f32]>, Option<&[f32]>) -> Result<f64> + 'a;

/// How a step calls the per-view loss: on all cores, or view after view in order (a
/// caller's hook that is not thread-safe).
enum Losses<'a, 'b> {
    Parallel(&'a StepLoss<'b>),
    InOrder(&'a mut SeqLoss<'b>),
}

/// Image buffers of one view's step: the render (cached views), dL/drgb, the loss planes.
#[derive(Debug, Default)]
struct ViewBufs {
    rgb: Vec<f32>,
    grad: Vec<f32>,
    loss: LossScratch,
}

/// A view's share of a step, until it is added into the SH gradients.
struct ViewGradOwned<'a> {
    loss: f64,
    ids: std::borrow::Cow<'a, [u32]>,
    centre: [f32; 3],
    raw: Vec<[f32; 3]>,
    grad_c: Vec<[f32; 3]>,
}

/// Buffers handed out to one task at a time and taken back, so that a fit reuses its
/// memory across views and steps (fresh multi-megabyte buffers fault in new pages every
/// time). Which buffer a view gets does not matter: every use overwrites it.
#[derive(Debug, Default)]
struct Pool<T>(std::sync::Mutex<Vec<T>>);

impl<T: Default> Pool<T> {
    fn take(&self) -> T {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default()
    }
    fn put(&self, t: T) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).push(t);
    }
}

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
    /// Per-view image buffers, reused across views and steps.
    bufs: Pool<ViewBufs>,
    losses: Vec<f32>,
    cached_views: usize,
    cache_bytes: usize,
    /// Per-Gaussian weights of the colour updates ([`crate::selection`]); None: all 1.
    weights: Option<Vec<f32>>,
}

/// Each view's state: its cache (projection and compositing order, and alpha when the
/// fit masks by it) when the cache mode allows, in view order; and the cached bytes. An
/// error when no Gaussian is visible from any camera.
fn plan_views(scene: &Scene, cameras: &[Camera], p: &FitParams) -> Result<(Vec<ViewState>, usize)> {
    let mut states = Vec::with_capacity(cameras.len());
    let mut cache_bytes = 0usize;
    let mut any_visible = false;
    // Views are projected and composited a window at a time on all cores; which
    // caches are kept is decided in view order, as before.
    let window = crate::parallel::window_for(rayon::current_num_threads());
    for win in cameras.chunks(window) {
        let caches: Vec<ViewCache> = win
            .par_iter()
            .map(|cam| ViewCache::from_frame(&project(scene, cam)))
            .collect();
        for (cam, cache) in win.iter().zip(caches) {
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
    }
    if !any_visible {
        return Err(Error::param(format!(
            "no Gaussian of the scene ({} Gaussians) is visible from any of the {} cameras",
            scene.len(),
            cameras.len()
        )));
    }
    Ok((states, cache_bytes))
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
        let (states, cache_bytes) = plan_views(scene, cameras, p)?;
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
            bufs: Pool::default(),
            losses: Vec::new(),
            cached_views,
            cache_bytes,
            weights: None,
        })
    }

    /// Scale each Gaussian's colour updates by its weight in `sel` (one per Gaussian of
    /// the scene, in [0, 1]; weight 0: the Gaussian's colours keep their bits); None:
    /// every Gaussian moves freely (the same bytes as never calling this).
    pub fn set_weights(&mut self, sel: Option<&crate::selection::Selection>) -> Result<()> {
        if let Some(s) = sel
            && s.len() != self.scene.len()
        {
            return Err(Error::param(format!(
                "selection of {} Gaussians for a scene of {}",
                s.len(),
                self.scene.len()
            )));
        }
        self.weights = sel.map(|s| s.weights.clone());
        Ok(())
    }

    /// Views whose contributions are cached, and the bytes the caches hold.
    pub fn cache_stats(&self) -> (usize, usize) {
        (self.cached_views, self.cache_bytes)
    }

    /// One Adam step over all views; returns the mean loss over views before the update.
    /// Views are processed in parallel; losses and gradients are added in view order,
    /// so the result is the same for any thread count.
    pub fn step(&mut self) -> f32 {
        let lp = LossParams {
            ssim_weight: self.params.ssim_weight,
        };
        let cameras = self.cameras;
        let targets = self
            .targets
            .expect("ColourFit::step needs the targets given to ColourFit::new");
        let loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let (h, w) = (cameras[v].height as usize, cameras[v].width as usize);
            let ViewBufs {
                loss,
                rgb: own,
                grad,
            } = b;
            let rgb = rgb.unwrap_or(own);
            grad.resize(h * w * 3, 0.0);
            Ok(loss_and_grad_into(loss, rgb, &targets[v], alpha, h, w, lp, grad) as f64)
        };
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_over(&all, Losses::Parallel(&loss))
            .expect("the L1 + D-SSIM loss cannot fail") as f32
    }

    /// The image-gradient hook (added for the VGG baselines): one Adam step over all
    /// views like [`ColourFit::step`], with the per-view loss supplied by the caller.
    /// `view_loss(v, rgb, alpha)` gets camera `v`'s render `[H, W, 3]` (and its alpha
    /// when `mask_alpha` is set) and returns the loss and dL/d(rgb); the gradient is
    /// chained through the colour backward pass. Returns the mean loss over views before
    /// the update; the targets given to [`ColourFit::new`] are not used. The hook is
    /// called view after view, in order.
    pub fn step_with(&mut self, view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_over(&all, Losses::InOrder(&mut loss))
    }

    /// One Adam step over the cameras `views` only (indices into the cameras given to
    /// [`Self::new`]): the per-view losses' gradients are summed, divided by
    /// `views.len()`, and applied once. Returns the mean loss over `views` before the
    /// update. Distillation ([`crate::distill`]) steps on a few adjacent views at a time.
    /// The hook is called view after view, in the order of `views`.
    pub fn step_views(&mut self, views: &[usize], view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        self.step_over(views, Losses::InOrder(&mut loss))
    }

    /// One step: for every view (in parallel or in order, see [`Losses`]), colours,
    /// render, the loss (which leaves dL/drgb in the buffers' `grad`), colour and SH
    /// backward; then the Adam update.
    fn step_over(&mut self, views: &[usize], losses: Losses<'_, '_>) -> Result<f64> {
        Ok(self.grad_or_step(views, losses, true)?.0)
    }

    /// The gradient of the mean loss over `views` w.r.t. the DC coefficients (`[N * 3]`,
    /// what [`Self::step_views`] hands to Adam), without changing anything: for plain
    /// gradient steps and for tests of the gradient itself.
    pub fn gradient_views(
        &mut self,
        views: &[usize],
        view_loss: &mut ViewLoss<'_>,
    ) -> Result<(f64, Vec<f32>)> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        self.grad_or_step(views, Losses::InOrder(&mut loss), false)
    }

    /// The gradient over `views`, then (with `apply`) the Adam update; returns the mean
    /// loss and the DC gradient.
    fn grad_or_step(
        &mut self,
        views: &[usize],
        mut losses: Losses<'_, '_>,
        apply: bool,
    ) -> Result<(f64, Vec<f32>)> {
        if views.is_empty() || views.iter().any(|&v| v >= self.cameras.len()) {
            return Err(Error::param(format!(
                "step_views: views {views:?} for {} cameras",
                self.cameras.len()
            )));
        }
        let nv = views.len();
        let mut grad_dc = std::mem::take(&mut self.grad_dc);
        let mut grad_rest = std::mem::take(&mut self.grad_rest);
        grad_dc.par_iter_mut().for_each(|g| *g = [0.0; 3]);
        grad_rest.par_iter_mut().for_each(|g| *g = 0.0);
        let mut loss_sum = 0.0f64;
        // A window of views at a time: their colour gradients (two floats triples per
        // visible Gaussian) are held until added, so memory stays bounded.
        let window = crate::parallel::window_for(rayon::current_num_threads()).max(8);
        let mut first_err = None;
        for chunk in views.chunks(window) {
            let outs: Vec<Result<ViewGradOwned<'_>>> = match &mut losses {
                Losses::Parallel(f) => chunk
                    .par_iter()
                    .map(|&v| self.view_grad(v, &mut |v, b, rgb, alpha| f(v, b, rgb, alpha)))
                    .collect(),
                Losses::InOrder(f) => chunk.iter().map(|&v| self.view_grad(v, &mut **f)).collect(),
            };
            let outs: Vec<ViewGradOwned<'_>> = match outs.into_iter().collect() {
                Ok(o) => o,
                Err(e) => {
                    first_err = Some(e);
                    break;
                }
            };
            for o in &outs {
                loss_sum += o.loss;
            }
            let views: Vec<ViewGrad<'_>> = outs
                .iter()
                .map(|o| ViewGrad {
                    ids: &o.ids,
                    centre: o.centre,
                    raw: &o.raw,
                    grad_c: &o.grad_c,
                })
                .collect();
            sh_backward_views(&self.scene, &views, &mut grad_dc, &mut grad_rest);
        }
        if let Some(e) = first_err {
            self.grad_dc = grad_dc;
            self.grad_rest = grad_rest;
            return Err(e);
        }
        let nvf = nv as f32;
        let gdc: Vec<f32> = grad_dc
            .par_iter()
            .flat_map_iter(|g| g.map(|x| x / nvf))
            .collect();
        grad_rest.par_iter_mut().for_each(|g| *g /= nvf);
        if !apply {
            self.grad_dc = grad_dc;
            self.grad_rest = grad_rest;
            return Ok((loss_sum / nv as f64, gdc));
        }
        let w = self.weights.as_deref();
        self.adam_dc.step_weighted(&mut self.dc, &gdc, w);
        self.adam_rest
            .step_weighted(&mut self.scene.sh_rest, &grad_rest, w);
        let dc = &self.dc;
        self.scene
            .sh_dc
            .par_iter_mut()
            .zip(dc.par_chunks(3))
            .for_each(|(c, d)| *c = [d[0], d[1], d[2]]);
        self.grad_dc = grad_dc;
        self.grad_rest = grad_rest;
        let loss = loss_sum / nv as f64;
        self.losses.push(loss as f32);
        Ok((loss, gdc))
    }

    /// Forward, loss and colour backward of view `v`.
    fn view_grad<'s>(&'s self, v: usize, loss: &mut SeqLoss<'_>) -> Result<ViewGradOwned<'s>> {
        let p = &self.params;
        let out = &self.scene;
        let cam = &self.cameras[v];
        let centre = cam.center();
        let mut b = self.bufs.take();
        let r = match &self.states[v] {
            ViewState::Cached { cache, alpha } => {
                let ids = cache.gaussians();
                let raw = raw_colours(out, ids, centre);
                b.rgb.resize(cache.width * cache.height * 3, 0.0);
                cache.forward_into(&clamp_colours(&raw), p.background, &mut b.rgb);
                let mask = p.mask_alpha.then_some(&alpha[..]);
                loss(v, &mut b, None, mask).map(|l| ViewGradOwned {
                    loss: l,
                    ids: std::borrow::Cow::Borrowed(ids),
                    centre,
                    grad_c: cache.backward(&b.grad),
                    raw,
                })
            }
            ViewState::Uncached => {
                let frame = project(out, cam);
                let raw = raw_colours(out, &frame.splats.ids, centre);
                let r = composite(&frame, &clamp_colours(&raw), p.background);
                let mask = p.mask_alpha.then_some(&r.alpha[..]);
                loss(v, &mut b, Some(&r.rgb), mask).map(|l| {
                    let grad_c = colour_grad_uncached(&frame, &b.grad);
                    ViewGradOwned {
                        loss: l,
                        ids: std::borrow::Cow::Owned(frame.splats.ids),
                        centre,
                        grad_c,
                        raw,
                    }
                })
            }
        };
        self.bufs.put(b);
        r
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
