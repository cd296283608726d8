//! The evaluation reference in two parts (issue 55): [`SourceReference`], what depends
//! only on the original views (and so the scene and the cameras), and [`StyleReference`],
//! what depends only on the style image (and the views' count and size, which fix the
//! style crops). A user who tries five styles on one scene makes the source part once;
//! [`super::Reference::merge`] joins one of each into the [`super::Reference`] an
//! evaluation reads, with the same values bit for bit as computing it whole (the whole
//! one is made through these two: [`super::Reference::compute`]).
//!
//! The two cross terms, the original views' Gram distances to the style (whole view and
//! per layer over the object), are made at the merge from the views' Gram matrices,
//! which the source part keeps (symmetric, so the artifact stores their upper triangles).
//!
//! Timing ([`crate::timing`]): each part is the phase `reference`, with the parts of
//! [`super`]'s list that it computes.

use super::{EvalParams, GRAM_MAX_SIDE, Settings, style_crops};
use crate::Result;
use crate::imageio::Image;
use crate::metrics::consistency::{self, PairScore};
use crate::metrics::fid;
use crate::metrics::gram;
use crate::metrics::nets::Nets;
use crate::metrics::texture;
use crate::metrics::views::ViewSet;
use serde::{Deserialize, Serialize};

/// The part of the reference that depends only on the original views.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceReference {
    /// The settings of the evaluations it serves (those of the whole reference).
    pub settings: Settings,
    /// The original views' own consistency at the short and the long offset.
    pub short_original: Vec<PairScore>,
    pub long_original: Vec<PairScore>,
    /// Inception pool3 of the original views and of their object squares.
    pub views_pool3: Vec<Vec<f32>>,
    pub object_squares_pool3: Vec<Vec<f32>>,
    /// Per view, its VGG16 Gram matrix per tap (all five).
    pub view_grams: Vec<Vec<Vec<f64>>>,
    /// Per view, its object's alpha-weighted Gram matrix per layer of
    /// [`texture::GRAM_LAYERS`] (`None`: too little coverage; [`texture::view_grams`]).
    pub object_grams: Vec<Vec<Option<Vec<f64>>>>,
}

/// What the style part was made for: the style crops' count and size come from the
/// views (`views.max(2)` crops at `width x height`), and the seed draws them and the
/// style squares (made only when `object_squares > 0`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StyleSettings {
    pub views: usize,
    pub width: usize,
    pub height: usize,
    pub seed: u64,
    pub object_squares: usize,
    /// The Inception features made (a part made before this field: yes).
    #[serde(default = "super::yes")]
    pub inception: bool,
}

impl StyleSettings {
    /// The style settings that serve evaluations with the whole-reference `settings`.
    pub fn of(s: &Settings) -> StyleSettings {
        StyleSettings {
            views: s.views,
            width: s.width,
            height: s.height,
            seed: s.seed,
            object_squares: s.object_squares,
            inception: s.inception,
        }
    }

    /// The fields where `self` differs from `other`, as `name a vs b`.
    pub fn differences(&self, other: &StyleSettings) -> Vec<String> {
        let mut d = Vec::new();
        let fields = [
            ("views", self.views as u64, other.views as u64),
            ("width", self.width as u64, other.width as u64),
            ("height", self.height as u64, other.height as u64),
            ("seed", self.seed, other.seed),
            (
                "object_squares",
                self.object_squares as u64,
                other.object_squares as u64,
            ),
            (
                "inception",
                u64::from(self.inception),
                u64::from(other.inception),
            ),
        ];
        for (name, a, b) in fields {
            if a != b {
                d.push(format!("{name} {a} vs {b}"));
            }
        }
        d
    }
}

/// The part of the reference that depends only on the style image (and
/// [`StyleSettings`]).
#[derive(Debug, Clone, PartialEq)]
pub struct StyleReference {
    pub settings: StyleSettings,
    /// Inception pool3 of the style crops (FID/KID_style) and of the style's squares
    /// (empty when `object_squares` is 0).
    pub crops_pool3: Vec<Vec<f32>>,
    pub style_squares_pool3: Vec<Vec<f32>>,
    /// The style image's (at most [`GRAM_MAX_SIDE`] px) VGG16 Gram matrices, per tap.
    pub style_grams: Vec<Vec<f64>>,
}

impl SourceReference {
    /// Compute the source part of evaluating against `orig` with `p` (`nets`: its LPIPS
    /// backbone, VGG16 and Inception).
    pub fn compute(nets: &mut Nets, orig: &ViewSet, p: &EvalParams) -> Result<SourceReference> {
        p.validate()?;
        let (n, w, h) = (orig.n, orig.width, orig.height);
        let ph = crate::timing::span("reference");
        let pairs = |offset| consistency::pairs(n, offset);
        let cons = crate::timing::span("consistency");
        let (short_original, _) =
            consistency::score_pairs(&mut nets.lpips, orig, &orig.images, &pairs(p.short_range))?;
        let (long_original, _) =
            consistency::score_pairs(&mut nets.lpips, orig, &orig.images, &pairs(p.long_range))?;
        drop(cons);

        let vgg = nets.vgg();
        let (mut view_grams, mut object_grams) = (Vec::new(), Vec::new());
        for i in 0..n {
            let f = crate::timing::phase("vgg", || vgg.features(&[&orig.images[i]]))?;
            object_grams.push(crate::timing::phase("object gram", || {
                texture::view_grams(&f[0], orig.geometry(i).1, w, h)
            }));
            view_grams.push(crate::timing::phase("gram matrices", || gram::grams(&f[0])));
        }

        let (views_pool3, object_squares_pool3) = match nets.inception.as_mut() {
            Some(inc) if p.inception => {
                let _inception = crate::timing::span("inception");
                let views_pool3 = crate::timing::phase("views", || {
                    inc.pool3(&orig.images.iter().collect::<Vec<_>>())
                })?;
                let _sq = crate::timing::span("object squares");
                let at =
                    texture::object_patch_positions(&orig.alpha, w, h, p.object_squares, p.seed);
                let squares = texture::object_patches(orig, &at);
                (views_pool3, inc.pool3(&squares.iter().collect::<Vec<_>>())?)
            }
            _ => (Vec::new(), Vec::new()),
        };
        drop(ph);
        Ok(SourceReference {
            settings: Settings::of(orig, p),
            short_original,
            long_original,
            views_pool3,
            object_squares_pool3,
            view_grams,
            object_grams,
        })
    }
}

impl StyleReference {
    /// Compute the style part for `settings` (`nets`: VGG16 and Inception; the LPIPS
    /// backbone is not used).
    pub fn compute(
        nets: &mut Nets,
        style: &Image,
        settings: StyleSettings,
    ) -> Result<StyleReference> {
        let squares = settings.object_squares > 0;
        Self::compute_with(nets, style, settings, squares)
    }

    /// [`Self::compute`], the style squares only when `squares` (the whole reference
    /// skips them where no object square fits the views: they would not be used).
    pub(super) fn compute_with(
        nets: &mut Nets,
        style: &Image,
        settings: StyleSettings,
        squares: bool,
    ) -> Result<StyleReference> {
        let s = &settings;
        let ph = crate::timing::span("reference");
        let vgg = nets.vgg();
        let f = crate::timing::phase("vgg", || vgg.features(&[&style.fit_within(GRAM_MAX_SIDE)]))?;
        let style_grams = crate::timing::phase("gram matrices", || gram::grams(&f[0]));
        let (crops_pool3, style_squares_pool3) = match nets.inception.as_mut() {
            Some(inc) if s.inception => {
                let mut pool3 = |v: &[Image]| inc.pool3(&v.iter().collect::<Vec<_>>());
                let _inception = crate::timing::span("inception");
                let crops_pool3 = crate::timing::phase("style crops", || {
                    pool3(&style_crops(
                        style,
                        s.views.max(fid::MIN_IMAGES),
                        s.width,
                        s.height,
                        s.seed,
                    ))
                })?;
                let style_squares_pool3 = if squares {
                    crate::timing::phase("style squares", || {
                        pool3(&texture::style_patches(style, s.seed))
                    })?
                } else {
                    Vec::new()
                };
                (crops_pool3, style_squares_pool3)
            }
            _ => (Vec::new(), Vec::new()),
        };
        drop(ph);
        Ok(StyleReference {
            settings,
            crops_pool3,
            style_squares_pool3,
            style_grams,
        })
    }
}

/// The upper triangle (row by row, diagonal included) of the symmetric `c x c` matrix
/// `m`.
pub fn upper_triangle(m: &[f64]) -> Vec<f64> {
    let c = m.len().isqrt();
    (0..c)
        .flat_map(|a| (a..c).map(move |b| m[a * c + b]))
        .collect()
}

/// The symmetric matrix of an [`upper_triangle`]; `None` unless its length is
/// `c (c + 1) / 2` for some `c`.
pub fn from_upper_triangle(t: &[f64]) -> Option<Vec<f64>> {
    let c = (2 * t.len()).isqrt();
    if c * (c + 1) / 2 != t.len() {
        return None;
    }
    let mut m = vec![0.0; c * c];
    let mut k = 0;
    for a in 0..c {
        for b in a..c {
            m[a * c + b] = t[k];
            m[b * c + a] = t[k];
            k += 1;
        }
    }
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_symmetric_matrix_round_trips_through_its_upper_triangle() {
        let c = 5;
        let m: Vec<f64> = (0..c * c)
            .map(|k| {
                let (a, b) = (k / c, k % c);
                (a.min(b) * 7 + a.max(b)) as f64 * 0.1
            })
            .collect();
        let t = upper_triangle(&m);
        assert_eq!(t.len(), c * (c + 1) / 2);
        assert_eq!(from_upper_triangle(&t), Some(m));
        assert_eq!(from_upper_triangle(&[1.0, 2.0]), None);
        assert_eq!(from_upper_triangle(&[]), Some(Vec::new()));
    }
}
