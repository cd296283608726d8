//! The image loss of a colour fit and its exact gradient w.r.t. the rendered image.
//!
//! Loss (Kerbl et al. 2023, Eq. 7): `L = (1 - lambda) L1 + lambda (1 - SSIM)`, lambda =
//! 0.2, with SSIM as in the 3DGS code: 11x11 Gaussian window, sigma 1.5, zero "same"
//! padding, `C1 = 0.01^2`, `C2 = 0.03^2`, averaged over pixels and channels (Wang et al.
//! 2004). The optional alpha mask multiplies both the render and the target by the
//! rendered alpha (constant, geometry is frozen) before the loss, so uncovered pixels
//! carry no loss. [`loss_and_grad`] returns the loss and its exact gradient w.r.t. the
//! rendered image.

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

/// The mean squared error of `rgb` against `target` over every value, and its gradient
/// `2 (rgb - target) / n` (the patch synthesis's loss; [`crate::render::ViewCache::l2_backward`]
/// fuses it into the cached views' forward and backward).
pub fn l2(rgb: &[f32], target: &[f32]) -> (f64, Vec<f32>) {
    let n = rgb.len().max(1) as f32;
    let grad: Vec<f32> = rgb
        .iter()
        .zip(target)
        .map(|(a, b)| 2.0 * (a - b) / n)
        .collect();
    let loss = rgb
        .iter()
        .zip(target)
        .map(|(a, b)| ((a - b) * (a - b)) as f64)
        .sum::<f64>()
        / n as f64;
    (loss, grad)
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
