//! LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a
//! Perceptual Metric", Eq. 1) from tapped backbone features:
//!
//! `d(x, y) = sum_k  mean_{h,w}  sum_c  lin_k[c] * (f̂_k(x) - f̂_k(y))^2`,
//! `f̂ = f / (|f|_2 over channels + 1e-10)`.
//!
//! The backbone runs in ONNX ([`super::nets`]); this part runs here so features computed
//! once serve every pair an image takes part in, and so the spatial mean can be restricted
//! to a mask (view consistency compares only pixels that both views see): with a pixel
//! mask, each tap's spatial mean becomes a weighted mean with the mask box-averaged to
//! that tap's resolution.

use super::nets::{Features, LpipsModel};
use crate::Result;
use crate::imageio::Image;
use crate::vgg::Tensor3;

/// Per-pixel `sum_c lin[c] (f̂a - f̂b)^2` at one tap, `h x w`.
pub fn tap_map(a: &Tensor3, b: &Tensor3, lin: &[f32]) -> Vec<f64> {
    assert_eq!((a.c, a.h, a.w), (b.c, b.h, b.w), "LPIPS: tap shapes differ");
    let hw = a.h * a.w;
    let norm = |t: &Tensor3| {
        (0..hw)
            .map(|p| {
                let s: f64 = (0..t.c).map(|c| (t.data[c * hw + p] as f64).powi(2)).sum();
                1.0 / (s.sqrt() + 1e-10)
            })
            .collect::<Vec<f64>>()
    };
    let (na, nb) = (norm(a), norm(b));
    let mut out = vec![0.0; hw];
    for c in 0..a.c {
        let l = lin[c] as f64;
        for p in 0..hw {
            let d = a.data[c * hw + p] as f64 * na[p] - b.data[c * hw + p] as f64 * nb[p];
            out[p] += l * d * d;
        }
    }
    out
}

/// Box-average a full-resolution mask (`width x height`, values in [0, 1]) onto an
/// `h x w` grid (each cell averages the pixels it covers).
pub fn downsample_mask(mask: &[f32], width: usize, height: usize, h: usize, w: usize) -> Vec<f64> {
    let mut sum = vec![0.0; h * w];
    let mut cnt = vec![0.0; h * w];
    for y in 0..height {
        let ty = (y * h / height).min(h - 1);
        for x in 0..width {
            let tx = (x * w / width).min(w - 1);
            sum[ty * w + tx] += mask[y * width + x] as f64;
            cnt[ty * w + tx] += 1.0;
        }
    }
    sum.iter()
        .zip(&cnt)
        .map(|(s, c)| if *c > 0.0 { s / c } else { 0.0 })
        .collect()
}

/// LPIPS distance between two images' features; `mask` = `(weights, width, height)` at
/// image resolution restricts the spatial means (`None`: plain means, standard LPIPS).
pub fn distance(
    a: &Features,
    b: &Features,
    lin: &[Vec<f32>],
    mask: Option<(&[f32], usize, usize)>,
) -> f64 {
    let mut total = 0.0;
    for (k, (ta, tb)) in a.iter().zip(b).enumerate() {
        let m = tap_map(ta, tb, &lin[k]);
        total += match mask {
            None => m.iter().sum::<f64>() / m.len() as f64,
            Some((mk, w, h)) => {
                let wts = downsample_mask(mk, w, h, ta.h, ta.w);
                let ws: f64 = wts.iter().sum();
                if ws <= 0.0 {
                    0.0
                } else {
                    m.iter().zip(&wts).map(|(v, q)| v * q).sum::<f64>() / ws
                }
            }
        };
    }
    total
}

/// LPIPS between image pairs `(a[i], b[i])` (features computed here).
pub fn pairwise(model: &mut LpipsModel, a: &[&Image], b: &[&Image]) -> Result<Vec<f64>> {
    let fa = model.features(a)?;
    let fb = model.features(b)?;
    Ok(fa
        .iter()
        .zip(&fb)
        .map(|(x, y)| distance(x, y, &model.lin, None))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::nets::{LpipsNet, tests::setup};

    fn tap(c: usize, h: usize, w: usize, f: impl Fn(usize) -> f32) -> Tensor3 {
        Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(f).collect(),
        }
    }

    #[test]
    fn tap_map_by_hand() {
        // one pixel, two channels: a = (3, 4) -> (0.6, 0.8); b = (1, 0) -> (1, 0).
        let a = tap(2, 1, 1, |i| [3.0, 4.0][i]);
        let b = tap(2, 1, 1, |i| [1.0, 0.0][i]);
        let m = tap_map(&a, &b, &[2.0, 0.5]);
        let want = 2.0 * 0.4f64.powi(2) + 0.5 * 0.8f64.powi(2);
        assert!((m[0] - want).abs() < 1e-6);
        // scale invariance of the unit normalisation
        let a2 = tap(2, 1, 1, |i| [30.0, 40.0][i]);
        assert!((tap_map(&a2, &b, &[2.0, 0.5])[0] - want).abs() < 1e-6);
    }

    #[test]
    fn masked_mean_uses_only_masked_cells() {
        let a = tap(1, 2, 2, |i| [1.0, 1.0, 1.0, 1.0][i]);
        let b = tap(1, 2, 2, |i| [1.0, -1.0, 1.0, 1.0][i]);
        let lin = vec![vec![1.0]];
        let fa = vec![a];
        let fb = vec![b];
        assert!((distance(&fa, &fb, &lin, None) - 1.0).abs() < 1e-9); // 4/4
        // 4x4 image mask covering only the left half -> cells (0,0), (1,0): no difference.
        let mask: Vec<f32> = (0..16).map(|p| if p % 4 < 2 { 1.0 } else { 0.0 }).collect();
        assert!(distance(&fa, &fb, &lin, Some((&mask, 4, 4))).abs() < 1e-9);
        let right: Vec<f32> = mask.iter().map(|m| 1.0 - m).collect();
        assert!((distance(&fa, &fb, &lin, Some((&right, 4, 4))) - 2.0).abs() < 1e-9);
    }

    fn photo_like(w: usize, h: usize) -> Image {
        Image::from_fn(w, h, |x, y| {
            let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
            let disc = ((u - 0.4).powi(2) + (v - 0.5).powi(2) < 0.06) as u8 as f32;
            [
                0.5 + 0.3 * (9.0 * u).sin() * (7.0 * v).cos(),
                0.3 + 0.5 * disc,
                (0.2 + 0.6 * u * v + 0.1 * ((x / 4 + y / 4) % 2) as f32).min(1.0),
            ]
        })
    }

    #[test]
    fn lpips_is_zero_on_itself_and_grows_with_blur_and_noise() {
        let Some(m) = setup() else { return };
        for net in [LpipsNet::Alex, LpipsNet::Vgg16] {
            let mut model = LpipsModel::load(&m, net, 2).unwrap();
            let img = photo_like(96, 80);
            let versions = [
                img.clone(),
                img.blurred(0.7),
                img.blurred(1.5),
                img.blurred(3.0),
                img.noisy(0.03, 1),
                img.noisy(0.1, 1),
                img.noisy(0.3, 1),
            ];
            let others: Vec<&Image> = versions.iter().collect();
            let same: Vec<&Image> = vec![&img; versions.len()];
            let d = pairwise(&mut model, &same, &others).unwrap();
            eprintln!(
                "{}: self {:.2e}, blur {:?}, noise {:?}",
                net.name(),
                d[0],
                &d[1..4],
                &d[4..]
            );
            assert!(d[0].abs() < 1e-9, "LPIPS(x, x) = {}", d[0]);
            assert!(
                d[1] > 1e-4 && d[1] < d[2] && d[2] < d[3],
                "blur: {:?}",
                &d[1..4]
            );
            assert!(
                d[4] > 1e-4 && d[4] < d[5] && d[5] < d[6],
                "noise: {:?}",
                &d[4..]
            );
        }
    }
}
