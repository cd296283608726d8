//! The separable Gaussian blur of a plane, one for the crate: the synthesis's guide,
//! detail layer and consensus ([`crate::ends::patches`]), the metrics' band passes and
//! low passes ([`crate::metrics`]), the stylizer prior's clean estimate and the test
//! images' degradations ([`crate::imageio::Image::blurred`]).
//!
//! Taps `exp(-i^2 / (2 sigma^2))` for `|i| <= ceil(3 sigma)`, divided by their sum
//! ([`taps`]); a row pass then a column pass ([`separable`]), each output the sum of its
//! taps' products in tap order. The five blurs it replaced (the guide's, the stylizer's,
//! structure kept's, the leakage measure's and the test images') computed the same in
//! `f32` or `f64`; the first four give the same bits through it (the default end's
//! scenes, the `arf` preset's run and `evaluate`'s measures checked against the previous
//! build), the test images' differ in the last bits (their taps were divided per
//! product). What lies outside the plane is a [`Border`]: the edge pixel
//! repeated (the metrics' band pass, as `scripts/reference/structure_ref.py` defines it),
//! the plane mirrored about its edge pixels (the stylizer, as scipy's `mirror`), or zero
//! (the leakage measure's low pass, normalised by the blurred mask).
//!
//! The colour fit's SSIM window (`crate::optim::loss`) stays its own: a fixed 11-tap
//! window over zero-padded planes whose operator is applied to the loss's gradients too,
//! with scratch buffers kept between calls.

use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;
use std::iter::Sum;
use std::ops::{Add, Div, Mul, Neg};

/// What a tap reads outside the plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Border {
    /// The nearest edge pixel (clamp to edge).
    Clamp,
    /// The plane mirrored about its edge pixels: `..., 2, 1, | 0, 1, 2, ...` (the edge
    /// pixel not repeated; scipy's `mirror`).
    Mirror,
    /// Zero.
    Zero,
}

/// The floating-point types the blur runs in.
pub trait Real:
    Copy
    + Send
    + Sync
    + Add<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + Sum
    + for<'a> Sum<&'a Self>
{
    const ZERO: Self;
    /// `i` as this type (exact for the radii used).
    fn from_i64(i: i64) -> Self;
    fn two() -> Self;
    fn exp(self) -> Self;
    fn ceil_to_i64(self) -> i64;
}

macro_rules! real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            fn from_i64(i: i64) -> Self {
                i as $t
            }
            fn two() -> Self {
                2.0
            }
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            fn ceil_to_i64(self) -> i64 {
                <$t>::ceil(self) as i64
            }
        }
    };
}
real!(f32);
real!(f64);

/// The normalised taps of standard deviation `sigma` px, radius `ceil(3 sigma)`.
pub fn taps<T: Real>(sigma: T) -> Vec<T> {
    let r = (T::from_i64(3) * sigma).ceil_to_i64();
    let k: Vec<T> = (-r..=r)
        .map(|i| (-T::from_i64(i * i) / (T::two() * sigma * sigma)).exp())
        .collect();
    let s: T = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Source index of position `i` (may lie outside `0..n`) under `border`; `None` for a
/// zero outside.
fn source(i: i64, n: usize, border: Border) -> Option<usize> {
    let last = n as i64 - 1;
    match border {
        Border::Clamp => Some(i.clamp(0, last) as usize),
        Border::Zero => (0..=last).contains(&i).then_some(i as usize),
        Border::Mirror => Some(mirror(i, n)),
    }
}

/// Index `i` (any integer) of a length-`n` line mirrored about its edge pixels,
/// periodically for any overshoot: `..., 2, 1, | 0, 1, ..., n - 1, | n - 2, ...`.
pub fn mirror(i: i64, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let p = 2 * (n as i64 - 1);
    let k = i.rem_euclid(p);
    (if k < n as i64 { k } else { p - k }) as usize
}

/// The row-major `h x w` plane `x` convolved with the symmetric `taps` along its rows,
/// then its columns, `border` outside (module docs).
pub fn separable<T: Real>(x: &[T], (h, w): (usize, usize), taps: &[T], border: Border) -> Vec<T> {
    assert_eq!(x.len(), w * h, "blur: plane size");
    let r = (taps.len() / 2) as i64;
    // Rows: each output is its taps' products summed in tap order (a zero outside adds
    // no term).
    let cols: Vec<Vec<(usize, T)>> = (0..w as i64)
        .map(|xx| {
            taps.iter()
                .enumerate()
                .filter_map(|(t, &k)| source(xx + t as i64 - r, w, border).map(|s| (s, k)))
                .collect()
        })
        .collect();
    let mut tmp = Vec::with_capacity(w * h);
    for row in x.chunks_exact(w) {
        tmp.extend(
            cols.iter()
                .map(|c| c.iter().map(|&(s, k)| k * row[s]).sum::<T>()),
        );
    }
    // Columns: each output row accumulates its taps' rows in tap order.
    let mut out = vec![T::ZERO; w * h];
    for (y, o) in out.chunks_exact_mut(w).enumerate() {
        for (t, &k) in taps.iter().enumerate() {
            if let Some(s) = source(y as i64 + t as i64 - r, h, border) {
                for (ov, &v) in o.iter_mut().zip(&tmp[s * w..(s + 1) * w]) {
                    *ov = *ov + k * v;
                }
            }
        }
    }
    out
}

/// [`separable`] with the taps of `sigma` ([`taps`]).
pub fn gaussian<T: Real>(x: &[T], size: (usize, usize), sigma: T, border: Border) -> Vec<T> {
    separable(x, size, &taps(sigma), border)
}

/// Every plane of `[C, H, W]` blurred by [`gaussian`] with pixel std `sigma`, mirrored
/// borders (the stylizer prior's clean estimate and the metrics' high pass), the planes
/// in parallel; `x` itself below 0.1 px (its side taps would be below 1e-21).
pub fn gaussian_chw(x: ArrayView3<'_, f32>, sigma: f32) -> Array3<f32> {
    if sigma < 0.1 {
        return x.to_owned();
    }
    let (c, h, w) = x.dim();
    let x = x.as_standard_layout();
    let src = x.as_slice().expect("standard layout");
    let out: Vec<f32> = src
        .par_chunks(h * w)
        .flat_map_iter(|plane| gaussian(plane, (h, w), sigma, Border::Mirror))
        .collect();
    Array3::from_shape_vec((c, h, w), out).expect("shape")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blur written out pixel by pixel from its definition, in f64.
    fn by_hand(x: &[f64], (h, w): (usize, usize), sigma: f64, border: Border) -> Vec<f64> {
        let r = (3.0 * sigma).ceil() as i64;
        let g: Vec<f64> = (-r..=r)
            .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp())
            .collect();
        let s: f64 = g.iter().sum();
        let at = |y: i64, xx: i64| -> f64 {
            match (source(y, h, border), source(xx, w, border)) {
                (Some(y), Some(xx)) => x[y * w + xx],
                _ => 0.0,
            }
        };
        let mut out = vec![0.0; w * h];
        for y in 0..h as i64 {
            for xx in 0..w as i64 {
                let mut v = 0.0;
                for (a, ga) in (-r..=r).zip(&g) {
                    for (b, gb) in (-r..=r).zip(&g) {
                        v += ga * gb * at(y + a, xx + b);
                    }
                }
                out[(y * w as i64 + xx) as usize] = v / (s * s);
            }
        }
        out
    }

    #[test]
    fn matches_the_double_sum_under_every_border() {
        let (h, w) = (7, 11);
        let x: Vec<f64> = (0..h * w)
            .map(|i| ((i * 37 % 17) as f64 - 8.0) / 8.0)
            .collect();
        for border in [Border::Clamp, Border::Mirror, Border::Zero] {
            for sigma in [0.6, 1.0, 2.5] {
                let a = gaussian(&x, (h, w), sigma, border);
                let b = by_hand(&x, (h, w), sigma, border);
                for (p, q) in a.iter().zip(&b) {
                    assert!((p - q).abs() < 1e-12, "{border:?} {sigma}: {p} {q}");
                }
            }
        }
    }

    #[test]
    fn constants_stay_except_at_a_zero_border() {
        let x = vec![0.25f32; 9 * 5];
        for border in [Border::Clamp, Border::Mirror] {
            for v in gaussian(&x, (5, 9), 4.0, border) {
                assert!((v - 0.25).abs() < 1e-6, "{border:?} {v}");
            }
        }
        let z = gaussian(&x, (5, 9), 4.0, Border::Zero);
        assert!(z[2 * 9 + 4] < 0.25 * 0.5, "{}", z[2 * 9 + 4]);
        let t = taps(4.0f64);
        assert_eq!(t.len(), 25);
        assert!((t.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn mirror_reflects_about_the_edge_pixel() {
        let v: Vec<usize> = (-4..5)
            .map(|i| source(i, 4, Border::Mirror).unwrap())
            .collect();
        assert_eq!(v, [2, 3, 2, 1, 0, 1, 2, 3, 2]);
        assert_eq!(source(5, 1, Border::Mirror), Some(0));
        assert_eq!(source(-1, 4, Border::Zero), None);
        assert_eq!(source(-3, 4, Border::Clamp), Some(0));
    }
}
