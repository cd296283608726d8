//! Short- and long-range view consistency (FantasyStyle's experiments): for view pairs
//! `(i, i + k)` (`k = 1` short range, `k = 5` long range by default), warp the stylized
//! view `i + k` into view `i` with the rendered depth and the cameras ([`crate::maths::warp`]),
//! then compare it with stylized view `i` on the pixels both see:
//!
//! * RMSE over valid pixels and the three channels (images in `[0, 1]`);
//! * LPIPS with both images set to mid-grey outside the valid mask (so masked pixels
//!   contribute no difference) and each tap's spatial mean restricted to the mask
//!   ([`super::lpips::distance`]).
//!
//! The same is computed on the original renders as a floor: the warp itself is not
//! perfect (view-dependent colour, splat blending at edges), so stylized consistency is
//! read relative to it. Pairs with less than [`MIN_OVERLAP`] valid pixels are skipped.
//!
//! The warp's loss grows with the content's texture: resampling a sharp pattern at a
//! sub-pixel offset and a grazing angle loses more of it than it loses of a smooth one, so a
//! seam-free recolouring with more contrast than the original scores worse than the
//! original. Each pair therefore also has an *excess*: its LPIPS (and RMSE) minus that of
//! the [`round_trip`], view `i`'s own image warped into view `j` and back through the same
//! geometry, both on the pixels the round trip keeps. The round trip holds no pixel of view
//! `j`, so it has the warp's loss on this content and no inter-view difference at all; the
//! excess is what view `j` adds: a seam, a motif that moved, a colour blend of overlapping
//! splats that changes with the view. The round trip resamples twice where the pair
//! resamples once, so its floor is high on fine texture: on the analytic plane with
//! six-cycle stripes its LPIPS is 1.7x the pair's (an excess of -0.006 against the pair's
//! 0.008) and a small or negative excess reads "no more than the warp loses", not "exactly
//! consistent". A per-view colour change is most of its pair score (0.30 of 0.31 there);
//! over the keep benchmark's 29 cases the per-view 2D stylization (`preview`) has a mean
//! long-range excess of 0.124, the default's 3D result 0.019 (BENCHMARKS.md, "Seams").
//! What the round trip cannot see is a correspondence wrong both ways (the depth test's
//! 3% tolerance matches the two sides of a thin fin): content contrast still raises that.
//! Reference: `scripts/reference/consistency_ref.py` (numpy, from these definitions).
//! [`score_pairs`] times its parts as the phases `warp` and `lpips` ([`crate::timing`]).

use super::lpips;
use super::nets::LpipsModel;
use super::views::ViewSet;
use crate::Result;
use crate::imageio::Image;
use crate::maths::warp::{Warped, surface_depth, warp_into};
use serde::Serialize;

/// Fewest valid pixels (fraction of the image) for a pair to be measured.
pub const MIN_OVERLAP: f64 = 0.02;
/// Fewest of a measured pair's valid pixels its [`round_trip`] must keep for the excess
/// to be measured (so the pair and its floor describe mostly the same pixels; on the
/// shared scenes it keeps 0.59-0.96 of them).
pub const MIN_ROUND_TRIP: f64 = 0.5;

/// Pairs `(i, i + offset)`.
pub fn pairs(n: usize, offset: usize) -> Vec<(usize, usize)> {
    if offset == 0 {
        return Vec::new();
    }
    (0..n.saturating_sub(offset))
        .map(|i| (i, i + offset))
        .collect()
}

/// One measured pair.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PairScore {
    pub i: usize,
    pub j: usize,
    /// Fraction of view `i`'s pixels that view `j` sees (warp valid mask).
    pub valid_fraction: f64,
    /// `None` when the overlap is below [`MIN_OVERLAP`].
    pub lpips: Option<f64>,
    pub rmse: Option<f64>,
    /// The pair's LPIPS minus its [`round_trip`]'s, both on the round trip's pixels
    /// (module doc); `None` when the pair is not measured or its round trip keeps fewer
    /// than [`MIN_ROUND_TRIP`] of its pixels.
    #[serde(default)]
    pub excess_lpips: Option<f64>,
    /// The same for RMSE.
    #[serde(default)]
    pub excess_rmse: Option<f64>,
}

/// RMSE over masked pixels (all channels).
pub fn masked_rmse(a: &Image, b: &Image, mask: &[f32]) -> f64 {
    let (mut s, mut n) = (0.0f64, 0.0f64);
    for (p, &m) in mask.iter().enumerate() {
        if m > 0.0 {
            for c in 0..3 {
                let d = (a.data[p * 3 + c] - b.data[p * 3 + c]) as f64;
                s += m as f64 * d * d;
            }
            n += 3.0 * m as f64;
        }
    }
    if n > 0.0 { (s / n).sqrt() } else { 0.0 }
}

/// `img` with mid-grey outside `mask`.
pub fn masked(img: &Image, mask: &[f32]) -> Image {
    let mut out = img.clone();
    for (p, &m) in mask.iter().enumerate() {
        if m <= 0.0 {
            out.data[p * 3..p * 3 + 3].copy_from_slice(&[0.5; 3]);
        }
    }
    out
}

/// Warp `images[j]` into view `i` of `geom` (depths/cameras of `geom`).
pub fn warp_pair(geom: &ViewSet, images: &[Image], i: usize, j: usize) -> Warped {
    let (di, ai) = geom.geometry(i);
    let (dj, aj) = geom.geometry(j);
    warp_into(
        &geom.cameras[i],
        &surface_depth(di, ai),
        &geom.cameras[j],
        &surface_depth(dj, aj),
        &images[j],
    )
}

/// The warp's own loss on view `i`'s content: `images[i]` warped into view `j`, then back
/// into view `i` sampling only the first leg's valid pixels. Its mask lies inside
/// [`warp_pair`]`(i, j)`'s, and it samples view `j`'s frame at the same positions.
pub fn round_trip(geom: &ViewSet, images: &[Image], i: usize, j: usize) -> Warped {
    let (di, ai) = geom.geometry(i);
    let (dj, aj) = geom.geometry(j);
    let (zi, zj) = (surface_depth(di, ai), surface_depth(dj, aj));
    let there = warp_into(&geom.cameras[j], &zj, &geom.cameras[i], &zi, &images[i]);
    let zj_there: Vec<f32> = zj
        .iter()
        .zip(&there.mask)
        .map(|(&z, &m)| if m > 0.0 { z } else { f32::NAN })
        .collect();
    warp_into(
        &geom.cameras[i],
        &zi,
        &geom.cameras[j],
        &zj_there,
        &there.image,
    )
}

/// LPIPS of `a` to each of `others` on `mask` (every image set to mid-grey outside it),
/// `a`'s features computed once: one batch of `1 + others.len()` images.
fn masked_lpips(
    model: &mut LpipsModel,
    a: &Image,
    others: &[&Image],
    mask: &[f32],
) -> Result<Vec<f64>> {
    let images: Vec<Image> = std::iter::once(a)
        .chain(others.iter().copied())
        .map(|im| masked(im, mask))
        .collect();
    let f = model.features(&images.iter().collect::<Vec<_>>())?;
    let size = Some((mask, a.width, a.height));
    Ok(f[1..]
        .iter()
        .map(|fb| lpips::distance(&f[0], fb, &model.lin, size))
        .collect())
}

/// The excess of pair `(i, j)` whose warp is `wp` (module doc): LPIPS and RMSE.
fn excess(
    model: &mut LpipsModel,
    geom: &ViewSet,
    images: &[Image],
    (i, j): (usize, usize),
    wp: &Warped,
) -> Result<(Option<f64>, Option<f64>)> {
    let rt = crate::timing::phase("warp", || round_trip(geom, images, i, j));
    if (rt.valid as f64) < MIN_ROUND_TRIP * wp.valid as f64 {
        return Ok((None, None));
    }
    let _ph = crate::timing::span("lpips");
    let m = &rt.mask;
    let d = masked_lpips(model, &images[i], &[&wp.image, &rt.image], m)?;
    let lp = d[0] - d[1];
    let rm = masked_rmse(&images[i], &wp.image, m) - masked_rmse(&images[i], &rt.image, m);
    Ok((Some(lp), Some(rm)))
}

/// Score `pairs` of `images` (stylized or original) using the geometry of `geom`.
/// Also returns the warps (for the report's illustration).
pub fn score_pairs(
    model: &mut LpipsModel,
    geom: &ViewSet,
    images: &[Image],
    pairs: &[(usize, usize)],
) -> Result<(Vec<PairScore>, Vec<Warped>)> {
    let mut scores = Vec::with_capacity(pairs.len());
    let mut warps = Vec::with_capacity(pairs.len());
    for &(i, j) in pairs {
        let wp = crate::timing::phase("warp", || warp_pair(geom, images, i, j));
        let frac = wp.valid_fraction();
        let ((lp, rm), (excess_lpips, excess_rmse)) = if frac < MIN_OVERLAP {
            ((None, None), (None, None))
        } else {
            let d = {
                let _ph = crate::timing::span("lpips");
                masked_lpips(model, &images[i], &[&wp.image], &wp.mask)?[0]
            };
            let pair = (Some(d), Some(masked_rmse(&images[i], &wp.image, &wp.mask)));
            (pair, excess(model, geom, images, (i, j), &wp)?)
        };
        scores.push(PairScore {
            i,
            j,
            valid_fraction: frac,
            lpips: lp,
            rmse: rm,
            excess_lpips,
            excess_rmse,
        });
        warps.push(wp);
    }
    Ok((scores, warps))
}

/// Mean of the measured values (`None` if none were measured).
pub fn mean_of(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let xs: Vec<f64> = v.flatten().collect();
    (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_lists() {
        assert_eq!(pairs(4, 1), vec![(0, 1), (1, 2), (2, 3)]);
        assert_eq!(pairs(7, 5), vec![(0, 5), (1, 6)]);
        assert!(pairs(5, 5).is_empty());
        assert!(pairs(3, 0).is_empty());
    }

    #[test]
    fn rmse_by_hand() {
        let a = Image::filled(2, 1, [0.0; 3]);
        let mut b = Image::filled(2, 1, [0.0; 3]);
        b.data[3..6].copy_from_slice(&[0.3, 0.3, 0.3]);
        assert!((masked_rmse(&a, &b, &[1.0, 1.0]) - (0.09f64 / 2.0).sqrt()).abs() < 1e-7);
        assert!(masked_rmse(&a, &b, &[1.0, 0.0]).abs() < 1e-12);
        assert!((masked_rmse(&a, &b, &[0.0, 1.0]) - 0.3).abs() < 1e-7);
    }
}
