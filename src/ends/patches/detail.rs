//! The detail layer of the patch synthesis (issue 53): the object's fine structure laid
//! over the synthesised texture instead of asked of it.
//!
//! A guide that asks every patch to match the object's luma pixel for pixel keeps the
//! object's edges but spends the style's own edges (a mosaic's outlines, a window's
//! leading) where the object is smooth: they do not match a smooth luma. Here the two
//! are split by scale, as a painter would: the structure guide looks at the object's
//! shading only (its luma blurred at the motif scale, `synthesis.guide_blur`,
//! [`super::guide`]), and the object's fine structure (its edges, lettering, the lines of
//! a face) is the *detail layer*
//! `D = alpha (g - G_sigma * g)`, `g` the source's luma remapped to the style's moments
//! ([`super::guide::source_guides`]), `G_sigma` a Gaussian of `synthesis.detail_blur`
//! render pixels. The synthesis matches and votes on `render - k D` (the texture, with
//! `k` = `synthesis.detail`), and the colour fit's target is the vote plus `k D` (on
//! every channel, as luminance): the style's texture with the object's detail over it.
//! The base-detail split is the one of detail-preserving tone mapping (Durand & Dorsey
//! 2002); in guided synthesis it is StyLit's and EbSynth's edge guide turned from a cost
//! into a layer.
//!
//! **Line weight.** Remapped to the style's global luma moments, a smooth object's detail
//! (a fish's eye and fin creases, a duck's bill) is far fainter than a busy style's own
//! edges (a wall's mortar, op-art bands), and the texture drowns it. So the layer is
//! raised until its strongest tenth (the [`LINE_QUANTILE`] of `|D|` over the object's
//! pixels of every view) is as strong as the same quantile of the style's own band-pass
//! (its luma minus that luma blurred alike, the style at the motif scale), by a gain
//! `clamp(q_style / q_object, 1 / synthesis.line_weight, synthesis.line_weight)`: an
//! illustrator's line weight, matched to the style's. It works both ways: where the
//! object's fine structure is stronger than anything in the style (a plant's dense
//! leaf edges under a smooth photograph) the layer is lowered, at most to
//! `1 / line_weight`, so the object's lines do not outweigh the style's texture; a
//! style with no band-pass at all has nothing to match and leaves it at 1. One gain per
//! style for all views, so they agree. Measured in BENCHMARKS.md "Line weight".
//!
//! **Ink** (`synthesis.ink`). The line weight matches the layer's strongest tenth over
//! the whole object, which on a smooth object is its outline's shading; the creases
//! inside it (a duck's neck, a fish's eye and gills) stay fainter than a brick wall's
//! mortar. So the interior's own strongest tenth (the object more than twice the layer's
//! blur from its outline, where the outline's band-pass does not reach) is raised, with
//! a pixel or two around it, until it is `ink` times the style's typical edge (the
//! [`INK_STYLE_QUANTILE`] of its band-pass), never lowered: an illustrator inking the
//! creases, and only them. One gain per style for all views. Measured in BENCHMARKS.md
//! "Line weight".
//!
//! **Shading band** (`synthesis.shade_blur`, off by default): the layer can also hold the
//! object's shading, `alpha (G_detail * g - G_shade * g)`, at the style's contrast and
//! without the line weight's gain. With the guide weak (`control` 0.1, `detail` 10 so
//! `k` stays 1) the synthesis then lays the style out as if unguided (op-art's bands, a
//! wall's rows across a smooth object) and the layer shades it, where the guide would
//! have posterised the shading into areas of the style's colours (docs/patch-prior.md "Why
//! the op-art bands come out as blobs").

use super::SynthesisParams;
use super::guide::{band, blur, source_guides, style_moments};
use crate::imageio::Image;
use crate::metrics::interior::erode;
use rayon::prelude::*;

/// The detail layer's weight `k`: `synthesis.detail` times the structure's weight
/// `synthesis.control` (0: the unguided end, no guide and no detail).
pub fn weight(p: &SynthesisParams) -> f32 {
    p.detail * p.control
}

/// The quantile of `|detail|` that the line weight matches: the strongest tenth.
pub const LINE_QUANTILE: f32 = 0.9;
/// A style's band-pass quantile at most this is flat: no line weight to match (gain 1).
pub const FLAT: f32 = 1e-6;

/// The detail layer of every source view (`[H W]` each; module docs), from the frozen
/// source views (`rgb` `[H, W, 3]`, `alpha` `[H, W]`, `sizes` (H, W), composited over
/// `background`) remapped to `style`'s luma moments, times the line weight's gain
/// ([`line_gain`]; `style_size`: the style's shorter side in render pixels) measured over
/// the pixels of the region `within` (its share of each view's pixels; empty: the whole
/// object): a region's lines are matched to its own style where it lies.
pub fn source_detail(
    rgb: &[Vec<f32>],
    alpha: &[Vec<f32>],
    (sizes, style_size): (&[(usize, usize)], usize),
    background: [f32; 3],
    (style, within): (&Image, &[Vec<f32>]),
    p: &SynthesisParams,
) -> Vec<Vec<f32>> {
    let g = source_guides(rgb, alpha, sizes, background, &style_moments(style));
    let (mut d, bases): (Vec<Vec<f32>>, Vec<Vec<f32>>) = g
        .into_par_iter()
        .zip(alpha)
        .zip(sizes)
        .map(|((g, a), &size)| {
            let base = blur(g.clone(), size, p.detail_blur);
            let d = g
                .iter()
                .zip(&base)
                .zip(a)
                .map(|((&v, &b), &a)| a * (v - b))
                .collect();
            (d, base)
        })
        .unzip();
    let at = object_pixels(alpha, within);
    if p.line_weight > 1.0 {
        let k = line_gain(&d, &at, style, style_size, p);
        tracing::debug!("detail layer: line weight gain {k:.3}");
        d.iter_mut().flatten().for_each(|v| *v *= k);
    }
    if p.ink > 0.0 {
        ink(&mut d, &at, sizes, (style, style_size), p);
    }
    if p.shade_blur > 0.0 {
        (d.par_iter_mut().zip(bases).zip(alpha).zip(sizes)).for_each(|(((d, base), a), &size)| {
            let coarse = blur(base.clone(), size, shade_sigma(p));
            for (((d, b), c), a) in d.iter_mut().zip(&base).zip(&coarse).zip(a) {
                *d += a * (b - c);
            }
        });
    }
    d
}

/// Each view's coverage, times the region's share of each pixel when `within` is not
/// empty: the pixels a region's line weight and ink are measured over.
fn object_pixels<'a>(
    alpha: &'a [Vec<f32>],
    within: &[Vec<f32>],
) -> std::borrow::Cow<'a, [Vec<f32>]> {
    if within.is_empty() {
        return std::borrow::Cow::Borrowed(alpha);
    }
    alpha
        .iter()
        .zip(within)
        .map(|(a, c)| a.iter().zip(c).map(|(a, c)| a * c).collect())
        .collect()
}

/// The quantile of the style's band-pass that the ink matches: its typical edge.
pub const INK_STYLE_QUANTILE: f32 = 0.75;
/// The ink's reach around an edge pixel: the standard deviation (render pixels) of the
/// blur that softens the edges' mask ...
const INK_SPREAD: f32 = 2.0;
/// ... and the gain on that blur, so that the mask is 1 on and next to an edge.
const INK_FILL: f32 = 4.0;

/// The ink (module docs): the pixels of the object's [`interior`] (`alpha` > 0.5 and
/// more than twice `synthesis.detail_blur` from the outline, every view) where `|d|` is
/// at least its [`LINE_QUANTILE`] there (`q_object`), softened by [`INK_SPREAD`], get the
/// gain `max(1, synthesis.ink q_style / q_object)`, `q_style` the [`INK_STYLE_QUANTILE`]
/// of the style's band-pass ([`style_band`]); the rest of the layer is as it was.
/// Returns the gain (1: nothing changed).
fn ink(
    d: &mut [Vec<f32>],
    alpha: &[Vec<f32>],
    sizes: &[(usize, usize)],
    (style, style_size): (&Image, usize),
    p: &SynthesisParams,
) -> f32 {
    let reach = (2.0 * p.detail_blur).ceil() as usize;
    let inner: Vec<Vec<f32>> = (alpha.iter().zip(sizes))
        .map(|(a, &size)| interior(a, size, reach))
        .collect();
    let (Some(s), Some(o)) = (
        quantile(style_band(style, style_size, p), INK_STYLE_QUANTILE),
        quantile(object_band(d, &inner), LINE_QUANTILE),
    ) else {
        return 1.0;
    };
    if !(o > 0.0 && s.is_finite()) {
        return 1.0;
    }
    let f = (p.ink * s / o).max(1.0);
    tracing::debug!("detail layer: ink gain {f:.3} (style {s:.4}, object's edges {o:.4})");
    if f <= 1.0 {
        return 1.0;
    }
    (d.par_iter_mut().zip(&inner).zip(sizes)).for_each(|((d, a), &size)| {
        let edges: Vec<f32> = d
            .iter()
            .zip(a)
            .map(|(v, &a)| f32::from(u8::from(a > 0.5 && v.abs() >= o)))
            .collect();
        let mask = blur(edges, size, INK_SPREAD);
        for (v, m) in d.iter_mut().zip(mask) {
            *v *= 1.0 + (f - 1.0) * (INK_FILL * m).min(1.0);
        }
    });
    f
}

/// The pixels of coverage > 0.5 whose square of half-side `r` lies in the coverage and
/// in the view (1, else 0; the evaluation's [`erode`]): the object away from its
/// outline, whose own band-pass reaches about twice the layer's blur inward.
fn interior(alpha: &[f32], (h, w): (usize, usize), r: usize) -> Vec<f32> {
    let inside: Vec<bool> = alpha.iter().map(|&a| a > 0.5).collect();
    erode(&inside, w, h, r)
        .into_iter()
        .map(|b| f32::from(u8::from(b)))
        .collect()
}

/// `|band-pass|` of the style's luma at `style_size` (its shorter side in render pixels):
/// the luma minus that luma blurred by `synthesis.detail_blur`, as the views' detail is.
fn style_band(style: &Image, style_size: usize, p: &SynthesisParams) -> Vec<f32> {
    let st = style.with_shorter_side(style_size.max(1));
    let l = super::motif::luma(&st.data);
    band(&l, (st.height, st.width), p.detail_blur)
        .into_iter()
        .map(f32::abs)
        .collect()
}

/// `|d|` over the pixels of coverage > 0.5 of every view.
fn object_band(d: &[Vec<f32>], alpha: &[Vec<f32>]) -> Vec<f32> {
    d.iter()
        .zip(alpha)
        .flat_map(|(d, a)| {
            d.iter()
                .zip(a)
                .filter(|(_, a)| **a > 0.5)
                .map(|(d, _)| d.abs())
        })
        .collect()
}

/// The blur that takes the layer's base (`G_detail_blur * g`) to `G_shade_blur * g`:
/// Gaussians compose by their variances.
fn shade_sigma(p: &SynthesisParams) -> f32 {
    (p.shade_blur * p.shade_blur - p.detail_blur * p.detail_blur).sqrt()
}

/// The line weight's gain (module docs): `clamp(q_style / q_object, 1 / line_weight,
/// line_weight)` (1 for a style whose quantile is at most [`FLAT`]), `q` the
/// [`LINE_QUANTILE`] of `|band-pass|` of the style's luma (at `style_size`, its shorter
/// side in render pixels, blurred by `synthesis.detail_blur` as the views are) and of the
/// detail `d` over the pixels of coverage > 0.5 of every view; 1 where either is empty
/// or the object has no detail.
pub fn line_gain(
    d: &[Vec<f32>],
    alpha: &[Vec<f32>],
    style: &Image,
    style_size: usize,
    p: &SynthesisParams,
) -> f32 {
    match (
        quantile(style_band(style, style_size, p), LINE_QUANTILE),
        quantile(object_band(d, alpha), LINE_QUANTILE),
    ) {
        (Some(s), Some(o)) if o > 0.0 && s > FLAT && s.is_finite() => {
            (s / o).clamp(1.0 / p.line_weight, p.line_weight)
        }
        _ => 1.0,
    }
}

/// The `q` quantile of `v` (the value at rank `floor((n - 1) q)`); `None` when empty.
pub(super) fn quantile(mut v: Vec<f32>, q: f32) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let k = ((v.len() - 1) as f32 * q) as usize;
    Some(*v.select_nth_unstable_by(k, f32::total_cmp).1)
}

/// The detail layer the synthesis lays over its texture (`[H W]` per view): with one
/// region (`cover` empty) its [`source_detail`] times its guidance scale; with several,
/// each pixel the sum over the regions of their share of it (`cover[view]`) times their
/// guidance scale times their detail (each remapped to the region's own style, its line
/// weight measured over the region's own pixels).
/// `regions`: (the region's style, its guidance scale, its cover per view).
pub fn layer(
    rgb: &[Vec<f32>],
    alpha: &[Vec<f32>],
    (sizes, style_size): (&[(usize, usize)], usize),
    background: [f32; 3],
    regions: &[(&Image, f32, &[Vec<f32>])],
    p: &SynthesisParams,
) -> Vec<Vec<f32>> {
    let mut out: Vec<Vec<f32>> = sizes.iter().map(|&(h, w)| vec![0.0; h * w]).collect();
    for &(style, g, cover) in regions {
        let d = source_detail(
            rgb,
            alpha,
            (sizes, style_size),
            background,
            (style, cover),
            p,
        );
        for (v, (o, d)) in out.iter_mut().zip(d).enumerate() {
            for (i, (o, d)) in o.iter_mut().zip(d).enumerate() {
                let share = cover.get(v).map_or(1.0, |c| c[i]);
                *o += share * g * d;
            }
        }
    }
    out
}

/// `targets` with `k` times the detail `d` laid over them ([`add`]), each value then
/// clamped to [0, 1] (a colour the renders, and the `.spz` codec, can hold: a dark line
/// on a dark cell stays black, not below).
pub fn lay(targets: &mut [Vec<f32>], d: &[Vec<f32>], k: f32) {
    add(targets, d, k);
    for t in targets.iter_mut() {
        for v in t.iter_mut() {
            *v = v.clamp(0.0, 1.0);
        }
    }
}

/// `images` with `k` times the detail `d` added ([`add`]).
pub fn with(images: &[Vec<f32>], d: &[Vec<f32>], k: f32) -> Vec<Vec<f32>> {
    let mut out = images.to_vec();
    add(&mut out, d, k);
    out
}

/// `images` (`[H, W, 3]` each) plus `k` times the detail `d` (`[H W]` each) on every
/// channel.
pub fn add(images: &mut [Vec<f32>], d: &[Vec<f32>], k: f32) {
    for (img, d) in images.iter_mut().zip(d) {
        for (px, &dv) in img.chunks_exact_mut(3).zip(d) {
            for c in px {
                *c += k * dv;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 40 x 40 style of dark and light vertical stripes (2 and 4 px): strong edges.
    fn stripes() -> Image {
        Image::from_fn(40, 40, |x, _| [if x % 6 < 2 { 0.05 } else { 0.9 }; 3])
    }

    #[test]
    fn a_flat_object_has_no_detail_and_an_edge_has_both_signs() {
        let (h, w) = (24, 24);
        let flat = vec![0.4f32; h * w * 3];
        let alpha = vec![1.0f32; h * w];
        let style = Image::from_fn(8, 8, |x, _| [x as f32 / 8.0; 3]);
        let p = SynthesisParams::default();
        let d = source_detail(
            &[flat],
            std::slice::from_ref(&alpha),
            (&[(h, w)], 8),
            [0.0; 3],
            (&style, &[]),
            &p,
        );
        assert!(d[0].iter().all(|v| v.abs() < 1e-5));
        let step: Vec<f32> = (0..h * w)
            .flat_map(|i| [if i % w < w / 2 { 0.2 } else { 0.8 }; 3])
            .collect();
        let d = source_detail(
            &[step],
            &[alpha],
            (&[(h, w)], 8),
            [0.0; 3],
            (&style, &[]),
            &p,
        );
        let (dark, light) = (d[0][5 * w + w / 2 - 1], d[0][5 * w + w / 2]);
        assert!(dark < -0.01 && light > 0.01, "{dark} {light}");
        let mut imgs = vec![vec![0.5f32; h * w * 3]];
        add(&mut imgs, &d, 2.0);
        assert!((imgs[0][(5 * w + w / 2) * 3] - (0.5 + 2.0 * light)).abs() < 1e-6);
    }

    /// A faint crease on a flat object under a striped style: the line weight raises the
    /// detail by the ratio of the two quantiles (computed here by sorting), capped by
    /// `line_weight`; a flat style or `line_weight = 1` leaves it as it was.
    #[test]
    fn the_line_weight_matches_the_styles_strongest_edges() {
        let (h, w) = (32, 32);
        let alpha = vec![1.0f32; h * w];
        let crease: Vec<f32> = (0..h * w)
            .flat_map(|i| [if i % w == w / 2 { 0.45 } else { 0.5 }; 3])
            .collect();
        let stripes = stripes();
        let flat = Image::from_fn(40, 40, |_, _| [0.4; 3]);
        let detail = |style: &Image, line_weight: f32| {
            let p = SynthesisParams {
                line_weight,
                ..SynthesisParams::default()
            };
            let views = (&[(h, w)][..], 40);
            let rgb = std::slice::from_ref(&crease);
            source_detail(
                rgb,
                std::slice::from_ref(&alpha),
                views,
                [0.0; 3],
                (style, &[]),
                &p,
            )
        };
        let raw = detail(&stripes, 1.0);
        let q = |mut v: Vec<f32>| {
            v.sort_by(f32::total_cmp);
            v[((v.len() - 1) as f32 * LINE_QUANTILE) as usize]
        };
        let l = super::super::motif::luma(&stripes.data);
        let base = blur(l.clone(), (40, 40), SynthesisParams::default().detail_blur);
        let want = q(l.iter().zip(&base).map(|(a, b)| (a - b).abs()).collect())
            / q(raw[0].iter().map(|v| v.abs()).collect());
        assert!(want > 2.0, "the stripes' edges are the stronger: {want}");
        let peak = |d: &[Vec<f32>]| d[0].iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let capped = detail(&stripes, 2.0);
        assert!((peak(&capped) / peak(&raw) - 2.0).abs() < 1e-4);
        let free = detail(&stripes, 10.0);
        let got = peak(&free) / peak(&raw);
        assert!(
            (got - want.min(10.0)).abs() < 1e-3 * want,
            "{got} vs {want}"
        );
        // A flat style has no edges to match: the gain stays 1.
        assert_eq!(detail(&flat, 4.0), detail(&flat, 1.0));
        // Slow waves (a 64 px period: their spread is in the shading, little in the
        // band-pass): the crease is now the stronger (both are remapped to the style's
        // spread first), and the layer is lowered by the ratio, to 1 / line_weight at most.
        let faint = Image::from_fn(40, 40, |x, _| {
            [0.5 + 0.4 * (std::f32::consts::TAU * x as f32 / 64.0).sin(); 3]
        });
        let raw = detail(&faint, 1.0);
        let l = super::super::motif::luma(&faint.data);
        let base = blur(l.clone(), (40, 40), SynthesisParams::default().detail_blur);
        let ratio = q(l.iter().zip(&base).map(|(a, b)| (a - b).abs()).collect())
            / q(raw[0].iter().map(|v| v.abs()).collect());
        assert!(ratio < 0.5, "the crease is the stronger: {ratio}");
        let got = peak(&detail(&faint, 10.0)) / peak(&raw);
        assert!((got - ratio.max(0.1)).abs() < 1e-3, "{got} vs {ratio}");
        let floor = peak(&detail(&faint, 2.0)) / peak(&raw);
        assert!((floor - 0.5).abs() < 1e-4, "{floor}");
    }

    /// The shading band: with the line weight off, the layer at `detail_blur` 4 plus the
    /// band from 4 to 16 px is the layer at `detail_blur` 16 (the two residues telescope;
    /// up to the Gaussians' truncation); with a line weight the gain raises the fine part
    /// only, so the difference the band makes is the same at every gain.
    #[test]
    fn the_shading_band_telescopes_and_takes_no_line_weight() {
        let (h, w) = (64, 64);
        let alpha = vec![1.0f32; h * w];
        // A lit sphere-like ramp with a crease.
        let obj: Vec<f32> = (0..h * w)
            .flat_map(|i| {
                let (y, x) = ((i / w) as f32, (i % w) as f32);
                let r2 = ((x - 32.0).powi(2) + (y - 32.0).powi(2)) / 900.0;
                let crease = if (i % w) == 40 { -0.06 } else { 0.0 };
                [0.2 + 0.6 * (1.0 - r2).max(0.0) + crease; 3]
            })
            .collect();
        let stripes = stripes();
        let detail = |detail_blur: f32, shade_blur: f32, line_weight: f32| {
            let p = SynthesisParams {
                detail_blur,
                shade_blur,
                line_weight,
                ..SynthesisParams::default()
            };
            p.validate().unwrap();
            let (rgb, a) = (std::slice::from_ref(&obj), std::slice::from_ref(&alpha));
            source_detail(rgb, a, (&[(h, w)], 40), [0.0; 3], (&stripes, &[]), &p).remove(0)
        };
        let banded = detail(4.0, 16.0, 1.0);
        let wide = detail(16.0, 0.0, 1.0);
        let range = wide.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(range > 0.1, "the shading is in the wide layer: {range}");
        // Away from the frame's border (clamp-to-edge differs there).
        for y in 20..44 {
            for x in 20..44 {
                let (a, b) = (banded[y * w + x], wide[y * w + x]);
                assert!((a - b).abs() < 0.02 * range, "({y}, {x}): {a} vs {b}");
            }
        }
        let band = |lw: f32| -> Vec<f32> {
            let (with, without) = (detail(4.0, 16.0, lw), detail(4.0, 0.0, lw));
            with.iter().zip(&without).map(|(a, b)| a - b).collect()
        };
        let (b1, b4) = (band(1.0), band(4.0));
        assert!(b1.iter().zip(&b4).all(|(a, b)| (a - b).abs() < 1e-5));
        assert!(
            detail(4.0, 0.0, 4.0) != detail(4.0, 0.0, 1.0),
            "the gain acts"
        );
        // Out of range: below the detail's own scale.
        let bad = SynthesisParams {
            shade_blur: 2.0,
            ..SynthesisParams::default()
        };
        assert!(bad.validate().is_err());
    }

    /// Two regions of one object: a strong edge on the left, a faint crease on the right.
    /// The right region's line weight is measured over its own pixels, so its crease is
    /// raised as the crease alone would be (by the quantiles of the right half, computed
    /// here by sorting); measured over the whole object, the left edge would hold it down.
    #[test]
    fn a_regions_line_weight_is_measured_where_it_lies() {
        let (h, w) = (32, 48);
        let alpha = vec![1.0f32; h * w];
        let obj: Vec<f32> = (0..h * w)
            .flat_map(|i| {
                let x = i % w;
                [if x < 12 {
                    0.2
                } else if x == 36 {
                    0.47
                } else {
                    0.5
                }; 3]
            })
            .collect();
        let right: Vec<f32> = (0..h * w)
            .map(|i| f32::from(u8::from(i % w >= 24)))
            .collect();
        let stripes = stripes();
        let p = SynthesisParams {
            line_weight: 10.0,
            ..SynthesisParams::default()
        };
        let detail = |within: &[Vec<f32>], p: &SynthesisParams| {
            let (rgb, a) = (std::slice::from_ref(&obj), std::slice::from_ref(&alpha));
            source_detail(rgb, a, (&[(h, w)], 40), [0.0; 3], (&stripes, within), p)
        };
        let raw = detail(&[], &SynthesisParams::default());
        let (whole, own) = (detail(&[], &p), detail(std::slice::from_ref(&right), &p));
        let at = 5 * w + 36;
        let (k_whole, k_own) = (whole[0][at] / raw[0][at], own[0][at] / raw[0][at]);
        let q = |mut v: Vec<f32>| {
            v.sort_by(f32::total_cmp);
            v[((v.len() - 1) as f32 * LINE_QUANTILE) as usize]
        };
        let l = super::super::motif::luma(&stripes.data);
        let base = blur(l.clone(), (40, 40), p.detail_blur);
        let q_style = q(l.iter().zip(&base).map(|(a, b)| (a - b).abs()).collect());
        let q_right = q((0..h * w)
            .filter(|i| i % w >= 24)
            .map(|i| raw[0][i].abs())
            .collect());
        let want = (q_style / q_right).clamp(1.0, 10.0);
        assert!((k_own - want).abs() < 1e-3 * want, "{k_own} vs {want}");
        assert!(k_own > 1.5 * k_whole, "own {k_own}, whole object {k_whole}");
    }

    /// A flat grey square with a thin dark cross (the object's detail), styled with
    /// coloured cells in dark outlines: returns (how much darker the cross is than the
    /// rest, the share of the rest that is as dark as an outline).
    fn cross_in_cells(p: &SynthesisParams) -> (f32, f32) {
        let n = 64;
        let on_cross = |i: usize| (31..33).contains(&(i / n)) || (31..33).contains(&(i % n));
        let src: Vec<f32> = (0..n * n)
            .flat_map(|i| [if on_cross(i) { 0.15 } else { 0.6 }; 3])
            .collect();
        let palette = [
            [0.9, 0.5, 0.1],
            [0.2, 0.6, 0.3],
            [0.5, 0.2, 0.5],
            [0.9, 0.85, 0.6],
        ];
        let style = Image::from_fn(96, 96, |x, y| {
            if x % 16 < 2 || y % 16 < 2 {
                [0.05; 3]
            } else {
                palette[(x / 16 + 3 * (y / 16)) % 4]
            }
        });
        let out = super::super::synthesize_images(
            &[src],
            &[vec![1.0; n * n]],
            &[(n, n)],
            &[(&style, 1.0)],
            [0.0; 3],
            96,
            p,
        )
        .unwrap();
        let l = super::super::motif::luma(&out[0]);
        let (mut cross, mut rest, mut dark, mut count) = (0.0, 0.0, 0usize, 0usize);
        for (i, &v) in l.iter().enumerate() {
            let (y, x) = (i / n, i % n);
            if on_cross(i) && (8..56).contains(&y) && (8..56).contains(&x) {
                cross += v;
            } else if y.abs_diff(32) > 4 && x.abs_diff(32) > 4 {
                rest += v;
                count += 1;
                dark += usize::from(v < 0.2);
            }
        }
        let cross = cross / (2 * 2 * 48 - 4) as f32;
        (rest / count as f32 - cross, dark as f32 / count as f32)
    }

    #[test]
    fn the_detail_layer_keeps_the_objects_lines_and_the_styles_outlines() {
        let base = SynthesisParams {
            levels: vec![2, 1],
            control: 1.0,
            ..SynthesisParams::default()
        };
        let old = cross_in_cells(&base);
        let blurred = cross_in_cells(&SynthesisParams {
            guide_blur: 2.0,
            ..base.clone()
        });
        let new = cross_in_cells(&SynthesisParams {
            guide_blur: 2.0,
            detail: 1.0,
            ..base.clone()
        });
        eprintln!(
            "(cross contrast, outline share): pixel guide {old:?}, blurred {blurred:?}, blurred + detail {new:?}"
        );
        assert!(new.0 > blurred.0 + 0.05, "the detail layer keeps the cross");
        assert!(
            new.1 > 0.05 && new.1 > 1.5 * old.1,
            "the outlines stay on the flat part"
        );
    }

    /// A 40 px square object (from 4 to 44) in a 48 x 48 view, luma 0.5 with a 3 px
    /// crease of 0.45 at x = 23..=25 and a darker band (0.3) at x < 6: its RGB and
    /// coverage.
    fn creased_square(h: usize, w: usize) -> (Vec<f32>, Vec<f32>) {
        let inside = |i: usize| (4..44).contains(&(i / w)) && (4..44).contains(&(i % w));
        let alpha = (0..h * w).map(|i| f32::from(u8::from(inside(i)))).collect();
        let luma = |x: usize| match x {
            23..=25 => 0.45,
            0..6 => 0.3,
            _ => 0.5,
        };
        let obj = (0..h * w).flat_map(|i| [luma(i % w); 3]).collect();
        (obj, alpha)
    }

    /// The ink: under a striped style, a faint crease inside a flat object is raised by
    /// `max(1, ink q75(style band) / q90(|d| over the interior))` (both quantiles by
    /// sorting here), a darker band beside the outline (within twice the layer's blur of
    /// it) is not an edge of the interior and stays as it was, and so does the object far
    /// from the crease; a flat style has no edges to match and leaves the layer as it was.
    #[test]
    fn the_ink_raises_the_interior_edges_and_nothing_else() {
        let (h, w) = (48, 48);
        let (obj, alpha) = creased_square(h, w);
        let detail = |style: &Image, ink: f32| {
            let p = SynthesisParams {
                ink,
                line_weight: 1.0,
                ..SynthesisParams::default()
            };
            source_detail(
                std::slice::from_ref(&obj),
                std::slice::from_ref(&alpha),
                (&[(h, w)][..], 40),
                [0.0; 3],
                (style, &[]),
                &p,
            )
        };
        let stripes = stripes();
        let (raw, inked) = (detail(&stripes, 0.0), detail(&stripes, 2.0));
        let q = |mut v: Vec<f32>, q: f32| {
            v.sort_by(f32::total_cmp);
            v[((v.len() - 1) as f32 * q) as usize]
        };
        let p = SynthesisParams::default();
        let reach = (2.0 * p.detail_blur).ceil() as usize;
        let inner = |i: usize| {
            let (y, x) = (i / w, i % w);
            (4 + reach..44 - reach).contains(&y) && (4 + reach..44 - reach).contains(&x)
        };
        let l = super::super::motif::luma(&stripes.data);
        let base = blur(l.clone(), (40, 40), p.detail_blur);
        let s = q(
            l.iter().zip(&base).map(|(a, b)| (a - b).abs()).collect(),
            0.75,
        );
        let interior = (0..h * w).filter(|&i| inner(i));
        let o = q(interior.map(|i| raw[0][i].abs()).collect(), 0.9);
        let f = 2.0 * s / o;
        assert!(f > 2.0, "the stripes' edges are the stronger: {f}");
        // The crease (3 px wide) is all edge: its middle takes the whole gain.
        let crease = 24 * w + 24;
        let got = inked[0][crease] / raw[0][crease];
        assert!((got - f).abs() < 1e-4 * f, "{got} of {f}");
        // The dark band's edge 2 px inside the outline is stronger than the crease but
        // not in the interior; the mask (6 px at most around an edge) does not reach it.
        for (at, what) in [
            (24 * w + 5, "beside the outline"),
            (24 * w + 6, "beside the outline"),
            (24 * w + 14, "far from the crease"),
        ] {
            assert!(
                raw[0][at].abs() > 1e-3 || what != "beside the outline",
                "a band there"
            );
            assert!(
                (inked[0][at] - raw[0][at]).abs() <= 1e-6 * raw[0][at].abs().max(1e-3),
                "{what}: {} vs {}",
                inked[0][at],
                raw[0][at]
            );
        }
        let flat = Image::from_fn(40, 40, |_, _| [0.4; 3]);
        assert_eq!(detail(&flat, 2.0), detail(&flat, 0.0));
    }
}
