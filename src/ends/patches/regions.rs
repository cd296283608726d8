//! Several regions in one synthesis (issue 54; docs/selection.md, "Regions"): each
//! region is a weight per Gaussian, a style (one image, or a blend of weighted images)
//! and a strength. The shared work is done once: the renders, the queries, the colour
//! fit over every view. What is per region: its style bank at each level
//! ([`super::level::StyleLevel`] of its blend), its channels' source images (the
//! structure guide remaps the source's luminance to its own style), the search and the
//! balance of the queries it owns, and the guidance scale of the pixels it owns (times
//! its strength).
//!
//! Who owns what: each region's weights composited from every camera like a colour (the
//! rasteriser's own weights, `sum_i w_ri alpha_i T_i`: the share of the pixel's light
//! that comes from the region's Gaussians), pooled to the level; a pixel (and the query
//! patch centred on it) belongs to the region with the largest share, the first on a
//! tie, the first where no region covers it. One region owns every pixel: the synthesis
//! of one style, bit for bit.

use super::view::Query;
use crate::imageio::Image;
use crate::{Camera, Error, Result, Scene};

/// One region of the synthesis.
#[derive(Debug, Clone)]
pub struct RegionStyle<'a> {
    /// Its style: images with weights summing to 1 (one image: a weight of 1).
    pub styles: Vec<(&'a Image, f32)>,
    /// Its Gaussians' weights, in the scene's order (`None`: every Gaussian). Read only
    /// when there are several regions (who owns a pixel); the colour fit takes the
    /// selection [`super::synthesize`] is given.
    pub weights: Option<&'a [f32]>,
    /// The guidance scale's factor on its pixels, in [0, 1].
    pub strength: f32,
}

impl<'a> RegionStyle<'a> {
    /// The whole scene in one style at full strength.
    pub fn one(style: &'a Image) -> RegionStyle<'a> {
        RegionStyle {
            styles: vec![(style, 1.0)],
            weights: None,
            strength: 1.0,
        }
    }

    /// The style the channels' source images are remapped to: a blend's heaviest (the
    /// first of equals).
    pub fn lead(&self) -> &'a Image {
        let mut best = self.styles[0];
        for &s in &self.styles[1..] {
            if s.1 > best.1 {
                best = s;
            }
        }
        best.0
    }
}

/// Each region's share of every pixel of every view (`[region][view][H W]`, module
/// docs, [`crate::render::shares`]); empty when there is one region (it owns every
/// pixel).
pub(super) fn cover(
    scene: &Scene,
    cameras: &[Camera],
    regions: &[RegionStyle<'_>],
) -> Result<Vec<Vec<Vec<f32>>>> {
    if regions.len() < 2 {
        return Ok(Vec::new());
    }
    let every = vec![1.0f32; scene.len()];
    let weights: Vec<&[f32]> = regions
        .iter()
        .map(|r| r.weights.unwrap_or(&every))
        .collect();
    let mut out = vec![Vec::with_capacity(cameras.len()); regions.len()];
    for cam in cameras {
        for (r, s) in crate::render::shares::shares(scene, cam, &weights)?
            .into_iter()
            .enumerate()
        {
            out[r].push(s);
        }
    }
    Ok(out)
}

/// The regions' styles and strengths checked: at least one region, each with at least
/// one style, its weights finite, positive and summing to 1, its strength in [0, 1].
pub(super) fn check(regions: &[RegionStyle<'_>]) -> Result<()> {
    if regions.is_empty() || regions.len() > usize::from(u8::MAX) {
        return Err(Error::param("synthesis: 1 to 255 regions"));
    }
    for (i, r) in regions.iter().enumerate() {
        let sum: f32 = r.styles.iter().map(|s| s.1).sum();
        if r.styles.is_empty()
            || r.styles.iter().any(|s| !(s.1.is_finite() && s.1 > 0.0))
            || (sum - 1.0).abs() > 1e-4
        {
            return Err(Error::param(format!(
                "synthesis: region {i}'s style weights must be positive and sum to 1"
            )));
        }
        if !(0.0..=1.0).contains(&r.strength) {
            return Err(Error::param(format!(
                "synthesis: region {i}'s strength must lie in [0, 1]"
            )));
        }
    }
    Ok(())
}

/// One region's queries: their indices in the views' queries laid end to end, and their
/// pixels, view by view (`all`: every query, the one region's).
pub(super) struct Owned {
    pub(super) index: Vec<usize>,
    rows: Vec<Option<Vec<usize>>>,
    pub(super) pixels: Vec<Vec<[usize; 3]>>,
}

impl Owned {
    pub(super) fn new(queries: &[Query], r: usize, all: bool) -> Owned {
        let (mut index, mut rows, mut pixels) = (Vec::new(), Vec::new(), Vec::new());
        let mut offset = 0;
        for q in queries {
            if all {
                index.extend(offset..offset + q.pixels.len());
                rows.push(None);
                pixels.push(q.pixels.clone());
            } else {
                let mine: Vec<usize> = (0..q.pixels.len())
                    .filter(|&i| usize::from(q.region[i]) == r)
                    .collect();
                index.extend(mine.iter().map(|i| offset + i));
                pixels.push(mine.iter().map(|&i| q.pixels[i]).collect());
                rows.push(Some(mine));
            }
            offset += q.pixels.len();
        }
        Owned {
            index,
            rows,
            pixels,
        }
    }

    /// The region's rows of `part` of every view's queries, stacked.
    pub(super) fn stack<'q>(
        &self,
        queries: &'q [Query],
        part: impl Fn(&'q Query) -> ndarray::ArrayView2<'q, f32>,
    ) -> ndarray::Array2<f32> {
        let picked: Vec<ndarray::Array2<f32>>;
        let views: Vec<ndarray::ArrayView2<'_, f32>> = if self.rows.iter().all(Option::is_none) {
            queries.iter().map(&part).collect()
        } else {
            picked = queries
                .iter()
                .zip(&self.rows)
                .map(|(q, rows)| part(q).select(ndarray::Axis(0), rows.as_deref().unwrap_or(&[])))
                .collect();
            picked.iter().map(|a| a.view()).collect()
        };
        ndarray::concatenate(ndarray::Axis(0), &views).expect("patches of one width")
    }
}

#[cfg(test)]
mod blend_tests {
    use super::super::{SynthesisParams, synthesize_images};
    use crate::imageio::Image;

    /// Stripes of period 8 in two colours, across (`rows`) or down.
    fn stripes(rows: bool, a: [f32; 3], b: [f32; 3]) -> Image {
        let (w, h) = (64, 64);
        let data = (0..w * h)
            .flat_map(|i| {
                let t = if rows { i / w } else { i % w };
                if (t / 4) % 2 == 0 { a } else { b }
            })
            .collect();
        Image {
            width: w,
            height: h,
            data,
        }
    }

    /// The Gram matrix of an image's 3x3 colour patches (27 features per pixel).
    fn patch_gram(rgb: &[f32], w: usize, h: usize) -> Vec<f64> {
        let mut g = vec![0.0f64; 27 * 27];
        let mut n = 0.0;
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let f: Vec<f64> = (0..9)
                    .flat_map(|k| {
                        let i = (y + k / 3 - 1) * w + x + k % 3 - 1;
                        (0..3).map(move |c| f64::from(rgb[i * 3 + c]))
                    })
                    .collect();
                for a in 0..27 {
                    for b in 0..27 {
                        g[a * 27 + b] += f[a] * f[b];
                    }
                }
                n += 1.0;
            }
        }
        g.iter().map(|v| v / n).collect()
    }

    fn distance(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
    }

    /// A blend sweep from style A to style B (red/white rows, blue/yellow columns): the
    /// result's Gram distance to A rises and to B falls at every step.
    #[test]
    fn a_blend_sweep_moves_from_one_style_to_the_other() {
        let a = stripes(true, [0.9, 0.1, 0.1], [0.95, 0.95, 0.95]);
        let b = stripes(false, [0.1, 0.2, 0.9], [0.9, 0.8, 0.1]);
        let (h, w) = (32, 32);
        let image: Vec<f32> = (0..h * w)
            .flat_map(|i| {
                let v = 0.3 + 0.4 * (i % w) as f32 / w as f32;
                [v, v, v]
            })
            .collect();
        let alpha = vec![vec![1.0f32; h * w]];
        let p = SynthesisParams {
            levels: vec![2, 1],
            patch: 5,
            pca_dims: 8,
            ..SynthesisParams::default()
        };
        let (ga, gb) = (
            patch_gram(&a.data, a.width, a.height),
            patch_gram(&b.data, b.width, b.height),
        );
        let mut to_a = Vec::new();
        let mut to_b = Vec::new();
        for wb in [0.0f32, 0.25, 0.5, 0.75, 1.0] {
            let styles: Vec<(&Image, f32)> = [(&a, 1.0 - wb), (&b, wb)]
                .into_iter()
                .filter(|s| s.1 > 0.0)
                .collect();
            let out = synthesize_images(
                std::slice::from_ref(&image),
                &alpha,
                &[(h, w)],
                &styles,
                [0.0; 3],
                64,
                &p,
            )
            .unwrap();
            let g = patch_gram(&out[0], w, h);
            to_a.push(distance(&g, &ga));
            to_b.push(distance(&g, &gb));
        }
        for i in 1..to_a.len() {
            assert!(to_a[i] > to_a[i - 1], "to A: {to_a:?}");
            assert!(to_b[i] < to_b[i - 1], "to B: {to_b:?}");
        }
    }
}

#[cfg(test)]
mod empty_tests {
    use super::super::{SynthesisParams, synthesize};
    use super::RegionStyle;
    use crate::scene::colour::Bands;

    /// A region that owns no pixel (its Gaussians cover none: here, no Gaussian at all)
    /// searches no query and changes nothing; the other region is styled as usual.
    #[test]
    fn a_region_that_owns_no_pixel_is_harmless() {
        let scene = crate::sample::sample_scene(1);
        let cams = crate::camera::load_cameras("orbit:2", &scene.bounds(), 32, 32).unwrap();
        let style = super::super::motif::tests::disc();
        let (all, none) = (vec![1.0f32; scene.len()], vec![0.0f32; scene.len()]);
        let p = SynthesisParams {
            levels: vec![2, 1],
            rounds: 1,
            steps: 2,
            control: 1.0,
            ..SynthesisParams::default()
        };
        let regions = [
            RegionStyle {
                weights: Some(&all),
                ..RegionStyle::one(&style)
            },
            RegionStyle {
                weights: Some(&none),
                ..RegionStyle::one(&style)
            },
        ];
        let run = |r: &[RegionStyle<'_>]| {
            synthesize(&scene, &cams, r, [0.0; 3], 32, &p, None, None, Bands::Keep)
                .unwrap()
                .0
        };
        let two = run(&regions);
        let one = run(&regions[..1]);
        assert_eq!(two.sh_dc, one.sh_dc, "the empty region changed the result");
    }
}
