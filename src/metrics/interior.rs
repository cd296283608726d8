//! Interior structure, edge recall, motif contrast and style texture (issue 53): four
//! measures of the object's inside, per view and as the mean over views, beside structure
//! kept ([`super::structure`]).
//!
//! Structure kept counts the silhouette (the object against the background is most of
//! its band-pass energy) and punishes any texture the style adds: a flat wash of one
//! colour keeps the silhouette and scores well, a stroke texture over intact edges
//! scores less. These four look only inside the object and separate "kept the source's
//! edges" from "carries the style's texture".
//!
//! **Common parts.** `D` is the band-passed luminance of [`structure::band_pass`] (Rec.
//! 601 luma, difference of Gaussians sigma 1 px minus sigma 4 px, clamp to edge): the
//! same function structure kept uses. The *interior* of a view is its object mask
//! (source alpha > [`structure::ALPHA_MIN`]) eroded by [`EROSION_PX`] px with a
//! **square** structuring element ([`erode`]: a pixel stays when every pixel of the
//! `(2r+1) x (2r+1)` square centred on it lies inside the image and inside the mask, so
//! the frame's border erodes like the background). A view whose interior has fewer than
//! [`MIN_INTERIOR_PIXELS`] pixels has no value for any of the four (`None`, with the
//! reason). Percentiles are the linear interpolation between closest ranks ([`percentile`]:
//! numpy's default): the `q` quantile of `n` sorted values `v` is `v[k] + f (v[k+1] -
//! v[k])` with `k + f = q (n - 1)`.
//!
//! **Interior structure.** The Pearson correlation of the source's and the stylized
//! view's `D` over the interior ([`structure::correlation`]); `None` also when either
//! is flat there (variance below [`structure::MIN_VARIANCE`]).
//!
//! **Edge recall.** The source's strongest band-pass pixels: interior pixels with
//! `|D_src|` at least the 90th percentile of `|D_src|` over the interior (the top 10%)
//! and above [`MIN_BAND`]. The share of them where the stylized view has `D_sty` of the
//! same sign (`D_src D_sty > 0`) with `|D_sty|` at least the 75th percentile of
//! `|D_sty|` over the interior and above [`MIN_BAND`]. 1: every strong source edge is
//! among the stylized view's own strong band-pass pixels with the same polarity; chance
//! (a stylized band pass unrelated to the source's) about `0.5 x 0.25 = 0.125`
//! ([`CHANCE_RECALL`]); extra style edges elsewhere are not punished; a flat view
//! recalls 0. `None` also when the source has no band-pass pixel above [`MIN_BAND`]
//! inside. [`MIN_BAND`] (1e-6, far below one 8-bit step) keeps rounding noise of a flat
//! image from counting as an edge.
//!
//! **Motif contrast.** The spread (population standard deviation) of the stylized view's
//! `D` over the interior, divided by the spread of the style image's own `D` over all its
//! pixels, the style resized so its shorter side is [`STYLE_SHORTER_SIDE`] px
//! ([`Image::with_shorter_side`], bilinear: the scale at which the texture term, the VGG
//! baselines and the object KID draw the style; the evaluation does not know a run's
//! `texture.style_size`, so it uses this fixed scale). About 1: the object carries the
//! style's band-pass contrast; 0: a flat wash; above 1: more contrast than the style.
//! `None` also when the style's spread is below `sqrt(MIN_VARIANCE)` (a flat style).
//!
//! **Style texture.** Motif contrast counts the object's *own* band pass as motif: a
//! result that lays the source's detail (letters, a face's lines, its shading) over a
//! flat wash of the style's colours scores a high motif contrast with no style texture at
//! all. Style texture removes the source's part first: over the interior `M`, with
//! `D_src` and `D_sty` the source's and the stylized view's band passes, `beta = sum(D_src
//! D_sty) / sum(D_src^2)` (the least-squares projection of `D_sty` on `D_src`, through
//! the origin; `beta = 0` when `sum(D_src^2) <= ` [`MIN_SOURCE_ENERGY`]), the residual
//! `R = D_sty - beta D_src`, and style texture = `std(R over M)` (population) over the
//! style image's band-pass spread (motif contrast's denominator). What is left is the part
//! of the stylized band pass that is not the source's own, at any gain or polarity: the
//! style's motifs. The source itself (or any brightness, contrast or inversion of it) has
//! 0; the source with the style's texture added keeps about that texture's own value; a
//! flat wash 0. `None` in the same cases as motif contrast. Motif contrast stays as it
//! was: together they say how much of the object's band-pass contrast is the style's.
//!
//! **Limit.** The coarse Gaussian reaches 12 px, so the silhouette's band-pass response
//! still reaches the interior's outer 4 px: on a small object a flat wash recalls some of
//! the edges near the outline and has a small motif contrast and style texture
//! (docs/evaluation.md). Style texture removes only a gain of the source's band pass: a
//! blur or any other change of the source's detail leaves a residual that counts.
//!
//! Reference: `scripts/reference/interior_ref.py` (numpy, written from this definition:
//! its own erosion, percentiles and resize; the band pass and correlation of
//! `structure_ref.py`, structure kept's reference) computes the same;
//! `tests/integration/interior.rs` compares the two on renders of the sample scene.

use super::structure::{self, band_pass, correlation, mean_present, object_pixels};
use super::views::ViewSet;
use crate::imageio::Image;
use serde::Serialize;

/// Erosion of the object mask, px (square structuring element of side `2 x 8 + 1`).
pub const EROSION_PX: usize = 8;
/// Fewest interior pixels a view needs for any of the four values.
pub const MIN_INTERIOR_PIXELS: usize = 64;
/// The source's strong band-pass pixels: `|D|` at least this quantile (the top 10%).
pub const SOURCE_QUANTILE: f64 = 0.90;
/// A stylized pixel is strong with `|D|` at least this quantile of its own view.
pub const STYLIZED_QUANTILE: f64 = 0.75;
/// `|D|` at or below this is no edge (rounding noise of a flat image).
pub const MIN_BAND: f64 = 1e-6;
/// Edge recall of a stylized band pass unrelated to the source's: same sign (1/2) and
/// among its top quarter (1/4).
pub const CHANCE_RECALL: f64 = 0.125;
/// The style image's shorter side for its band-pass spread, px, unless the evaluation
/// is told the style size the end used (`evaluate --style-size`, the end's
/// `texture.style_size`, whose default this is).
pub const STYLE_SHORTER_SIDE: usize = 256;
/// Style texture's projection on the source's band pass is skipped (`beta = 0`) when
/// `sum(D_src^2)` over the interior is at or below this (a flat source).
pub const MIN_SOURCE_ENERGY: f64 = 1e-12;

/// What interior structure means (`metrics.json`, beside the value).
pub const INTERIOR_STRUCTURE_NOTE: &str = "interior structure: per view, the Pearson correlation of the source's and the \
     stylized view's band-passed luminance (the band pass of structure kept) over the object's interior: the mask \
     (source alpha > 0.5) eroded by 8 px with a square (17 x 17); 1 = the inner edges and shading kept, without the \
     silhouette; mean over the views with a value (an interior under 64 pixels or a flat band pass has none)";
/// What edge recall means.
pub const EDGE_RECALL_NOTE: &str = "edge recall: per view, inside the interior (mask eroded 8 px, square), the share of \
     the source's strongest band-pass pixels (top 10% of |D|) where the stylized view's band pass has the same sign \
     and |D| at least its own 75th percentile over the interior; 1 = every strong source edge kept, chance about \
     0.125, extra style edges not punished, a flat wash 0";
/// What motif contrast means.
pub const MOTIF_CONTRAST_NOTE: &str = "motif contrast: per view, the standard deviation of the stylized view's \
     band-passed luminance over the interior (mask eroded 8 px, square) divided by the style image's own (resized to \
     shorter side style_size px, the scale the end laid it at: 256 unless evaluate --style-size, all its pixels); \
     about 1 = the object carries the style's contrast, 0 = a flat wash";
/// What style texture means.
pub const STYLE_TEXTURE_NOTE: &str = "style texture: per view, over the interior (mask eroded 8 px, square), the \
     stylized band pass D_sty less its least-squares projection on the source's D_src (R = D_sty - beta D_src, beta = \
     sum(D_src D_sty) / sum(D_src^2), 0 for a flat source); the standard deviation of R divided by the style image's \
     band-pass spread (motif contrast's denominator); the style's motifs without the object's own edges: 0 = the \
     source's detail only (or a flat wash), about 1 = the style's contrast on top of it";

/// The four measures of one view, with why any is missing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewInterior {
    /// Interior pixels (the eroded mask).
    pub pixels: usize,
    pub interior_structure: Option<f64>,
    pub edge_recall: Option<f64>,
    pub motif_contrast: Option<f64>,
    pub style_texture: Option<f64>,
    /// Why a value is missing (empty when all four have one).
    pub reasons: Vec<String>,
}

/// The four measures of an evaluation: means over the views with a value, per view.
#[derive(Debug, Clone, Serialize)]
pub struct Interior {
    pub interior_structure: Option<f64>,
    pub edge_recall: Option<f64>,
    pub motif_contrast: Option<f64>,
    pub style_texture: Option<f64>,
    /// The style image's band-pass spread at shorter side `style_size` px.
    pub style_band_spread: Option<f64>,
    /// The style's shorter side for its spread, px ([`STYLE_SHORTER_SIDE`] unless told).
    pub style_size: usize,
    pub interior_per_view: Vec<ViewInterior>,
    pub interior_structure_note: &'static str,
    pub edge_recall_note: &'static str,
    pub motif_contrast_note: &'static str,
    pub style_texture_note: &'static str,
}

/// Square erosion of a row-major `w x h` mask by `r` px: a pixel stays when the whole
/// `(2r+1) x (2r+1)` square centred on it lies inside the image and the mask.
pub fn erode(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    assert_eq!(mask.len(), w * h, "erode: mask size");
    // Along one axis: a pixel stays when the 2r+1 pixels centred on it are all set and
    // inside (a running count of set pixels, prefix sums).
    let pass = |line: &[bool]| -> Vec<bool> {
        let n = line.len();
        let mut pre = vec![0usize; n + 1];
        for (i, m) in line.iter().enumerate() {
            pre[i + 1] = pre[i] + usize::from(*m);
        }
        (0..n)
            .map(|i| i >= r && i + r < n && pre[i + r + 1] - pre[i - r] == 2 * r + 1)
            .collect()
    };
    let mut rows = Vec::with_capacity(w * h);
    for y in 0..h {
        rows.extend(pass(&mask[y * w..(y + 1) * w]));
    }
    let mut out = vec![false; w * h];
    for x in 0..w {
        let col: Vec<bool> = (0..h).map(|y| rows[y * w + x]).collect();
        for (y, v) in pass(&col).into_iter().enumerate() {
            out[y * w + x] = v;
        }
    }
    out
}

/// The `q` quantile (0..=1) of `v` by linear interpolation between closest ranks
/// (numpy's default); `None` for no values.
pub fn percentile(v: &[f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let pos = q.clamp(0.0, 1.0) * (s.len() - 1) as f64;
    let k = pos.floor() as usize;
    let f = pos - k as f64;
    Some(match s.get(k + 1) {
        Some(next) if f > 0.0 => s[k] + f * (next - s[k]),
        _ => s[k],
    })
}

/// Population standard deviation of `v` (0 for no values).
fn spread(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt()
}

/// The values of `d` where `inside` holds.
fn select(d: &[f64], inside: &[bool]) -> Vec<f64> {
    d.iter()
        .zip(inside)
        .filter(|(_, m)| **m)
        .map(|(v, _)| *v)
        .collect()
}

/// Edge recall of the band passes `(src, sty)` over `inside` (see the module docs), or
/// why it has none.
pub fn edge_recall(src: &[f64], sty: &[f64], inside: &[bool]) -> Result<f64, String> {
    let (s, t) = (select(src, inside), select(sty, inside));
    let abs = |v: &[f64]| v.iter().map(|x| x.abs()).collect::<Vec<f64>>();
    let (ts, tt) = match (
        percentile(&abs(&s), SOURCE_QUANTILE),
        percentile(&abs(&t), STYLIZED_QUANTILE),
    ) {
        (Some(a), Some(b)) => (a, b),
        _ => return Err("no interior pixels".into()),
    };
    let (mut strong, mut kept) = (0usize, 0usize);
    for (a, b) in s.iter().zip(&t) {
        if a.abs() >= ts && a.abs() > MIN_BAND {
            strong += 1;
            if a * b > 0.0 && b.abs() >= tt && b.abs() > MIN_BAND {
                kept += 1;
            }
        }
    }
    if strong == 0 {
        return Err(
            "the source's band pass is flat inside the interior (no edge to recall)".into(),
        );
    }
    Ok(kept as f64 / strong as f64)
}

/// The spread of the stylized band pass `sty` over `inside` once its least-squares
/// projection on the source's `src` is removed: `std(sty - beta src)` with `beta =
/// sum(src sty) / sum(src^2)` (0 when `sum(src^2) <=` [`MIN_SOURCE_ENERGY`]); style
/// texture's numerator (see the module docs).
pub fn residual_spread(src: &[f64], sty: &[f64], inside: &[bool]) -> f64 {
    let (s, t) = (select(src, inside), select(sty, inside));
    let energy: f64 = s.iter().map(|a| a * a).sum();
    let beta = if energy > MIN_SOURCE_ENERGY {
        s.iter().zip(&t).map(|(a, b)| a * b).sum::<f64>() / energy
    } else {
        0.0
    };
    let r: Vec<f64> = s.iter().zip(&t).map(|(a, b)| b - beta * a).collect();
    spread(&r)
}

/// The band-pass spread of the style image at shorter side `side` px
/// (`None` when flat).
pub fn style_band_spread(style: &Image, side: usize) -> Option<f64> {
    let s = spread(&band_pass(&style.with_shorter_side(side)));
    (s * s >= structure::MIN_VARIANCE).then_some(s)
}

/// The four measures of one view: source image `src`, its alpha, the stylized image,
/// and the style's band-pass spread ([`style_band_spread`]).
pub fn view_interior(
    src: &Image,
    alpha: &[f32],
    styl: &Image,
    style_spread: Option<f64>,
) -> ViewInterior {
    let (w, h) = (src.width, src.height);
    assert_eq!((w, h), (styl.width, styl.height), "interior: image sizes");
    assert_eq!(alpha.len(), w * h, "interior: alpha size");
    let inside = erode(&object_pixels(alpha), w, h, EROSION_PX);
    let pixels = inside.iter().filter(|m| **m).count();
    let mut v = ViewInterior {
        pixels,
        interior_structure: None,
        edge_recall: None,
        motif_contrast: None,
        style_texture: None,
        reasons: Vec::new(),
    };
    if pixels < MIN_INTERIOR_PIXELS {
        v.reasons.push(format!(
            "the object's interior (mask eroded by {EROSION_PX} px) has {pixels} pixels, fewer than {MIN_INTERIOR_PIXELS}"
        ));
        return v;
    }
    let (ds, dt) = (band_pass(src), band_pass(styl));
    v.interior_structure = correlation(&ds, &dt, &inside);
    if v.interior_structure.is_none() {
        v.reasons
            .push("interior structure: a flat band pass over the interior".into());
    }
    match edge_recall(&ds, &dt, &inside) {
        Ok(r) => v.edge_recall = Some(r),
        Err(e) => v.reasons.push(format!("edge recall: {e}")),
    }
    match style_spread {
        Some(s) => {
            v.motif_contrast = Some(spread(&select(&dt, &inside)) / s);
            v.style_texture = Some(residual_spread(&ds, &dt, &inside) / s);
        }
        None => v
            .reasons
            .push("motif contrast and style texture: the style image's band pass is flat".into()),
    }
    v
}

/// The four measures of every view of `styl` against `src` (the same views) and the
/// style image taken at shorter side `style_size` px (the scale the end laid it at),
/// with their means over the views that have a value.
pub fn interior(src: &ViewSet, styl: &ViewSet, style: &Image, style_size: usize) -> Interior {
    let style_spread = style_band_spread(style, style_size);
    let per_view: Vec<ViewInterior> = (0..src.n)
        .map(|i| {
            view_interior(
                &src.images[i],
                src.geometry(i).1,
                &styl.images[i],
                style_spread,
            )
        })
        .collect();
    let mean = |f: fn(&ViewInterior) -> Option<f64>| {
        mean_present(&per_view.iter().map(f).collect::<Vec<_>>())
    };
    Interior {
        interior_structure: mean(|v| v.interior_structure),
        edge_recall: mean(|v| v.edge_recall),
        motif_contrast: mean(|v| v.motif_contrast),
        style_texture: mean(|v| v.style_texture),
        style_band_spread: style_spread,
        style_size,
        interior_per_view: per_view,
        interior_structure_note: INTERIOR_STRUCTURE_NOTE,
        edge_recall_note: EDGE_RECALL_NOTE,
        motif_contrast_note: MOTIF_CONTRAST_NOTE,
        style_texture_note: STYLE_TEXTURE_NOTE,
    }
}

impl Interior {
    /// One warning per view with a missing value, naming the view and the reason.
    pub fn warnings(&self) -> Vec<String> {
        self.interior_per_view
            .iter()
            .enumerate()
            .flat_map(|(i, v)| v.reasons.iter().map(move |r| format!("view {i}: {r}")))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::structure::fixtures::{map, textured_disc};

    const W: usize = 96;
    const H: usize = 80;

    /// The textured disc of `radius` at (48, 40).
    fn object(radius: f32) -> (Image, Vec<f32>) {
        textured_disc(W, H, (48.0, 40.0), radius)
    }

    fn noise_image(w: usize, h: usize, seed: u64) -> Image {
        let n = crate::rng::Rng::new(seed).normals_f32(w * h);
        Image::from_fn(w, h, |x, y| [0.5 + 0.1 * n[y * w + x]; 3])
    }

    #[test]
    fn erosion_shrinks_a_mask_by_8_px_and_the_frame_erodes_too() {
        let (w, h) = (64, 48);
        let rect = |x0, x1, y0, y1| -> Vec<bool> {
            (0..w * h)
                .map(|p| (x0..x1).contains(&(p % w)) && (y0..y1).contains(&(p / w)))
                .collect()
        };
        assert_eq!(erode(&rect(10, 50, 5, 40), w, h, 8), rect(18, 42, 13, 32));
        // The whole frame: its border erodes like the background.
        assert_eq!(erode(&vec![true; w * h], w, h, 8), rect(8, 56, 8, 40));
        // A hole of one pixel removes the 17 x 17 square around it.
        let mut holed = vec![true; w * h];
        holed[24 * w + 32] = false;
        let e = erode(&holed, w, h, 8);
        let kept = e.iter().filter(|m| **m).count();
        assert_eq!(kept, 48 * 32 - 17 * 17);
        assert!(!e[(24 + 8) * w + 32 + 8] && e[(24 + 9) * w + 32]);
        // Too thin to keep anything; radius 0 is the identity.
        assert!(erode(&rect(10, 26, 5, 40), w, h, 8).iter().all(|m| !*m));
        let r = rect(10, 26, 5, 40);
        assert_eq!(erode(&r, w, h, 0), r);
    }

    #[test]
    fn percentile_interpolates_between_closest_ranks() {
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(percentile(&v, 0.0), Some(1.0));
        assert_eq!(percentile(&v, 1.0), Some(4.0));
        let p = percentile(&v, 0.9).unwrap();
        assert!((p - 3.7).abs() < 1e-12, "{p}");
        assert_eq!(percentile(&v, 0.5), Some(2.5));
        assert_eq!(percentile(&[5.0], 0.75), Some(5.0));
        assert_eq!(percentile(&[], 0.75), None);
    }

    #[test]
    fn the_source_itself_keeps_everything() {
        let (img, alpha) = object(30.0);
        let v = view_interior(&img, &alpha, &img, Some(0.05));
        assert!(v.pixels >= MIN_INTERIOR_PIXELS, "{}", v.pixels);
        assert!(v.reasons.is_empty(), "{:?}", v.reasons);
        assert!((v.interior_structure.unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(v.edge_recall, Some(1.0));
        // Brightness and contrast keep the edges and their signs; inversion flips them.
        let v = view_interior(&img, &alpha, &map(&img, |x| 0.1 + 0.6 * x), None);
        assert!((v.interior_structure.unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(v.edge_recall, Some(1.0));
        let v = view_interior(&img, &alpha, &map(&img, |x| 1.0 - x), None);
        assert!((v.interior_structure.unwrap() + 1.0).abs() < 1e-9);
        assert_eq!(v.edge_recall, Some(0.0));
    }

    #[test]
    fn a_flat_wash_has_no_motif_contrast_and_recalls_nothing() {
        let (img, alpha) = object(30.0);
        let flat = Image::filled(W, H, [0.3, 0.6, 0.2]);
        let v = view_interior(&img, &alpha, &flat, Some(0.05));
        assert!(v.motif_contrast.unwrap() < 1e-9, "{:?}", v.motif_contrast);
        assert!(v.style_texture.unwrap() < 1e-9, "{:?}", v.style_texture);
        assert_eq!(v.edge_recall, Some(0.0));
        assert_eq!(v.interior_structure, None);
        assert_eq!(v.reasons.len(), 1, "{:?}", v.reasons);
        // A flat source has no edge to recall.
        let v = view_interior(&flat, &alpha, &img, Some(0.05));
        assert_eq!(v.edge_recall, None);
        assert!(v.reasons.iter().any(|r| r.contains("no edge to recall")));
        // ... and nothing to project out: all of the stylized band pass is style texture.
        assert!(v.motif_contrast.unwrap() > 0.1, "{:?}", v.motif_contrast);
        assert_eq!(v.style_texture, v.motif_contrast);
        // A flat style has no spread to compare with.
        assert_eq!(
            style_band_spread(&Image::filled(300, 260, [0.4; 3]), 256),
            None
        );
    }

    #[test]
    fn the_style_itself_has_motif_contrast_about_one() {
        // A style that needs resizing: shorter side 512 -> 256.
        let n = noise_image(512, 640, 3);
        let style = Image::from_fn(512, 640, |x, y| {
            let s = 0.2 * (((x / 12 + y / 12) % 2) as f32);
            n.px(x, y).map(|v| v + s)
        });
        let at = style.with_shorter_side(STYLE_SHORTER_SIDE);
        assert_eq!((at.width, at.height), (256, 320));
        let spread = style_band_spread(&style, STYLE_SHORTER_SIDE).unwrap();
        let alpha = vec![1.0; at.width * at.height];
        let v = view_interior(&at, &alpha, &at, Some(spread));
        let m = v.motif_contrast.unwrap();
        assert!((m - 1.0).abs() < 0.05, "{m}");
        // Twice the contrast, twice the value.
        let loud = map(&at, |x| 2.0 * x);
        let m2 = view_interior(&at, &alpha, &loud, Some(spread))
            .motif_contrast
            .unwrap();
        assert!((m2 - 2.0 * m).abs() < 1e-9, "{m2} {m}");
    }

    #[test]
    fn the_sources_own_detail_is_no_style_texture() {
        // Motif contrast counts the object's own band pass; style texture does not, at
        // any gain, offset or polarity.
        let (img, alpha) = object(30.0);
        let maps: [fn(f32) -> f32; 4] = [|x| x, |x| 0.1 + 0.6 * x, |x| 2.0 * x, |x| 1.0 - x];
        for (k, f) in maps.into_iter().enumerate() {
            let v = view_interior(&img, &alpha, &map(&img, f), Some(0.05));
            assert!(v.motif_contrast.unwrap() > 0.1, "{k}: {v:?}");
            // 0 up to the f32 rounding of the mapped image.
            assert!(v.style_texture.unwrap() < 1e-6, "{k}: {v:?}");
        }
    }

    #[test]
    fn texture_added_over_the_source_keeps_about_its_own_style_texture() {
        let (img, alpha) = object(30.0);
        let tex = noise_image(W, H, 5);
        let with = |base: &Image, gain: f32| {
            Image::from_fn(W, H, |x, y| {
                let (p, t) = (base.px(x, y), tex.px(x, y));
                [0, 1, 2].map(|c| gain * p[c] + 0.3 * (t[c] - 0.5))
            })
        };
        // The texture alone (over a flat ground): its own value, all of it style texture.
        let alone = view_interior(&img, &alpha, &with(&img, 0.0), Some(0.05));
        let own = alone.motif_contrast.unwrap();
        assert!(own > 0.1, "{alone:?}");
        assert!(
            (alone.style_texture.unwrap() - own).abs() < 0.02 * own,
            "{alone:?}"
        );
        // Over the source, and over the source at half its contrast: the source's part
        // is projected out, the texture's kept; motif contrast counts both.
        for gain in [1.0, 0.5] {
            let v = view_interior(&img, &alpha, &with(&img, gain), Some(0.05));
            let st = v.style_texture.unwrap();
            assert!((st - own).abs() < 0.05 * own, "gain {gain}: {st} vs {own}");
            assert!(v.motif_contrast.unwrap() > 1.1 * st, "gain {gain}: {v:?}");
        }
    }

    #[test]
    fn unrelated_detail_recalls_about_chance() {
        let (w, h) = (240, 240);
        let alpha = vec![1.0; w * h];
        let v = view_interior(&noise_image(w, h, 1), &alpha, &noise_image(w, h, 2), None);
        let r = v.edge_recall.unwrap();
        assert!((r - CHANCE_RECALL).abs() < 0.03, "{r}");
        assert!(v.interior_structure.unwrap().abs() < 0.1);
        assert_eq!((v.motif_contrast, v.style_texture), (None, None));
        assert!(v.reasons.iter().any(|r| r.contains("style texture")));
    }

    #[test]
    fn too_small_an_interior_has_no_value_and_says_why() {
        // A disc of radius 12: its 8 px square erosion keeps |dx|, |dy| <= ~0.5.
        let (img, alpha) = object(12.0);
        let v = view_interior(&img, &alpha, &img, Some(0.05));
        assert!(v.pixels < MIN_INTERIOR_PIXELS, "{}", v.pixels);
        assert_eq!(
            (
                v.interior_structure,
                v.edge_recall,
                v.motif_contrast,
                v.style_texture
            ),
            (None, None, None, None)
        );
        assert!(v.reasons[0].contains("fewer than 64"), "{:?}", v.reasons);
        // No object at all: no pixels, no panic.
        let v = view_interior(&img, &vec![0.0; W * H], &img, Some(0.05));
        assert_eq!((v.pixels, v.edge_recall), (0, None));
    }
}
