//! The patch prior's latent space and its unconditional model.
//!
//! **Latents.** Pixels at a reduced resolution: an image in `[0, 1]` becomes
//! x = 2 img - 1, averaged over f x f blocks ([`encode`]); [`decode`] upsamples bilinearly
//! (pixel centres, edges clamped) and maps back to `[0, 1]`. Both are linear, so the image
//! change a latent step asks for is the upsampled latent change over 2.
//!
//! **Null** (the model with no condition): the moment-matched Gaussian of the pixels,
//! x ~ N(mu, S) per pixel independently (C x C covariance), whose exact denoiser is
//! E[x0 | z_t] = mu + sa S (sa^2 S + sb^2 I)^-1 (z_t - sa mu).

use crate::{Error, Result};
use ndarray::{Array2, Array3, Array4, ArrayView3, ArrayView4, Axis};

/// `images` `[B, 3, H, W]` in `[0, 1]` to latents `[B, 3, H/f, W/f]` (2 img - 1, f x f
/// block means).
pub fn encode(images: ArrayView4<'_, f32>, f: usize) -> Result<Array4<f32>> {
    let (_, _, h, w) = images.dim();
    if f == 0 || h % f != 0 || w % f != 0 {
        return Err(Error::param(format!(
            "patch prior: images of {w}x{h} do not divide by the downsampling {f}"
        )));
    }
    let mut z = pool(images, f);
    z.mapv_inplace(|v| 2.0 * v - 1.0);
    Ok(z)
}

/// Latents `[B, C, h, w]` to images `[B, C, f h, f w]` (bilinear, then (x + 1) / 2).
pub fn decode(latents: ArrayView4<'_, f32>, f: usize) -> Array4<f32> {
    let mut up = upsample(latents, f);
    up.mapv_inplace(|v| 0.5 * v + 0.5);
    up
}

/// Bilinear upsampling `[B, C, h, w]` -> `[B, C, f h, f w]` (pixel centres, edges
/// clamped): the transpose-free inverse of [`pool`] on smooth images.
pub fn upsample(x: ArrayView4<'_, f32>, f: usize) -> Array4<f32> {
    let (b, c, h, w) = x.dim();
    let (hh, ww) = (h * f, w * f);
    let (ty, tx) = (upsample_taps(h, f), upsample_taps(w, f));
    Array4::from_shape_fn((b, c, hh, ww), |(n, ch, y, x0)| {
        bilinear(|yy, xx| x[[n, ch, yy, xx]], ty[y], tx[x0])
    })
}

/// [`upsample`]'s taps along an axis of `n` pixels upsampled by `f`: for each of the `n f`
/// output pixels, the two source pixels and the second's weight (the source coordinate of
/// output pixel i is (i + 0.5) / f - 0.5, clamped to the grid).
pub fn upsample_taps(n: usize, f: usize) -> Vec<(usize, usize, f32)> {
    (0..n * f)
        .map(|i| {
            let s = ((i as f32 + 0.5) / f as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            let i0 = s.floor() as usize;
            let i1 = (i0 + 1).min(n - 1);
            (i0, i1, s - i0 as f32)
        })
        .collect()
}

/// [`upsample`]'s value at one output pixel from its taps along y and x ([`upsample_taps`]),
/// `z(y, x)` the source.
#[inline(always)]
pub fn bilinear(
    z: impl Fn(usize, usize) -> f32,
    (y0, y1, fy): (usize, usize, f32),
    (x0, x1, fx): (usize, usize, f32),
) -> f32 {
    let top = z(y0, x0) * (1.0 - fx) + z(y0, x1) * fx;
    let bottom = z(y1, x0) * (1.0 - fx) + z(y1, x1) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// f x f block means `[B, C, h, w]` -> `[B, C, h/f, w/f]` (h, w multiples of f).
pub fn pool(x: ArrayView4<'_, f32>, f: usize) -> Array4<f32> {
    let (b, c, h, w) = x.dim();
    let inv = 1.0 / (f * f) as f32;
    Array4::from_shape_fn((b, c, h / f, w / f), |(n, ch, y, xx)| {
        let mut s = 0.0f32;
        for dy in 0..f {
            for dx in 0..f {
                s += x[[n, ch, y * f + dy, xx * f + dx]];
            }
        }
        s * inv
    })
}

/// A Gaussian over pixels: mean `[C]`, covariance `[C, C]`.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelGaussian {
    pub mean: Vec<f64>,
    pub cov: Vec<f64>,
}

impl PixelGaussian {
    /// Moments of the pixels of `images` (each `[C, h, w]`), pooled.
    pub fn of(images: &[ArrayView3<'_, f32>]) -> PixelGaussian {
        let c = images.first().map_or(3, |i| i.dim().0);
        let mut n = 0.0f64;
        let mut sum = vec![0.0f64; c];
        let mut sq = vec![0.0f64; c * c];
        for img in images {
            for px in img.view().permuted_axes([1, 2, 0]).rows() {
                n += 1.0;
                for a in 0..c {
                    sum[a] += px[a] as f64;
                    for b in 0..c {
                        sq[a * c + b] += px[a] as f64 * px[b] as f64;
                    }
                }
            }
        }
        let n = n.max(1.0);
        let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
        let cov = (0..c * c)
            .map(|k| sq[k] / n - mean[k / c] * mean[k % c])
            .collect();
        PixelGaussian { mean, cov }
    }

    /// The exact denoiser's x0 `[B, C, h, w]` for `z_t` at noise level (sa, sb).
    pub fn denoise(&self, z: ArrayView4<'_, f32>, sa: f64, sb: f64) -> Array4<f32> {
        let c = self.mean.len();
        // A = sa S (sa^2 S + sb^2 I)^-1.
        let mut m = Array2::<f64>::from_shape_fn((c, c), |(a, b)| sa * sa * self.cov[a * c + b]);
        for a in 0..c {
            m[[a, a]] += sb * sb;
        }
        let inv = invert(&m);
        let s = Array2::from_shape_fn((c, c), |(a, b)| sa * self.cov[a * c + b]);
        let a = s.dot(&inv);
        let mut out = z.to_owned();
        for mut px in out.view_mut().permuted_axes([0, 2, 3, 1]).rows_mut() {
            let d: Vec<f64> = (0..c).map(|k| px[k] as f64 - sa * self.mean[k]).collect();
            for k in 0..c {
                let v: f64 = (0..c).map(|l| a[[k, l]] * d[l]).sum();
                px[k] = (self.mean[k] + v) as f32;
            }
        }
        out
    }
}

/// Inverse of a small symmetric positive-definite matrix (Gauss-Jordan, f64).
fn invert(m: &Array2<f64>) -> Array2<f64> {
    let n = m.nrows();
    let mut a = m.clone();
    let mut inv = Array2::<f64>::eye(n);
    for col in 0..n {
        let p = (col..n)
            .max_by(|&i, &j| a[[i, col]].abs().total_cmp(&a[[j, col]].abs()))
            .expect("non-empty");
        for k in 0..n {
            a.swap([col, k], [p, k]);
            inv.swap([col, k], [p, k]);
        }
        let d = a[[col, col]];
        for k in 0..n {
            a[[col, k]] /= d;
            inv[[col, k]] /= d;
        }
        for r in (0..n).filter(|&r| r != col) {
            let f = a[[r, col]];
            for k in 0..n {
                a[[r, k]] -= f * a[[col, k]];
                inv[[r, k]] -= f * inv[[col, k]];
            }
        }
    }
    inv
}

/// One image `[C, h, w]` of a batch.
pub fn image(batch: &Array4<f32>, b: usize) -> Array3<f32> {
    batch.index_axis(Axis(0), b).to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn decode_inverts_encode_on_block_constant_images() {
        let mut r = Rng::new(1);
        let z = Array4::from_shape_vec((2, 3, 4, 5), r.normals_f32(120)).unwrap();
        let img = decode(z.view(), 1);
        let back = encode(img.view(), 1).unwrap();
        assert!((&back - &z).mapv(f32::abs).sum() < 1e-4);
        // f = 2: a constant latent decodes to a constant image and encodes back.
        let c = Array4::from_elem((1, 3, 3, 3), 0.25f32);
        let up = decode(c.view(), 2);
        assert_eq!(up.dim(), (1, 3, 6, 6));
        assert!(up.iter().all(|v| (v - 0.625).abs() < 1e-6));
        assert!(
            encode(up.view(), 2)
                .unwrap()
                .iter()
                .all(|v| (v - 0.25).abs() < 1e-6)
        );
        assert!(encode(up.view(), 4).is_err());
    }

    #[test]
    fn the_gaussian_denoiser_is_the_posterior_mean() {
        // Monte Carlo: E[x0 | z] regressed on z from samples matches the closed form.
        let g = PixelGaussian {
            mean: vec![0.2, -0.1, 0.0],
            cov: vec![0.5, 0.1, 0.0, 0.1, 0.3, 0.05, 0.0, 0.05, 0.2],
        };
        let (sa, sb) = (0.6f64, 0.8f64);
        // At z = sa mu the posterior mean is mu.
        let z = Array4::from_shape_fn((1, 3, 1, 1), |(_, c, _, _)| (sa * g.mean[c]) as f32);
        let x = g.denoise(z.view(), sa, sb);
        for c in 0..3 {
            assert!((x[[0, c, 0, 0]] as f64 - g.mean[c]).abs() < 1e-6);
        }
        // Linear in z with slope sa S (sa^2 S + sb^2)^-1: for a diagonal S, per channel.
        let d = PixelGaussian {
            mean: vec![0.0; 3],
            cov: vec![0.5, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.2],
        };
        let z = Array4::from_elem((1, 3, 1, 1), 1.0f32);
        let x = d.denoise(z.view(), sa, sb);
        for (c, v) in [0.5f64, 0.3, 0.2].iter().enumerate() {
            let want = sa * v / (sa * sa * v + sb * sb);
            assert!((x[[0, c, 0, 0]] as f64 - want).abs() < 1e-6);
        }
    }
}
