//! Multi-view frequency consistency (MVFC, FantasyStyle Sec. 4, the method).
//!
//! The noisy target latents z_t of N adjacent views, `[N, C, h, w]`, are filtered per
//! channel in the 3D frequency domain over (view, height, width): every high frequency
//! of z_t is kept, the low frequencies are replaced by a mix of z_t's and those of a
//! noise eps' shared by every view (the same `[C, h, w]` noise broadcast over views):
//!
//! ```text
//! F = FFT3(z_t),  G = FFT3(eps')
//! z_t' = Re IFFT3( H * F + L * (gamma F + (1 - gamma) G) ),   H = 1 - L
//! ```
//!
//! **The mask** follows FreeInit (Wu et al. 2023, `gaussian_low_pass_filter`): on the
//! centred frequency grid, with normalised distances d_v = 2 k_v / N, d_y = 2 k_y / h,
//! d_x = 2 k_x / w (k the signed frequency index, so d in [-1, 1)), and the view and
//! spatial cut-offs `d_t`, `d_s`:
//!
//! ```text
//! L(k) = exp( -d_v^2 / (2 d_t^2) - (d_y^2 + d_x^2) / (2 d_s^2) )
//! ```
//!
//! FreeInit writes this as `exp(-1/(2 d_s^2) * ((d_s/d_t)^2 (2t/T-1)^2 + (2h/H-1)^2 +
//! (2w/W-1)^2))` over fftshift-ed indices t, h, w; for even sizes the two are the same
//! numbers. We index by signed frequency instead, which (a) keeps the mask symmetric about
//! DC for odd sizes (FreeInit's `2t/T - 1` is off-centre there, so its mask is not
//! Hermitian and the real part silently symmetrises it) and (b) gives a single view
//! (N = 1) d_v = 0 rather than FreeInit's d_v = -1. The mask is separable, L = L_v L_y L_x,
//! so we store three 1D factors.
//!
//! Extremes: a cut-off of 0 is taken as its limit (the factor is 1 at frequency 0 and 0
//! elsewhere: only the mean along that axis is "low"); a cut-off of +inf gives a factor
//! of 1 (everything is low). FreeInit returns an all-zero mask for a zero cut-off, which
//! is not the limit. Large finite cut-offs underflow smoothly; no NaN can arise.
//!
//! **Defaults**: gamma = 0.9 (paper), d_s = d_t = 0.25 (FreeInit's defaults; with
//! 4-8 views, d_t = 0.25 keeps the view-mean and, weakly, the first view harmonic low).
//!
//! **Computation.** By linearity, `z_t' = z_t + (1 - gamma) Re IFFT3(L * FFT3(eps' - z_t))`,
//! so one forward and one inverse complex FFT per channel suffice, and gamma = 1 is
//! exactly the identity. The transforms use rustfft plans made once per shape
//! ([`MvfcFilter::new`]) and run in f32, parallel over channels and lines (rayon).

use crate::{Error, Result};
use ndarray::{Array4, ArrayView3, ArrayView4};
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// MVFC parameters: the `[mvfc]` section of the method's configuration
/// ([`crate::config`]; the field docs are its help), read by `distill` and
/// `mvfc-filter`. [`mvfc_path`] uses the filter's three numbers; `enabled` and `source`
/// say where the loop applies it.
#[derive(Debug, Clone, Copy, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MvfcParams {
    /// Filter the noisy latents with MVFC (false: the paper's "without MVFC" ablation).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub enabled: bool,
    /// Filter the source branch too, with the same eps' (false: the target only, as in
    /// the paper, which moves the scene even when the style is its own look: MVFC scales
    /// the low band of the signal by gamma, a bias the CSD difference does not cancel
    /// unless both branches are filtered).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub source: bool,
    /// Weight of the target's own low frequencies (paper: 0.9; 1 = no change, 0 = shared
    /// noise only).
    #[arg(long, default_value_t = 0.9)]
    pub gamma: f32,
    /// Spatial cut-off d_s of the Gaussian low-pass mask (normalised frequency, FreeInit
    /// convention; >= 0, `inf` allowed).
    #[arg(long = "ds", default_value_t = 0.25)]
    pub d_s: f32,
    /// View cut-off d_t of the Gaussian low-pass mask (normalised frequency; >= 0, `inf`
    /// allowed).
    #[arg(long = "dt", default_value_t = 0.25)]
    pub d_t: f32,
}

impl Default for MvfcParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl MvfcParams {
    /// Refuse NaN, negative cut-offs and gamma outside [0, 1].
    pub fn validate(&self) -> Result<()> {
        if !(0.0..=1.0).contains(&self.gamma) {
            return Err(Error::param(format!(
                "MVFC gamma must be in [0, 1], got {}",
                self.gamma
            )));
        }
        for (name, v) in [("d_s", self.d_s), ("d_t", self.d_t)] {
            if v.is_nan() || v < 0.0 {
                return Err(Error::param(format!(
                    "MVFC cut-off {name} must be >= 0 (or inf), got {v}"
                )));
            }
        }
        Ok(())
    }
}

/// One axis' factor of the Gaussian low-pass mask, indexed by unshifted FFT bin.
pub fn mask_factor(len: usize, cutoff: f32) -> Vec<f32> {
    (0..len)
        .map(|k| {
            // Signed frequency index (numpy.fft.fftfreq order), then d = 2 f / len.
            let f = if k < len.div_ceil(2) {
                k as f64
            } else {
                k as f64 - len as f64
            };
            let d = 2.0 * f / len as f64;
            if cutoff.is_infinite() {
                1.0
            } else if cutoff <= 0.0 {
                if f == 0.0 { 1.0 } else { 0.0 }
            } else {
                let c = cutoff as f64;
                (-d * d / (2.0 * c * c)).exp() as f32
            }
        })
        .collect()
}

/// A planned MVFC filter for one latent shape `[N, C, h, w]`: FFT plans and mask made
/// once, reused for every call.
pub struct MvfcFilter {
    shape: [usize; 4],
    params: MvfcParams,
    fwd: [Arc<dyn Fft<f32>>; 3],
    inv: [Arc<dyn Fft<f32>>; 3],
    /// Mask factors along view, height, width.
    mask: [Vec<f32>; 3],
}

impl std::fmt::Debug for MvfcFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MvfcFilter")
            .field("shape", &self.shape)
            .field("params", &self.params)
            .finish()
    }
}

impl MvfcFilter {
    /// Plan the filter for latents of `shape` = [N, C, h, w].
    pub fn new(shape: [usize; 4], params: MvfcParams) -> Result<Self> {
        params.validate()?;
        if shape.contains(&0) {
            return Err(Error::param(format!(
                "MVFC needs non-empty latents, got shape {shape:?}"
            )));
        }
        let [n, _, h, w] = shape;
        let mut planner = FftPlanner::<f32>::new();
        let fwd = [
            planner.plan_fft_forward(n),
            planner.plan_fft_forward(h),
            planner.plan_fft_forward(w),
        ];
        let inv = [
            planner.plan_fft_inverse(n),
            planner.plan_fft_inverse(h),
            planner.plan_fft_inverse(w),
        ];
        let mask = [
            mask_factor(n, params.d_t),
            mask_factor(h, params.d_s),
            mask_factor(w, params.d_s),
        ];
        Ok(MvfcFilter {
            shape,
            params,
            fwd,
            inv,
            mask,
        })
    }

    pub fn shape(&self) -> [usize; 4] {
        self.shape
    }

    pub fn params(&self) -> MvfcParams {
        self.params
    }

    /// The full low-pass mask L as `[N, h, w]` (for inspection and tests).
    pub fn low_pass_mask(&self) -> ndarray::Array3<f32> {
        let [n, _, h, w] = self.shape;
        ndarray::Array3::from_shape_fn((n, h, w), |(a, b, c)| {
            self.mask[0][a] * self.mask[1][b] * self.mask[2][c]
        })
    }

    /// Filter noisy target latents `z_t` [N, C, h, w] with the shared noise `eps_shared`
    /// [C, h, w]. Inputs must be finite (checked).
    pub fn apply(
        &self,
        z_t: ArrayView4<'_, f32>,
        eps_shared: ArrayView3<'_, f32>,
    ) -> Result<Array4<f32>> {
        let [n, c, h, w] = self.shape;
        if z_t.shape() != [n, c, h, w] {
            return Err(Error::param(format!(
                "MVFC planned for latents {:?}, got {:?}",
                self.shape,
                z_t.shape()
            )));
        }
        if eps_shared.shape() != [c, h, w] {
            return Err(Error::param(format!(
                "MVFC shared noise must be [C, h, w] = {:?}, got {:?}",
                [c, h, w],
                eps_shared.shape()
            )));
        }
        if z_t.iter().chain(eps_shared.iter()).any(|v| !v.is_finite()) {
            return Err(Error::param("MVFC input holds NaN or infinity"));
        }
        let scale = 1.0 - self.params.gamma;
        let mut out = z_t.to_owned();
        if scale == 0.0 {
            return Ok(out);
        }
        let plane = h * w;
        // Per channel: buf[v][y][x] = eps'[c] - z_t[v, c]; low-pass it in 3D.
        let lows: Vec<Vec<f32>> = (0..c)
            .into_par_iter()
            .map(|ch| {
                let mut buf = vec![Complex32::default(); n * plane];
                for v in 0..n {
                    let dst = &mut buf[v * plane..(v + 1) * plane];
                    for ((d, &e), &z) in dst
                        .iter_mut()
                        .zip(eps_shared.index_axis(ndarray::Axis(0), ch).iter())
                        .zip(z_t.slice(ndarray::s![v, ch, .., ..]).iter())
                    {
                        *d = Complex32::new(e - z, 0.0);
                    }
                }
                self.low_pass_in_place(&mut buf);
                buf.iter().map(|v| v.re).collect()
            })
            .collect();
        for (ch, low) in lows.iter().enumerate() {
            for v in 0..n {
                let mut dst = out.slice_mut(ndarray::s![v, ch, .., ..]);
                for (d, &l) in dst.iter_mut().zip(&low[v * plane..(v + 1) * plane]) {
                    *d += scale * l;
                }
            }
        }
        Ok(out)
    }

    /// IFFT3(L * FFT3(buf)) in place for one channel laid out [N][h][w]. Normalised.
    ///
    /// x and y are transformed plane by plane (rows of x; planes transposed to [x][y]
    /// for rows of y, which fit in cache). The view axis is strided by a whole plane, so
    /// instead of transposing the channel it is done in blocks of plane positions:
    /// gather `[block][N]`, FFT, mask, inverse FFT, scatter back.
    fn low_pass_in_place(&self, buf: &mut [Complex32]) {
        let [n, _, h, w] = self.shape;
        let plane = h * w;
        let mut tmp = vec![Complex32::default(); buf.len()];
        rows(&*self.fwd[2], buf, w);
        for v in 0..n {
            let r = v * plane..(v + 1) * plane;
            transpose(&buf[r.clone()], &mut tmp[r], h, w);
        }
        // tmp: [N][x][y]
        rows(&*self.fwd[1], &mut tmp, h);
        self.view_axis_masked(&mut tmp);
        rows(&*self.inv[1], &mut tmp, h);
        for v in 0..n {
            let r = v * plane..(v + 1) * plane;
            transpose(&tmp[r.clone()], &mut buf[r], w, h);
        }
        rows(&*self.inv[2], buf, w);
    }

    /// On `data` laid out [N][x][y] (already transformed along x and y): FFT along N,
    /// multiply by the mask and the 1/(N h w) normalisation, inverse FFT along N.
    fn view_axis_masked(&self, data: &mut [Complex32]) {
        let [n, _, h, w] = self.shape;
        let plane = h * w;
        let (mv, my, mx) = (&self.mask[0], &self.mask[1], &self.mask[2]);
        let norm = 1.0 / (n * plane) as f32;
        const B: usize = 64;
        let mut block = vec![Complex32::default(); B * n];
        let mut scratch = vec![
            Complex32::default();
            self.fwd[0]
                .get_inplace_scratch_len()
                .max(self.inv[0].get_inplace_scratch_len())
        ];
        for p0 in (0..plane).step_by(B) {
            let b = B.min(plane - p0);
            let blk = &mut block[..b * n];
            for v in 0..n {
                for (k, val) in data[v * plane + p0..v * plane + p0 + b].iter().enumerate() {
                    blk[k * n + v] = *val;
                }
            }
            if n > 1 {
                self.fwd[0].process_with_scratch(blk, &mut scratch);
            }
            for (k, line) in blk.chunks_mut(n).enumerate() {
                let p = p0 + k;
                let m = mx[p / h] * my[p % h] * norm;
                for (v, val) in line.iter_mut().enumerate() {
                    *val *= m * mv[v];
                }
            }
            if n > 1 {
                self.inv[0].process_with_scratch(blk, &mut scratch);
            }
            for v in 0..n {
                for (k, val) in data[v * plane + p0..v * plane + p0 + b]
                    .iter_mut()
                    .enumerate()
                {
                    *val = blk[k * n + v];
                }
            }
        }
    }
}

/// FFT every contiguous row of length `len` of `data`, in parallel blocks.
fn rows(fft: &dyn Fft<f32>, data: &mut [Complex32], len: usize) {
    if len == 1 {
        return;
    }
    // Blocks of whole rows, large enough to amortise scheduling.
    let rows_per_block = (16384 / len).max(1);
    data.par_chunks_mut(rows_per_block * len).for_each(|block| {
        let mut scratch = vec![Complex32::default(); fft.get_inplace_scratch_len()];
        fft.process_with_scratch(block, &mut scratch);
    });
}

/// `dst[j][i] = src[i][j]` for a row-major `src` of `r` rows and `c` columns.
fn transpose(src: &[Complex32], dst: &mut [Complex32], r: usize, c: usize) {
    const B: usize = 32;
    for i0 in (0..r).step_by(B) {
        for j0 in (0..c).step_by(B) {
            for i in i0..(i0 + B).min(r) {
                for j in j0..(j0 + B).min(c) {
                    dst[j * r + i] = src[i * c + j];
                }
            }
        }
    }
}

/// One-shot convenience: plan and apply.
pub fn mvfc(
    z_t: ArrayView4<'_, f32>,
    eps_shared: ArrayView3<'_, f32>,
    params: MvfcParams,
) -> Result<Array4<f32>> {
    let s = z_t.shape();
    MvfcFilter::new([s[0], s[1], s[2], s[3]], params)?.apply(z_t, eps_shared)
}

/// MVFC of the N adjacent views of one iteration taken along a camera path. When the
/// views' ends are neighbours (`circular`: the whole of a closed path) the view axis of
/// the 3D FFT is circular, as [`mvfc`] has it. Otherwise the FFT's wrap-around would
/// make the last view a neighbour of the first, so the view axis is extended by its
/// mirror image (v0 .. v_{N-1}, v_{N-2} .. v1, an even extension as in a DCT) before
/// filtering and cut back to the N views after: each view's low frequencies are then
/// blended with those of its path neighbours only.
pub fn mvfc_path(
    z_t: ArrayView4<'_, f32>,
    eps_shared: ArrayView3<'_, f32>,
    params: MvfcParams,
    circular: bool,
) -> Result<Array4<f32>> {
    let n = z_t.shape()[0];
    if circular || n <= 2 {
        // Two views are each other's only neighbour either way.
        return mvfc(z_t, eps_shared, params);
    }
    let order: Vec<usize> = (0..n).chain((1..n - 1).rev()).collect();
    let ext = z_t.select(ndarray::Axis(0), &order);
    let out = mvfc(ext.view(), eps_shared, params)?;
    Ok(out.slice(ndarray::s![..n, .., .., ..]).to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use ndarray::{Array3, Array4};

    fn randn4(seed: u64, s: [usize; 4]) -> Array4<f32> {
        let n = s.iter().product();
        Array4::from_shape_vec(s, Rng::new(seed).normals_f32(n)).unwrap()
    }
    fn randn3(seed: u64, s: [usize; 3]) -> Array3<f32> {
        let n = s.iter().product();
        Array3::from_shape_vec(s, Rng::new(seed).normals_f32(n)).unwrap()
    }
    fn max_abs_diff(a: &Array4<f32>, b: &Array4<f32>) -> f32 {
        a.iter()
            .zip(b.iter())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    /// On an open path the first and last views do not exchange low frequencies (the
    /// circular filter couples them as neighbours); a circular window equals [`mvfc`].
    #[test]
    fn open_paths_do_not_couple_their_ends() {
        let p = MvfcParams {
            gamma: 0.0,
            ..MvfcParams::default()
        };
        let (n, s) = (6, [6, 1, 4, 4]);
        let e = randn3(5, [1, 4, 4]);
        let z = randn4(6, s);
        // Influence of a change of the last view on the first view.
        let mut z2 = z.clone();
        z2.slice_mut(ndarray::s![n - 1, .., .., ..])
            .mapv_inplace(|v| v + 3.0);
        let influence = |circular: bool| {
            let a = mvfc_path(z.view(), e.view(), p, circular).unwrap();
            let b = mvfc_path(z2.view(), e.view(), p, circular).unwrap();
            let d = &a.slice(ndarray::s![0, .., .., ..]) - &b.slice(ndarray::s![0, .., .., ..]);
            d.iter().map(|v| v.abs()).fold(0.0f32, f32::max)
        };
        let (open, circ) = (influence(false), influence(true));
        // Its neighbour (view 1) feels it in both cases; the far end only when circular.
        assert!(circ > 0.05, "circular coupling {circ}");
        assert!(open < 0.2 * circ, "open {open} vs circular {circ}");
        assert_eq!(
            mvfc_path(z.view(), e.view(), p, true).unwrap(),
            mvfc(z.view(), e.view(), p).unwrap()
        );
    }

    /// Direct O(M^2) reference of the formula: DFT3 by definition in f64.
    fn direct(z: &Array4<f32>, e: &Array3<f32>, p: MvfcParams) -> Array4<f32> {
        let [n, c, h, w] = [z.shape()[0], z.shape()[1], z.shape()[2], z.shape()[3]];
        let (mv, my, mx) = (
            mask_factor(n, p.d_t),
            mask_factor(h, p.d_s),
            mask_factor(w, p.d_s),
        );
        let tau = std::f64::consts::TAU;
        let mut out = Array4::<f32>::zeros((n, c, h, w));
        for ch in 0..c {
            // spectrum of z and of eps (broadcast over views)
            let mut fz = vec![(0.0f64, 0.0f64); n * h * w];
            let mut fe = vec![(0.0f64, 0.0f64); n * h * w];
            for kv in 0..n {
                for ky in 0..h {
                    for kx in 0..w {
                        let (mut a, mut b) = ((0.0, 0.0), (0.0, 0.0));
                        for v in 0..n {
                            for y in 0..h {
                                for x in 0..w {
                                    let ph = -tau
                                        * ((kv * v) as f64 / n as f64
                                            + (ky * y) as f64 / h as f64
                                            + (kx * x) as f64 / w as f64);
                                    let (s, co) = ph.sin_cos();
                                    let zv = z[[v, ch, y, x]] as f64;
                                    let ev = e[[ch, y, x]] as f64;
                                    a.0 += zv * co;
                                    a.1 += zv * s;
                                    b.0 += ev * co;
                                    b.1 += ev * s;
                                }
                            }
                        }
                        let i = (kv * h + ky) * w + kx;
                        fz[i] = a;
                        fe[i] = b;
                    }
                }
            }
            for v in 0..n {
                for y in 0..h {
                    for x in 0..w {
                        let mut acc = 0.0;
                        for kv in 0..n {
                            for ky in 0..h {
                                for kx in 0..w {
                                    let i = (kv * h + ky) * w + kx;
                                    let l = (mv[kv] * my[ky] * mx[kx]) as f64;
                                    let g = p.gamma as f64;
                                    let re = (1.0 - l) * fz[i].0
                                        + l * (g * fz[i].0 + (1.0 - g) * fe[i].0);
                                    let im = (1.0 - l) * fz[i].1
                                        + l * (g * fz[i].1 + (1.0 - g) * fe[i].1);
                                    let ph = tau
                                        * ((kv * v) as f64 / n as f64
                                            + (ky * y) as f64 / h as f64
                                            + (kx * x) as f64 / w as f64);
                                    acc += re * ph.cos() - im * ph.sin();
                                }
                            }
                        }
                        out[[v, ch, y, x]] = (acc / (n * h * w) as f64) as f32;
                    }
                }
            }
        }
        out
    }

    #[test]
    fn gamma_one_is_identity() {
        let z = randn4(1, [4, 4, 8, 8]);
        let e = randn3(2, [4, 8, 8]);
        let p = MvfcParams {
            gamma: 1.0,
            ..Default::default()
        };
        let out = mvfc(z.view(), e.view(), p).unwrap();
        assert!(max_abs_diff(&out, &z) <= 1e-6);
    }

    #[test]
    fn all_low_and_gamma_zero_gives_the_shared_noise() {
        // L = 1 everywhere, gamma = 0: output is eps' in every view (FFT round trip).
        let z = randn4(3, [5, 2, 7, 6]);
        let e = randn3(4, [2, 7, 6]);
        let p = MvfcParams {
            gamma: 0.0,
            d_s: f32::INFINITY,
            d_t: f32::INFINITY,
            ..Default::default()
        };
        let out = mvfc(z.view(), e.view(), p).unwrap();
        let want = Array4::from_shape_fn((5, 2, 7, 6), |(_, c, y, x)| e[[c, y, x]]);
        let err = max_abs_diff(&out, &want);
        assert!(err < 2e-6, "{err}");
    }

    #[test]
    fn matches_direct_dft_on_odd_sizes_and_single_view() {
        for (shape, seed) in [
            ([3, 2, 5, 7], 10u64),
            ([1, 3, 6, 5], 11),
            ([4, 1, 4, 4], 12),
        ] {
            let z = randn4(seed, shape);
            let e = randn3(seed + 100, [shape[1], shape[2], shape[3]]);
            let p = MvfcParams {
                gamma: 0.3,
                d_s: 0.4,
                d_t: 0.6,
                ..Default::default()
            };
            let out = mvfc(z.view(), e.view(), p).unwrap();
            let want = direct(&z, &e, p);
            let err = max_abs_diff(&out, &want);
            assert!(err < 2e-5, "shape {shape:?}: {err}");
        }
    }

    #[test]
    fn single_view_mask_has_no_view_attenuation() {
        let f = MvfcFilter::new([1, 1, 4, 4], MvfcParams::default()).unwrap();
        let m = f.low_pass_mask();
        assert_eq!(m[[0, 0, 0]], 1.0);
        // Symmetric about DC for odd sizes.
        let m5 = mask_factor(5, 0.3);
        assert_eq!(m5[1], m5[4]);
        assert_eq!(m5[2], m5[3]);
    }

    #[test]
    fn extreme_cutoffs_are_finite_and_take_their_limits() {
        let z = randn4(20, [3, 2, 5, 4]);
        let e = randn3(21, [2, 5, 4]);
        for (ds, dt) in [
            (0.0, 0.0),
            (0.0, 1e30),
            (1e-30, 0.25),
            (1e30, 1e30),
            (f32::INFINITY, 0.0),
            (f32::MAX, f32::MIN_POSITIVE),
        ] {
            let p = MvfcParams {
                gamma: 0.5,
                d_s: ds,
                d_t: dt,
                ..Default::default()
            };
            let out = mvfc(z.view(), e.view(), p).unwrap();
            assert!(out.iter().all(|v| v.is_finite()), "d_s {ds} d_t {dt}");
        }
        // d -> 0 on every axis: only the global mean (DC) is mixed.
        let p = MvfcParams {
            gamma: 0.0,
            d_s: 0.0,
            d_t: 0.0,
            ..Default::default()
        };
        let out = mvfc(z.view(), e.view(), p).unwrap();
        for ch in 0..2 {
            let zc: ndarray::ArrayView3<f32> = z.slice(ndarray::s![.., ch, .., ..]);
            let oc: ndarray::ArrayView3<f32> = out.slice(ndarray::s![.., ch, .., ..]);
            let ec = e.slice(ndarray::s![ch, .., ..]);
            // mean replaced by eps' mean; deviations from the mean kept
            assert!((oc.mean().unwrap() - ec.mean().unwrap()).abs() < 1e-5);
            let d0 = zc[[1usize, 2, 3]] - zc.mean().unwrap();
            let d1 = oc[[1usize, 2, 3]] - oc.mean().unwrap();
            assert!((d0 - d1).abs() < 1e-5);
        }
    }

    #[test]
    fn bad_parameters_and_inputs_are_refused() {
        assert!(
            MvfcFilter::new(
                [2, 1, 4, 4],
                MvfcParams {
                    gamma: 1.5,
                    ..Default::default()
                }
            )
            .is_err()
        );
        assert!(
            MvfcFilter::new(
                [2, 1, 4, 4],
                MvfcParams {
                    d_s: f32::NAN,
                    ..Default::default()
                }
            )
            .is_err()
        );
        assert!(
            MvfcFilter::new(
                [2, 1, 4, 4],
                MvfcParams {
                    d_t: -1.0,
                    ..Default::default()
                }
            )
            .is_err()
        );
        assert!(MvfcFilter::new([0, 1, 4, 4], MvfcParams::default()).is_err());
        let f = MvfcFilter::new([2, 1, 4, 4], MvfcParams::default()).unwrap();
        let mut z = randn4(1, [2, 1, 4, 4]);
        let e = randn3(2, [1, 4, 4]);
        assert!(f.apply(z.view(), randn3(2, [1, 4, 5]).view()).is_err());
        z[[0, 0, 1, 1]] = f32::NAN;
        let err = f.apply(z.view(), e.view()).unwrap_err().to_string();
        assert!(err.contains("NaN"), "{err}");
    }
}
