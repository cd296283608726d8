//! The edge guide (`synthesis.edges`, 2 in the default preset): the object's fine
//! structure as one more channel of the match, so that the style's *own* edges (a
//! mosaic's leading, a wall's joints, a stroke's border) are chosen where the object has
//! its edges, with their polarity. It is the edge guide of EbSynth (Jamriska et al. 2019)
//! and StyLit (Fiser et al. 2016) as a cost, where the detail layer ([`super::detail`])
//! lays the object's own lines over the texture.
//!
//! **The weight** is `sqrt(3 edges control)`: like the detail layer's, it follows
//! `synthesis.control`, so `control = 0` is still the unguided end.
//!
//! **The channel.** At every level a band pass in synthesis pixels, a luma less its blur
//! of [`EDGE_SIGMA`] synthesis pixels. The style's is its own luma's. The object's is its
//! structure guide's (its luma remapped to the style's, [`super::guide::source_guides`])
//! times one gain, so that the strongest tenth of its band pass over the object at full
//! resolution is as strong as the style's (clamped to [1 / [`MAX_GAIN`], [`MAX_GAIN`]]):
//! a smooth toy's faint creases ask for the style's real edges.
//!
//! **One-sided.** A symmetric cost asks for no edge where the object has none: on a
//! smooth body it picks the style's flat patches and the style's texture fades (measured:
//! the wall's joints on the fish, style texture 0.62 -> 0.33, docs/structure-guide-history.md).
//! So the object imposes its band pass only at its own strongest edges, the pixels of
//! each view whose `|band|` is at least its [`IMPOSED_QUANTILE`] over the object,
//! widened by a blur of one pixel; everywhere else a query's channel is the band pass of
//! its *current* colours ([`super::parts::Channel::imposed`], made once per level), which the style patch
//! that matches those colours matches too: the texture is free there.

use super::detail::quantile;
use super::guide::{band, blur, source_guides, style_moments};
use super::motif::{LUMA, luma};
use super::parts::Channel;
use super::{OBJECT, SynthesisParams};
use crate::imageio::Image;
use ndarray::ArrayView3;

/// The band's blur, in synthesis pixels at every level.
pub const EDGE_SIGMA: f32 = 2.0;
/// The quantile of the band-pass magnitudes matched between the object and the style.
const GAIN_QUANTILE: f32 = 0.9;
/// The gain's bound, both ways.
const MAX_GAIN: f32 = 4.0;
/// The object imposes its band pass where its `|band|` is at least this quantile over
/// the view's object pixels (its strongest fifth).
pub const IMPOSED_QUANTILE: f32 = 0.8;

/// The gain that brings the object's band pass (`object`: its magnitudes over the
/// object's pixels) to the style's (`style`: its magnitudes), module docs.
fn gain(object: Vec<f32>, style: Vec<f32>) -> f32 {
    match (
        quantile(style, GAIN_QUANTILE),
        quantile(object, GAIN_QUANTILE),
    ) {
        (Some(s), Some(o)) if o > 0.0 && s > 1e-6 && s.is_finite() => {
            (s / o).clamp(1.0 / MAX_GAIN, MAX_GAIN)
        }
        _ => 1.0,
    }
}

/// The edge guide as a part of the synthesis ([`super::PARTS`]).
#[derive(Debug, Clone, Copy)]
pub struct EdgeGuide;

impl Channel for EdgeGuide {
    fn source(
        &self,
        rgb: &[Vec<f32>],
        alpha: &[Vec<f32>],
        sizes: &[(usize, usize)],
        background: [f32; 3],
        style: &Image,
    ) -> Vec<Vec<f32>> {
        let g = source_guides(rgb, alpha, sizes, background, &style_moments(style));
        let object: Vec<f32> = (g.iter().zip(alpha).zip(sizes))
            .flat_map(|((g, a), &size)| {
                let b = band(g, size, EDGE_SIGMA);
                (b.into_iter().zip(a.iter()))
                    .filter(|(_, a)| **a > OBJECT)
                    .map(|(d, _)| d.abs())
                    .collect::<Vec<_>>()
            })
            .collect();
        let s = band(&luma(&style.data), (style.height, style.width), EDGE_SIGMA);
        let k = gain(object, s.into_iter().map(f32::abs).collect());
        tracing::debug!("edge guide: gain {k:.3}");
        g.into_iter()
            .map(|g| g.into_iter().map(|v| v * k).collect())
            .collect()
    }

    fn style(&self, sized: &Image, _: &SynthesisParams) -> Vec<f32> {
        band(&luma(&sized.data), (sized.height, sized.width), EDGE_SIGMA)
    }

    fn at_level(&self, pooled: Vec<f32>, size: (usize, usize), _: &SynthesisParams) -> Vec<f32> {
        band(&pooled, size, EDGE_SIGMA)
    }

    fn weight(&self, p: &SynthesisParams) -> f32 {
        (3.0 * p.edges * p.control).sqrt()
    }

    fn imposed(&self, frozen: &[f32], alpha: &[f32], size: (usize, usize)) -> Option<Vec<f32>> {
        let mags: Vec<f32> = (frozen.iter().zip(alpha))
            .filter(|(_, a)| **a > OBJECT)
            .map(|(v, _)| v.abs())
            .collect();
        let t = quantile(mags, IMPOSED_QUANTILE)?;
        let strong: Vec<f32> = frozen
            .iter()
            .map(|v| if v.abs() >= t { 1.0 } else { 0.0 })
            .collect();
        Some(
            blur(strong, size, 1.0)
                .into_iter()
                .map(|m| (2.0 * m).min(1.0))
                .collect(),
        )
    }

    fn of_current(&self, current: ArrayView3<'_, f32>) -> Vec<f32> {
        let (_, h, w) = current.dim();
        let l: Vec<f32> = (0..h * w)
            .map(|i| {
                let (y, x) = (i / w, i % w);
                (0..3).map(|c| LUMA[c] * current[[c, y, x]]).sum()
            })
            .collect();
        band(&l, (h, w), EDGE_SIGMA)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ends::patches::parts::follow;
    use ndarray::Array3;

    /// A view `[3, h, w]` of one grey level per pixel.
    fn grey(h: usize, w: usize, f: impl Fn(usize, usize) -> f32) -> Array3<f32> {
        Array3::from_shape_fn((3, h, w), |(_, y, x)| f(y, x))
    }

    #[test]
    fn the_object_imposes_its_edges_and_leaves_the_rest_to_the_texture() {
        // The object: a vertical step at x = 8 (its band pass strong there, about zero
        // elsewhere). The current texture: horizontal stripes every 4 rows.
        let (h, w) = (16, 16);
        let step: Vec<f32> = (0..h * w)
            .map(|i| if i % w < 8 { 0.2 } else { 0.8 })
            .collect();
        let frozen = band(&step, (h, w), EDGE_SIGMA);
        let current = grey(h, w, |y, _| if (y / 2) % 2 == 0 { 0.3 } else { 0.7 });
        let alpha = vec![1.0; h * w];
        let share = EdgeGuide.imposed(&frozen, &alpha, (h, w)).unwrap();
        let got = follow(&frozen, &share, &EdgeGuide.of_current(current.view()));
        let own = band(
            &current
                .index_axis(ndarray::Axis(0), 0)
                .iter()
                .copied()
                .collect::<Vec<_>>(),
            (h, w),
            EDGE_SIGMA,
        );
        // At the step the object's band pass, with its sign.
        for y in 0..h {
            assert_eq!(got[y * w + 7], frozen[y * w + 7], "row {y}");
            assert!(got[y * w + 7] < 0.0 && got[y * w + 8] > 0.0);
        }
        // Far from it the texture's own band pass (the stripes), not the object's zero.
        for y in 0..h {
            for x in [0, 1, 14, 15] {
                let i = y * w + x;
                assert!((got[i] - own[i]).abs() < 1e-6, "({y}, {x})");
            }
        }
        assert!(own.iter().map(|v| v.abs()).fold(0.0, f32::max) > 0.05);
    }

    #[test]
    fn a_faint_object_is_raised_to_the_styles_edges_and_a_strong_one_lowered() {
        let faint = vec![0.01f32; 100];
        let style: Vec<f32> = vec![0.1; 100];
        assert!((gain(faint.clone(), style.clone()) - MAX_GAIN).abs() < 1e-6);
        let near: Vec<f32> = vec![0.05; 100];
        assert!((gain(near, style.clone()) - 2.0).abs() < 1e-5);
        let strong = vec![1.0f32; 100];
        assert!((gain(strong, style) - 1.0 / MAX_GAIN).abs() < 1e-6);
        // A flat style or object: no gain.
        assert_eq!(gain(faint, vec![0.0; 100]), 1.0);
        assert_eq!(gain(vec![0.0; 10], vec![0.1; 10]), 1.0);
    }

    #[test]
    fn the_edge_guide_follows_the_control_so_control_zero_is_unguided() {
        let names = |edges: f32, control: f32| -> Vec<&str> {
            let p = SynthesisParams {
                edges,
                control,
                ..SynthesisParams::default()
            };
            super::super::active_parts(&p)
                .iter()
                .map(|k| k.name)
                .collect()
        };
        assert!(names(1.0, 1.0).contains(&"edges"));
        assert!(!names(1.0, 0.0).contains(&"edges"));
        assert!(!names(0.0, 1.0).contains(&"edges"));
        let p = SynthesisParams {
            edges: 2.0,
            control: 0.5,
            ..SynthesisParams::default()
        };
        assert!((EdgeGuide.weight(&p) - 3.0f32.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn the_style_channel_is_its_luma_band_pass() {
        let (h, w) = (12, 12);
        let data: Vec<f32> = (0..h * w)
            .flat_map(|i| [if (i % w) < 6 { 0.0 } else { 1.0 }; 3])
            .collect();
        let img = Image {
            width: w,
            height: h,
            data,
        };
        let p = SynthesisParams::default();
        let got = EdgeGuide.style(&img, &p);
        let want = band(&luma(&img.data), (h, w), EDGE_SIGMA);
        assert_eq!(got, want);
        // A step: dark side below zero, bright side above, flat far away.
        assert!(got[5] < 0.0 && got[6] > 0.0 && got[0].abs() < got[5].abs());
    }
}
