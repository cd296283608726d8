//! The motif scale from the object's size on screen (`synthesis.motifs_per_part`): the
//! style's size chosen so that its motif period fits that many times across the object's
//! typical part.
//!
//! - **The style's period** `P` (px at a shorter side of [`REFERENCE_SIDE`]): the peak of
//!   its windowed luminance spectrum, the band with the most power per quarter octave
//!   ([`crate::metrics::spectrum::peak`], the same measure `evaluate` reports for the
//!   views' motif scale).
//! - **The object's part width** `W` (render px): inside the object's mask (coverage over
//!   one half) each pixel's distance to the nearest pixel outside it (the frame's border
//!   counts as outside), by the two-pass chamfer transform with steps 1 and sqrt 2
//!   (Borgefors 1986; within 8% of the Euclidean distance), less half a pixel (to the
//!   mask's edge); `W` is four times the mean distance, the width of a strip exactly (a disc of diameter D gives 2D/3), the median
//!   over the views.
//! - **The size**: `style_size = REFERENCE_SIDE (W / n) / P` for `n` motifs per part,
//!   rounded and clamped to [[`MIN_SIZE`], [`MAX_SIZE`]].
//!
//! Why: at a fixed 256 px a smooth 120 px armadillo wears one stained-glass cell per limb
//! and no leading, while a 512 px bust wears the same cells with their outlines (issue 53);
//! the motif has to be small against the object's parts, not against the frame.

use crate::imageio::Image;
use crate::metrics::spectrum::{peak, radial_spectrum, windowed_signal};

/// The style's shorter side at which its period is measured.
pub const REFERENCE_SIDE: usize = 256;
/// The smallest size chosen (a level-8 synthesis pixel then still covers 8 style px).
pub const MIN_SIZE: usize = 64;
/// The largest size chosen.
pub const MAX_SIZE: usize = 1024;

/// What the motif scale was chosen from, and the size (the end logs it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotifScale {
    /// The style's motif period at [`REFERENCE_SIDE`], px.
    pub period: f32,
    /// The object's part width on screen, px (median over the views).
    pub part: f32,
    /// The style's shorter side chosen, px.
    pub style_size: usize,
}

/// The style's motif period in px at a shorter side of [`REFERENCE_SIDE`] (module docs;
/// `None` for a flat style).
pub fn period(style: &Image) -> Option<f32> {
    let img = style.with_shorter_side(REFERENCE_SIDE);
    let s = windowed_signal(&img);
    peak(&radial_spectrum(&s, img.width, img.height)).map(|f| (1.0 / f) as f32)
}

/// Four times the mean chamfer distance to the outside over the mask `alpha > 0.5`
/// (`[h w]`; module docs); 0 for an empty mask.
pub fn part_width(alpha: &[f32], (h, w): (usize, usize)) -> f32 {
    const D: f32 = std::f32::consts::SQRT_2;
    let mut d: Vec<f32> = alpha
        .iter()
        .map(|&a| if a > 0.5 { f32::INFINITY } else { 0.0 })
        .collect();
    // Outside the frame is outside the object.
    let at = |d: &[f32], y: isize, x: isize| -> f32 {
        if y < 0 || x < 0 || y >= h as isize || x >= w as isize {
            0.0
        } else {
            d[y as usize * w + x as usize]
        }
    };
    for y in 0..h as isize {
        for x in 0..w as isize {
            let i = y as usize * w + x as usize;
            if d[i] > 0.0 {
                let m = (at(&d, y, x - 1) + 1.0)
                    .min(at(&d, y - 1, x) + 1.0)
                    .min(at(&d, y - 1, x - 1) + D)
                    .min(at(&d, y - 1, x + 1) + D);
                d[i] = d[i].min(m);
            }
        }
    }
    for y in (0..h as isize).rev() {
        for x in (0..w as isize).rev() {
            let i = y as usize * w + x as usize;
            if d[i] > 0.0 {
                let m = (at(&d, y, x + 1) + 1.0)
                    .min(at(&d, y + 1, x) + 1.0)
                    .min(at(&d, y + 1, x + 1) + D)
                    .min(at(&d, y + 1, x - 1) + D);
                d[i] = d[i].min(m);
            }
        }
    }
    // A pixel's distance to the outside pixel's centre, less half a pixel: to the edge.
    let inside: Vec<f64> = d
        .iter()
        .filter(|&&v| v > 0.0)
        .map(|&v| f64::from(v) - 0.5)
        .collect();
    if inside.is_empty() {
        return 0.0;
    }
    (4.0 * inside.iter().sum::<f64>() / inside.len() as f64) as f32
}

/// The style size that fits `n` motifs of `style` across the object's parts in the
/// views' coverage `alpha` (`[H W]` per view of `sizes` (H, W)); `None` when the style
/// is flat or no view covers the object.
pub fn choose(
    style: &Image,
    alpha: &[Vec<f32>],
    sizes: &[(usize, usize)],
    n: f32,
) -> Option<MotifScale> {
    let period = period(style)?;
    let mut parts: Vec<f32> = alpha
        .iter()
        .zip(sizes)
        .map(|(a, &s)| part_width(a, s))
        .filter(|&p| p > 0.0)
        .collect();
    if parts.is_empty() || n.is_nan() || n <= 0.0 {
        return None;
    }
    parts.sort_by(f32::total_cmp);
    let part = parts[parts.len() / 2];
    let size = (REFERENCE_SIDE as f32 * (part / n) / period).round() as usize;
    Some(MotifScale {
        period,
        part,
        style_size: size.clamp(MIN_SIZE, MAX_SIZE),
    })
}

/// The styles' size: `texture.style_size` (`given`), or with `synthesis.motifs_per_part`
/// the size that fits that many motifs of the first region's heaviest style across the
/// object's parts in the source views (module docs), logged with what it came from.
pub fn style_size(
    p: &super::SynthesisParams,
    given: usize,
    regions: &[super::regions::RegionStyle<'_>],
    s: &crate::render::source::SourceViews,
) -> usize {
    if p.motifs_per_part <= 0.0 {
        return given;
    }
    let style = regions
        .first()
        .and_then(|r| r.styles.iter().max_by(|a, b| a.1.total_cmp(&b.1)))
        .map(|x| x.0);
    let sizes = vec![(s.height, s.width); s.alpha.len()];
    match style.and_then(|st| choose(st, &s.alpha, &sizes, p.motifs_per_part)) {
        Some(m) => {
            tracing::info!(
                "motif scale: the style at {} px (its motif period {:.1} px at {} px; the object's parts {:.0} px wide on screen, {} motifs across; synthesis.motifs_per_part, 0 for texture.style_size)",
                m.style_size,
                m.period,
                REFERENCE_SIDE,
                m.part,
                p.motifs_per_part
            );
            m.style_size
        }
        None => {
            tracing::warn!(
                "motif scale: no period in the style or no object in the views; texture.style_size {given} px"
            );
            given
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip's part width is its width; a disc's two thirds of its diameter.
    #[test]
    fn part_widths_of_a_strip_and_a_disc() {
        let (h, w) = (120, 160);
        let strip: Vec<f32> = (0..h * w)
            .map(|i| {
                if (50..70).contains(&(i / w)) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let s = part_width(&strip, (h, w));
        assert!((s - 20.0).abs() < 1.0, "strip of 20 px: {s}");
        let disc: Vec<f32> = (0..h * w)
            .map(|i| {
                let (y, x) = ((i / w) as f32 - 60.0, (i % w) as f32 - 80.0);
                if y.hypot(x) < 40.0 { 1.0 } else { 0.0 }
            })
            .collect();
        let d = part_width(&disc, (h, w));
        assert!(
            (d - 80.0 * 2.0 / 3.0).abs() < 0.08 * 53.3,
            "disc of 80 px: {d}"
        );
        assert_eq!(part_width(&vec![0.0; h * w], (h, w)), 0.0);
    }

    /// Stripes of period p at 256 px give p; the size then scales with the part width
    /// and against the motifs per part, within its bounds.
    #[test]
    fn the_size_follows_the_part_and_the_period() {
        let stripes = |p: f32| {
            Image::from_fn(256, 256, |x, _| {
                let v = 0.5 + 0.4 * (2.0 * std::f32::consts::PI * x as f32 / p).sin();
                [v, v, v]
            })
        };
        for p in [8.0f32, 16.0, 32.0] {
            let got = period(&stripes(p)).unwrap();
            assert!((got / p - 1.0).abs() < 0.1, "period {p}: {got}");
        }
        let (h, w) = (100, 1000);
        let band = |lo: usize, hi: usize| -> Vec<f32> {
            (0..h * w)
                .map(|i| {
                    if (lo..hi).contains(&(i / w)) {
                        1.0
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let style = stripes(16.0);
        let size = |a: Vec<f32>, n: f32| choose(&style, &[a], &[(h, w)], n).unwrap();
        let wide = size(band(20, 80), 4.0);
        let thin = size(band(40, 60), 4.0);
        assert!((wide.part / 60.0 - 1.0).abs() < 0.03, "{wide:?}");
        assert!(thin.style_size < wide.style_size, "{thin:?} {wide:?}");
        // 60 px / 4 motifs = 15 px on screen for a 16 px period at 256: 240 px.
        let want = 256.0 * (wide.part / 4.0) / wide.period;
        assert_eq!(wide.style_size, want.round() as usize);
        assert!(size(band(20, 80), 2.0).style_size > wide.style_size);
        assert_eq!(size(band(45, 55), 40.0).style_size, MIN_SIZE);
        assert!(choose(&style, &[vec![0.0; h * w]], &[(h, w)], 4.0).is_none());
        assert!(
            choose(
                &Image::filled(64, 64, [0.5; 3]),
                &[band(20, 80)],
                &[(h, w)],
                4.0
            )
            .is_none()
        );
        for bad in [-1.0, 101.0, f32::NAN] {
            let p = super::super::SynthesisParams {
                motifs_per_part: bad,
                ..Default::default()
            };
            assert!(p.validate().is_err(), "motifs_per_part {bad}");
        }
    }
}
