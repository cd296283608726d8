//! The structure guide of the patch synthesis: the content control of the deterministic
//! end (ControlNet's role in FantasyStyle, Sec. 4.2; issue 47).
//!
//! Guided patch synthesis keeps a target's structure by matching guide channels beside
//! the colours: Image Analogies' luminance remapping (Hertzmann et al. 2001, Sec. 3.4),
//! StyLit's guides (Fiser et al. 2016), EbSynth's (Jamriska et al. 2019). Here every
//! object patch carries, beside its current colours, the luminance of the *frozen*
//! source render (never the current colours), remapped to the style's luminance mean
//! and spread: `g = (L - mean_obj) / std_obj * std_style + mean_style` (Rec. 601 luma;
//! the object's moments over every view's covered pixels). Every style patch carries
//! its own luminance. The match's cost is then
//! `|colour_q - colour_s|^2 + 3 control |g_q - g_s|^2` (a pixel's guide weighs like its
//! three colour channels at `control` = 1), inside the balanced coupling too, so the
//! style's dark cells go where the object is dark, its edges where the object has
//! edges. `control` = 0 is the unguided end.
//!
//! The style's moments are its *motifs'* ([`super::motif`]): a style photographed on a
//! plain background is not remapped to black.
//!
//! **At each level** the match compares both guides blurred at the motif scale
//! (`synthesis.guide_blur` synthesis pixels): a blur that leaves a smooth object's
//! shading mostly whole takes most of a textured style's spread away (at the coarsest
//! of the default's levels a brick wall's luma keeps 6% of its spread and op-art's 12%,
//! a smooth duck's 54% and a fish's 61%). Remapped with the full-resolution moments
//! alone, the object would then ask the style's blurred patches for more contrast than
//! any of them has, and get their extremes: the shading posterised into a few flat
//! areas of the style's darkest and brightest cells (the duck under brick wore a
//! scribbled net of joints; BENCHMARKS.md "The keep benchmark on the default"). So at each level the object's guide (over its pixels of every view)
//! has its spread narrowed to the spread of the level's style patches' guide, as the
//! match sees both, where it is wider ([`Moments::toward`]): Image Analogies' remap,
//! made on the band that is compared. It is never widened (where the style has more
//! contrast at a scale than the object, a photograph's large shapes, the object is not
//! asked for it), and its mean stays the full-resolution remap's (a coarse level's
//! patches reach into the style's border and its filled background, which pull their
//! mean; a self-style test moved the bust's coarse guide 0.1 darker when it followed).
//!
//! It is a part of the synthesis of the [`Channel`] kind ([`super::PARTS`]'
//! `guide`, on when `synthesis.control` > 0): one more channel of every patch, weighted
//! by sqrt(3 guide_weight control) (`synthesis.guide_weight`, 1 unless set, 0.25 in the
//! default preset: below 1 the object's shading asks less of the style's layout, while the
//! edge guide and the detail layer, which follow `control` alone, keep its lines).

use super::SynthesisParams;
use super::motif::{luma, motif_mask};
use super::parts::Channel;
use crate::imageio::Image;
use crate::maths::blur::{Border, gaussian};
use crate::render::fill::{push_pull, unpremultiply};

/// Mean and standard deviation of a set of values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    pub mean: f32,
    pub std: f32,
}

impl Moments {
    /// The moments of the `values` whose `keep` holds (mean 0.5, std 0.25 when none does).
    pub fn of(values: impl Iterator<Item = (f32, bool)>) -> Moments {
        let (mut n, mut s, mut s2) = (0.0f64, 0.0f64, 0.0f64);
        for (v, k) in values {
            if k {
                n += 1.0;
                s += v as f64;
                s2 += (v as f64) * (v as f64);
            }
        }
        if n < 1.0 {
            return Moments {
                mean: 0.5,
                std: 0.25,
            };
        }
        let mean = s / n;
        let var = (s2 / n - mean * mean).max(0.0);
        Moments {
            mean: mean as f32,
            std: var.sqrt().max(1e-3) as f32,
        }
    }

    /// `v` moved from these moments onto `to`'s.
    pub fn remap(&self, v: f32, to: &Moments) -> f32 {
        (v - self.mean) / self.std * to.std + to.mean
    }

    /// The moments of a mixture: each part's moments with its weight (weights > 0).
    pub fn blend(parts: impl Iterator<Item = (Moments, f32)>) -> Moments {
        let (mut w, mut m, mut m2) = (0.0f64, 0.0f64, 0.0f64);
        for (mo, wi) in parts {
            let (mean, std, wi) = (mo.mean as f64, mo.std as f64, wi as f64);
            w += wi;
            m += wi * mean;
            m2 += wi * (std * std + mean * mean);
        }
        if w <= 0.0 {
            return Moments::of(std::iter::empty());
        }
        let mean = m / w;
        Moments {
            mean: mean as f32,
            std: (m2 / w - mean * mean).max(0.0).sqrt().max(1e-3) as f32,
        }
    }

    /// The map a level's guide takes (module docs, "At each level"): these moments (the
    /// object's guide as the level's match sees it) keep their mean, their spread scaled
    /// down to `style`'s where it is wider, never up.
    pub fn toward(&self, style: &Moments) -> impl Fn(f32) -> f32 + use<> {
        let (mean, gain) = (self.mean, (style.std / self.std).min(1.0));
        move |v| (v - mean) * gain + mean
    }
}

/// The style's luma moments over its motif pixels.
pub fn style_moments(style: &Image) -> Moments {
    let motif = motif_mask(style);
    let l = luma(&style.data);
    Moments::of(l.into_iter().zip(motif))
}

/// The source views' guides (`[H W]` each): each view's un-premultiplied luma remapped
/// from the object's moments (over every view's pixels of coverage > 0.5) onto `style`,
/// extended into the uncovered background by push-pull like the colours
/// ([`crate::render::fill`]). `rgb` `[H, W, 3]` and `alpha` `[H, W]` per view, `sizes`
/// (H, W) per view.
pub fn source_guides(
    rgb: &[Vec<f32>],
    alpha: &[Vec<f32>],
    sizes: &[(usize, usize)],
    background: [f32; 3],
    style: &Moments,
) -> Vec<Vec<f32>> {
    let lumas: Vec<Vec<f32>> = rgb
        .iter()
        .zip(alpha)
        .map(|(c, a)| luma(&unpremultiply(c, a, background)))
        .collect();
    let object = Moments::of(
        lumas
            .iter()
            .zip(alpha)
            .flat_map(|(l, a)| l.iter().zip(a).map(|(&v, &a)| (v, a > 0.5))),
    );
    lumas
        .iter()
        .zip(alpha)
        .zip(sizes)
        .map(|((l, a), &(h, w))| {
            let g3: Vec<f32> = l
                .iter()
                .flat_map(|&v| [object.remap(v, style); 3])
                .collect();
            push_pull(&g3, a, h, w).into_iter().step_by(3).collect()
        })
        .collect()
}

/// `x` (`[h w]`) blurred by a Gaussian of standard deviation `sigma` pixels, the edge
/// pixel repeated outside ([`crate::maths::blur`]); `x` itself when `sigma` is 0.
pub fn blur(x: Vec<f32>, (h, w): (usize, usize), sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 {
        return x;
    }
    gaussian(&x, (h, w), sigma, Border::Clamp)
}

/// `x` (`[h w]`) less its [`blur`] of `sigma` pixels: its band pass finer than `sigma`.
pub fn band(x: &[f32], size: (usize, usize), sigma: f32) -> Vec<f32> {
    let base = blur(x.to_vec(), size, sigma);
    x.iter().zip(&base).map(|(a, b)| a - b).collect()
}

/// The structure guide as a part of the synthesis ([`super::PARTS`]).
#[derive(Debug, Clone, Copy)]
pub struct StructureGuide;

impl Channel for StructureGuide {
    fn source(
        &self,
        rgb: &[Vec<f32>],
        alpha: &[Vec<f32>],
        sizes: &[(usize, usize)],
        background: [f32; 3],
        style: &Image,
    ) -> Vec<Vec<f32>> {
        let to = style_moments(style);
        source_guides(rgb, alpha, sizes, background, &to)
    }

    fn style(&self, sized: &Image, p: &SynthesisParams) -> Vec<f32> {
        blur(luma(&sized.data), (sized.height, sized.width), p.guide_blur)
    }

    fn at_level(&self, pooled: Vec<f32>, size: (usize, usize), p: &SynthesisParams) -> Vec<f32> {
        blur(pooled, size, p.guide_blur)
    }

    fn weight(&self, p: &SynthesisParams) -> f32 {
        (3.0 * p.guide_weight * p.control).sqrt()
    }

    fn matched_at_level(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guide_weight_scales_the_structure_guide_alone() {
        let p = |guide_weight: f32, control: f32| SynthesisParams {
            guide_weight,
            control,
            edges: 2.0,
            detail: 0.75,
            ..SynthesisParams::default()
        };
        // The guide's weight is sqrt(3 guide_weight control); 1 leaves it at the control's.
        assert_eq!(StructureGuide.weight(&p(1.0, 0.5)), 1.5f32.sqrt());
        assert_eq!(StructureGuide.weight(&p(0.25, 1.0)), 0.75f32.sqrt());
        assert_eq!(StructureGuide.weight(&p(0.0, 1.0)), 0.0);
        // The edge guide and the detail layer follow the control alone.
        let edges = super::super::edges::EdgeGuide;
        assert_eq!(edges.weight(&p(0.25, 1.0)), edges.weight(&p(1.0, 1.0)));
        assert_eq!(
            super::super::detail::weight(&p(0.25, 1.0)),
            super::super::detail::weight(&p(1.0, 1.0))
        );
        // At no share the guide is off (no channel to carry), the edge guide still on.
        let on = |p: &SynthesisParams| -> Vec<&str> {
            super::super::active_parts(p)
                .iter()
                .map(|k| k.name)
                .collect()
        };
        let none = SynthesisParams {
            control: 1.0,
            guide_weight: 0.0,
            edges: 2.0,
            ..SynthesisParams::default()
        };
        assert!(!on(&none).contains(&"guide") && on(&none).contains(&"edges"));
        assert!(
            on(&SynthesisParams {
                guide_weight: 0.25,
                ..none
            })
            .contains(&"guide")
        );
    }

    #[test]
    fn the_styles_moments_are_its_motifs() {
        // A textured disc on black: the moments are the disc's, not the black's.
        let disc = super::super::motif::tests::disc();
        let mo = style_moments(&disc);
        assert!(mo.mean > 0.3, "{mo:?}");
    }

    #[test]
    fn the_source_guide_has_the_styles_moments_on_the_object() {
        let (h, w) = (16, 16);
        let rgb: Vec<f32> = (0..h * w)
            .flat_map(|i| [(i % w) as f32 / 16.0; 3])
            .collect();
        let alpha = vec![1.0f32; h * w];
        let to = Moments {
            mean: 0.2,
            std: 0.05,
        };
        let g = source_guides(&[rgb], &[alpha], &[(h, w)], [0.0; 3], &to);
        let got = Moments::of(g[0].iter().map(|&v| (v, true)));
        assert!((got.mean - 0.2).abs() < 1e-4 && (got.std - 0.05).abs() < 1e-4);
        // Monotone in the luma: brighter pixels stay brighter.
        assert!(g[0][15] > g[0][0]);
    }

    fn mo(mean: f32, std: f32) -> Moments {
        Moments { mean, std }
    }

    #[test]
    fn a_blend_has_the_moments_of_its_mixture() {
        // Two point masses, 0 (weight 3) and 1 (weight 1): mean 1/4, variance 3/16.
        let zero = mo(0.0, 0.0);
        let one = mo(1.0, 0.0);
        let b = Moments::blend([(zero, 3.0), (one, 1.0)].into_iter());
        assert!((b.mean - 0.25).abs() < 1e-6 && (b.std - 0.1875f32.sqrt()).abs() < 1e-6);
        // Against the moments of the values themselves.
        let v = [0.0f32, 0.0, 0.0, 1.0];
        let direct = Moments::of(v.iter().map(|&x| (x, true)));
        assert!((b.mean - direct.mean).abs() < 1e-6 && (b.std - direct.std).abs() < 1e-6);
    }

    #[test]
    fn the_level_map_narrows_the_spread_and_never_widens_it() {
        let object = mo(0.5, 0.2);
        let narrow = mo(0.4, 0.05);
        let f = object.toward(&narrow);
        // The object's mean stays, a deviation of one std becomes the style's.
        assert!((f(0.5) - 0.5).abs() < 1e-6 && (f(0.7) - 0.55).abs() < 1e-6);
        let wide = mo(0.6, 0.4);
        let g = object.toward(&wide);
        // A wider style leaves the guide as it is.
        assert!((g(0.5) - 0.5).abs() < 1e-6 && (g(0.7) - 0.7).abs() < 1e-6);
    }
}
