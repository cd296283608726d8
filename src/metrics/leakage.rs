//! Content leakage (issue 38): the share of the stylized object's *large-scale* appearance
//! that no colour map of the original scene explains.
//!
//! **What it is for.** FantasyStyle (AAAI 2026) is written against *content leakage*: a
//! style image's content (its objects, its layout) landing on the scene, where only its
//! style (strokes, colours) should. A recipe that texture-maps the style image onto the
//! object (`--project-style`, the `arf` preset) does exactly that: with a portrait as the
//! style, a duck wears the helmet ring and the orange suit in large regions; with a cup
//! on a saucer, a plant's pot becomes the cup's white rim over red china. A texture
//! method (Gram, NNFM, a patch prior) should draw the style's motifs everywhere without
//! its layout; a colour transfer changes the palette only. The measure must rank the
//! first as leaking and the other two not, and must not simply reward doing less.
//!
//! **Principle.** Three things a stylization can do to the object, and the spatial scale
//! each lives at:
//!
//! * *palette*: the scene's colours mapped to others: at every scale, but a function of
//!   the original colour at the same place;
//! * *texture*: the style's motifs, at the scale the style is drawn (the texture term and
//!   the VGG baselines draw it at 256 px shorter side, their receptive fields 40-92 px:
//!   strokes, dots, bricks of 4-20 px), which averages out over a larger window;
//! * *content*: the style image's regions and objects, larger than its motifs (a helmet
//!   ring, a cup's rim: 30 px and more at that scale), and placed where the style image
//!   had them, not where the scene has its own structure.
//!
//! So: low-pass both the original and the stylized object at a scale above the motifs
//! ([`SIGMA_PX`]); fit the stylized low-pass colour as a smooth function of the original's
//! low-pass colour at the same pixel (a quadratic polynomial of the three channels, per
//! channel, least squares over the object). What the fit leaves is large-scale structure
//! the scene does not explain. Its share of the stylized object's whole colour variance,
//! in units of the same share for the style image itself, is the leakage of the view:
//!
//! ```text
//! u    = sum_{p, c} (s_bar_c(p) - f_c(o_bar(p)))^2 / sum_{p, c} (s_c(p) - mean s_c)^2
//! leak = u / u_style,   u_style = sum (x_bar - mean)^2 / sum (x - mean)^2 over the style
//! ```
//!
//! `u` is 0 when every large-scale change is a colour map of the scene (the original
//! itself, a colour transfer, a histogram finish) and when the change is fine texture,
//! however strong (it is averaged away before the fit and only adds to the denominator);
//! `u` is the style's own large-scale share `u_style` when a crop of the style replaces
//! the object, so `leak` ~ 1 means "as much unexplained large-scale structure as pasting
//! the style image". Dividing by the whole variance and not by the low-pass variance
//! keeps a fine texture on a plain object at 0 (the low-pass of a fine texture is small
//! but, on a plain object, all of it unexplained). `leak` is not bounded by 1 (a style
//! with little large-scale structure, a method that paints large blobs).
//!
//! **Definition, exactly.** Per view, with the original views' alpha `a` (the object),
//! the original `O` and the stylized `S` renders (premultiplied over black):
//!
//! 1. object mask `m = [a >= OBJECT_ALPHA]`; un-premultiplied colours `o = O / a`,
//!    `s = S / a` on the mask;
//! 2. normalised Gaussian low-pass (normalised convolution, Knutsson & Westin 1993) of
//!    every channel: `x_bar = G * (m x) / G * m`, `G` a Gaussian of standard deviation
//!    [`SIGMA_PX`] pixels truncated at `ceil(3 sigma)`, zero outside the image, so the
//!    black background and the silhouette add no structure;
//! 3. the pixels `P` with `m = 1` and `G * m >= SUPPORT` (a low-pass window at least half
//!    on the object), at least [`MIN_PIXELS`] of them, else the view has no value;
//! 4. `f_c(o) = phi(o) . beta_c` with `phi = [1, r, g, b, r^2, g^2, b^2, rg, rb, gb]` of
//!    the original's low-pass colour (centred on its mean over `P`), `beta_c` the least
//!    squares fit over `P` (normal equations, pseudo-inverse with eigenvalues below
//!    `1e-12` of the largest dropped: a plain original spans fewer columns);
//! 5. `u` as above over `P`; no value when the stylized object is flat (mean square below
//!    [`MIN_VAR`]);
//! 6. `u_style` ([`style_large_scale_share`]): the same low-pass over the whole style
//!    image at its drawing scale (shorter side [`super::texture::PATCH_STYLE_SIDE`], the
//!    texture term's and the projection's motif scale), the share of its colour variance
//!    that survives: 0.55 for the astronaut portrait, 0.63 for the coffee cup.
//!
//! The measure is the mean of `leak` over the views with a value, with a 95% Student-t
//! interval over those views. It is exactly invariant to a brightness/contrast change of
//! either render (an affine map of `o` is absorbed by `phi`; an affine map of `s` scales
//! the residual and the variance alike), and depends on no network: about a second for
//! 16 views of 256x256 (no FFT needed: two separable blurs per channel and a 10x10 solve).
//!
//! **Measured** (16 orbit views of 256x256 of the 100k-Gaussian duck `bob_100k`, astronaut
//! style; mean [95% interval]): the original 0.000; colour transfer 0.000 [0.000, 0.000];
//! Gram 30 steps 0.012 [0.009, 0.016]; NNFM 30 steps 0.005 [0.004, 0.006]; the projection
//! (`stylize-baseline --method project`, helmet rings and the orange suit on the duck)
//! 0.320 [0.258, 0.382]; the `arf` recipe (projection + 40 iterations of the NNFM + Gram
//! texture term + colour finish) 0.337 [0.273, 0.401]. With the coffee cup: projection
//! 0.153 [0.133, 0.173] (the cup's white rim in a band round the body), `arf` 0.172
//! [0.153, 0.191], Gram 0.010, colour transfer 0.000. The variant normalised by the
//! low-pass variance instead ranked every case the same (projection 0.48, Gram 0.033) but
//! gives a fine texture on a plain object 1.
//!
//! **Why not a copy detector.** The first candidates (a numpy trial during this module's
//! design; its script was not kept and its numbers are not re-measured here) matched the stylized object against
//! the style image itself: the best normalised cross-correlation of 32-48 px luminance
//! patches (contrast-normalised, plain and band-passed, at the drawing scale, also over
//! the eight flips and rotations and three scales) against every window of the style,
//! minus the same for the original views; and VGG16 relu4_3 / relu5_3 nearest-neighbour
//! cosine against the style's features, minus the original's. On the 100k-Gaussian duck
//! with the portrait, the pasted style scored *below* the original on every pixel variant
//! (-0.07 at 32 px): the projection wraps the style around a curved surface, blends three
//! planes and multiplies it by the object's shading, so no patch of the result is a patch
//! of the style, while the plain original's smooth patches match smooth style patches by
//! chance (0.75). relu5_3 ranked the pasted duck first but the pasted pot last (-0.08).
//! What survives every distortion is that
//! the pasted layout is new large-scale structure; that is what this measure counts.
//!
//! **What it cannot tell.** Whose structure it is: large blobs an optimiser paints on its
//! own (an early patch-prior run that covered the duck in orange, white and black blobs
//! with no recognisable piece of the portrait scored 0.14), or a style whose motifs are
//! larger than the low-pass window (a mosaic of 40 px cells), count as leakage too. Read it with the pictures and with
//! `style_large_scale_share`.

use super::html::{esc, fmt_opt, table};
use super::views::ViewSet;
use crate::imageio::Image;
use crate::maths::blur::{Border, separable, taps};
use crate::maths::linalg::sym_eig;
use rayon::prelude::*;
use serde::Serialize;

/// Standard deviation of the low-pass, pixels: above the motif scale of the texture
/// methods at their drawing scale (a Gaussian of sigma 8 keeps 0.2% of the amplitude of a
/// 14 px period, the op-art rings at 256 px, and 46% of a 60 px one, a helmet ring).
pub const SIGMA_PX: f64 = 8.0;
/// Least alpha of an object pixel (the original views').
pub const OBJECT_ALPHA: f32 = 0.95;
/// Least share of the low-pass window on the object for a pixel to count.
pub const SUPPORT: f64 = 0.5;
/// Fewest counted pixels for a view to have a value.
pub const MIN_PIXELS: usize = 64;
/// Least mean square (per pixel and channel) of the stylized colour for a view to have a
/// value.
pub const MIN_VAR: f64 = 1e-8;
/// Columns of the colour map: `1, r, g, b, r^2, g^2, b^2, rg, rb, gb`.
const BASIS: usize = 10;

/// `metrics.json`'s `leakage`.
#[derive(Debug, Clone, Serialize)]
pub struct Leakage {
    /// Mean over views of the share of the stylized low-pass variance the original does
    /// not explain (module docs); 0 = none.
    pub value: Option<f64>,
    /// 95% Student-t interval of the mean over views.
    pub ci95: Option<[f64; 2]>,
    /// Per view (`None`: too little object, or nothing to explain).
    pub per_view: Vec<Option<f64>>,
    /// Views with a value.
    pub views_used: usize,
    /// Mean over views of the unexplained share itself (before the division by
    /// `style_large_scale_share`).
    pub unexplained_share: Option<f64>,
    /// The style image's share of colour variance above the motif scale: what a pasted
    /// copy of the style brings, the unit of `value`.
    pub style_large_scale_share: Option<f64>,
    pub sigma_px: f64,
    pub note: &'static str,
}

/// What the value means, written beside it.
pub const NOTE: &str = "content leakage: per view, the stylized object's large-scale structure (normalised \
     Gaussian low-pass, sigma 8 px, over pixels with alpha >= 0.95) that a quadratic colour map of the original's \
     low-pass colour at the same pixel does not explain, as a share of the stylized object's colour variance, \
     divided by the same low-pass share of the style image (style_large_scale_share); 0 = every large-scale \
     change is a colour map of the scene or fine texture, 1 = as much as pasting the style image; mean over \
     views with a 95% Student-t interval";

/// The normalised Gaussian taps, radius `ceil(3 sigma)` ([`crate::maths::blur::taps`]).
pub fn gaussian_taps(sigma: f64) -> Vec<f64> {
    taps(sigma)
}

/// Separable convolution of a row-major `h x w` plane with symmetric `taps`, zero outside.
pub fn blur(x: &[f64], w: usize, h: usize, taps: &[f64]) -> Vec<f64> {
    separable(x, (h, w), taps, Border::Zero)
}

/// The normalised low-pass `G * (m x) / G * m` of `img`'s channels (divided by `alpha`
/// first where given) at the pixels `at`; `gm` = `G * m`.
fn low_pass_at(
    img: &Image,
    m: &[f64],
    alpha: Option<&[f32]>,
    gm: &[f64],
    taps: &[f64],
    at: &[usize],
) -> Vec<[f64; 3]> {
    let (w, h) = (img.width, img.height);
    let mut out = vec![[0.0; 3]; at.len()];
    for c in 0..3 {
        let plane: Vec<f64> = (0..w * h)
            .map(|p| {
                if m[p] == 0.0 {
                    return 0.0;
                }
                let v = img.data[p * 3 + c] as f64;
                m[p] * alpha.map_or(v, |a| v / a[p] as f64)
            })
            .collect();
        let b = blur(&plane, w, h, taps);
        for (o, &p) in out.iter_mut().zip(at) {
            o[c] = b[p] / gm[p];
        }
    }
    out
}

/// The colour map's row for the (centred) colour `x`.
fn basis(x: [f64; 3]) -> [f64; BASIS] {
    let [r, g, b] = x;
    [1.0, r, g, b, r * r, g * g, b * b, r * g, r * b, g * b]
}

/// Least-squares fit of each column of `y` on `phi(x)` (pseudo-inverse of the normal
/// matrix); returns the residual sum of squares over the three channels.
fn residual_after_fit(x: &[[f64; 3]], y: &[[f64; 3]]) -> f64 {
    let n = x.len();
    let mean = |v: &[[f64; 3]]| {
        let mut m = [0.0; 3];
        for p in v {
            (0..3).for_each(|c| m[c] += p[c] / n as f64);
        }
        m
    };
    let mx = mean(x);
    let rows: Vec<[f64; BASIS]> = x
        .iter()
        .map(|p| basis([p[0] - mx[0], p[1] - mx[1], p[2] - mx[2]]))
        .collect();
    let mut ata = vec![0.0; BASIS * BASIS];
    let mut aty = [[0.0; 3]; BASIS];
    for (r, t) in rows.iter().zip(y) {
        for i in 0..BASIS {
            for j in 0..BASIS {
                ata[i * BASIS + j] += r[i] * r[j];
            }
            for c in 0..3 {
                aty[i][c] += r[i] * t[c];
            }
        }
    }
    let e = sym_eig(&ata, BASIS);
    let top = e.values.first().copied().unwrap_or(0.0).max(0.0);
    // beta = V diag(1 / lambda) V^T A^T y over the eigenvalues kept.
    let mut beta = [[0.0; 3]; BASIS];
    for k in 0..BASIS {
        let l = e.values[k];
        if l <= 1e-12 * top || l <= 0.0 {
            continue;
        }
        for c in 0..3 {
            let proj: f64 = (0..BASIS)
                .map(|i| e.vectors[i * BASIS + k] * aty[i][c])
                .sum();
            for (i, b) in beta.iter_mut().enumerate() {
                b[c] += e.vectors[i * BASIS + k] * proj / l;
            }
        }
    }
    rows.iter()
        .zip(y)
        .map(|(r, t)| {
            (0..3)
                .map(|c| {
                    let f: f64 = (0..BASIS).map(|i| r[i] * beta[i][c]).sum();
                    (t[c] - f) * (t[c] - f)
                })
                .sum::<f64>()
        })
        .sum()
}

/// One view's sums (module docs): `orig` and `styl` the original and stylized renders,
/// `alpha` the original's (`h x w`); `None` when the view has too little object.
pub fn view_parts(orig: &Image, styl: &Image, alpha: &[f32]) -> Option<ViewParts> {
    let (w, h) = (orig.width, orig.height);
    assert_eq!(
        (styl.width, styl.height, alpha.len()),
        (w, h, w * h),
        "view_parts: sizes"
    );
    let m: Vec<f64> = alpha
        .iter()
        .map(|&a| if a >= OBJECT_ALPHA { 1.0 } else { 0.0 })
        .collect();
    let taps = gaussian_taps(SIGMA_PX);
    let gm = blur(&m, w, h, &taps);
    let at: Vec<usize> = (0..w * h)
        .filter(|&p| m[p] > 0.0 && gm[p] >= SUPPORT)
        .collect();
    if at.len() < MIN_PIXELS {
        return None;
    }
    let o = low_pass_at(orig, &m, Some(alpha), &gm, &taps, &at);
    let s = low_pass_at(styl, &m, Some(alpha), &gm, &taps, &at);
    let full: Vec<[f64; 3]> = at
        .iter()
        .map(|&p| {
            let a = alpha[p] as f64;
            std::array::from_fn(|c| styl.data[p * 3 + c] as f64 / a)
        })
        .collect();
    Some(ViewParts {
        residual: residual_after_fit(&o, &s),
        coarse: centred_sum_sq(&s),
        total: centred_sum_sq(&full),
        pixels: at.len(),
    })
}

/// The sums over one view's counted pixels `P` (module docs), all over the three channels.
#[derive(Debug, Clone, Copy)]
pub struct ViewParts {
    /// Residual sum of squares of the stylized low-pass after the colour map of the original's.
    pub residual: f64,
    /// Centred sum of squares of the stylized low-pass.
    pub coarse: f64,
    /// Centred sum of squares of the stylized colour itself (no low-pass).
    pub total: f64,
    /// Counted pixels.
    pub pixels: usize,
}

impl ViewParts {
    /// The share of the stylized object's colour variance that is large-scale structure
    /// the scene does not explain (`residual / total`); `None` for a flat object.
    pub fn unexplained_share(&self) -> Option<f64> {
        (self.total / ((3 * self.pixels) as f64) >= MIN_VAR)
            .then(|| (self.residual / self.total).clamp(0.0, 1.0))
    }
}

/// One view's leakage (module docs): [`ViewParts::unexplained_share`] over the style's
/// [`style_large_scale_share`] `style_share`.
pub fn view_leakage(orig: &Image, styl: &Image, alpha: &[f32], style_share: f64) -> Option<f64> {
    let u = view_parts(orig, styl, alpha)?.unexplained_share()?;
    (style_share > 0.0).then(|| u / style_share)
}

fn centred_sum_sq(v: &[[f64; 3]]) -> f64 {
    let n = v.len() as f64;
    (0..3)
        .map(|c| {
            let mu = v.iter().map(|p| p[c]).sum::<f64>() / n;
            v.iter().map(|p| (p[c] - mu) * (p[c] - mu)).sum::<f64>()
        })
        .sum()
}

/// The share of `style`'s colour variance that survives the low-pass, at its drawing
/// scale (shorter side [`super::texture::PATCH_STYLE_SIDE`]); `None` for a flat image.
pub fn style_large_scale_share(style: &Image) -> Option<f64> {
    let s = style.with_shorter_side(super::texture::PATCH_STYLE_SIDE);
    let (w, h) = (s.width, s.height);
    let m = vec![1.0; w * h];
    let taps = gaussian_taps(SIGMA_PX);
    let gm = blur(&m, w, h, &taps);
    let at: Vec<usize> = (0..w * h).collect();
    let low = low_pass_at(&s, &m, None, &gm, &taps, &at);
    let all: Vec<[f64; 3]> = s
        .data
        .chunks_exact(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let t = centred_sum_sq(&all);
    (t > 0.0).then(|| centred_sum_sq(&low) / t)
}

/// Two-sided 95% Student-t quantile for `df` degrees of freedom (table to 30, then the
/// Cornish-Fisher expansion, within 1e-3).
pub fn t95(df: usize) -> f64 {
    const T: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match df {
        0 => f64::NAN,
        1..=30 => T[df - 1],
        _ => {
            let (z, d) = (1.959964f64, df as f64);
            z + (z.powi(3) + z) / (4.0 * d)
                + (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / (96.0 * d * d)
        }
    }
}

/// Mean and 95% Student-t interval of `v` (no interval below two values).
pub fn mean_ci95(v: &[f64]) -> (Option<f64>, Option<[f64; 2]>) {
    let n = v.len();
    if n == 0 {
        return (None, None);
    }
    let m = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (Some(m), None);
    }
    let sd = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64).sqrt();
    let half = t95(n - 1) * sd / (n as f64).sqrt();
    (Some(m), Some([m - half, m + half]))
}

/// The leakage of `styl` against `orig` (the same views) and the style image `style`.
pub fn leakage(orig: &ViewSet, styl: &ViewSet, style: &Image) -> Leakage {
    let share = style_large_scale_share(style);
    let parts: Vec<Option<ViewParts>> = (0..orig.n)
        .into_par_iter()
        .map(|i| view_parts(&orig.images[i], &styl.images[i], orig.geometry(i).1))
        .collect();
    let unexplained: Vec<Option<f64>> = parts
        .iter()
        .map(|p| p.and_then(|p| p.unexplained_share()))
        .collect();
    let per_view: Vec<Option<f64>> = unexplained
        .iter()
        .map(|u| u.zip(share.filter(|&s| s > 0.0)).map(|(u, s)| u / s))
        .collect();
    let used: Vec<f64> = per_view.iter().flatten().copied().collect();
    let (value, ci95) = mean_ci95(&used);
    let raw: Vec<f64> = unexplained.iter().flatten().copied().collect();
    Leakage {
        value,
        ci95,
        views_used: used.len(),
        per_view,
        unexplained_share: mean_ci95(&raw).0,
        style_large_scale_share: share,
        sigma_px: SIGMA_PX,
        note: NOTE,
    }
}

/// The report's "Content leakage" section.
pub fn html(l: &Leakage) -> String {
    let interval = l
        .ci95
        .map_or(String::new(), |[a, b]| format!(" [{a:.3}, {b:.3}]"));
    let rows = vec![
        vec![
            "content leakage (large-scale structure the scene does not explain) ↓".into(),
            format!("{}{interval}", fmt_opt(l.value, 3)),
            format!(
                "{} of {} views; 0 for the original and for any colour map of it",
                l.views_used,
                l.per_view.len()
            ),
        ],
        vec![
            "the style's share of colour variance above the motif scale".into(),
            fmt_opt(l.style_large_scale_share, 3),
            "context: what a pasted copy of the style brings (high for a photograph, low for a fine texture)"
                .into(),
        ],
    ];
    let per: Vec<String> = l.per_view.iter().map(|v| fmt_opt(*v, 3)).collect();
    format!(
        "{}<p class=\"note\">Per view: {}</p><p class=\"note\">{}</p>",
        table(&["measure", "value (95% interval)", "notes"], &rows),
        per.join(", "),
        esc(l.note)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 96;

    /// A disc of radius 40 (alpha 1, 0 outside).
    fn alpha() -> Vec<f32> {
        (0..W * W)
            .map(|p| {
                let (x, y) = ((p % W) as f32 - 47.5, (p / W) as f32 - 47.5);
                if x * x + y * y <= 40.0 * 40.0 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// A shaded sphere, slightly warm: the original.
    fn original() -> Image {
        Image::from_fn(W, W, |x, y| {
            let (u, v) = ((x as f32 - 47.5) / 40.0, (y as f32 - 47.5) / 40.0);
            let n = (1.0 - u * u - v * v).max(0.0).sqrt();
            let l = 0.15 + 0.7 * (0.3 * -u + 0.4 * -v + 0.87 * n).max(0.0);
            [l, 0.9 * l, 0.8 * l]
        })
    }

    /// Cheap deterministic noise in [0, 1).
    fn hash(i: usize) -> f32 {
        let mut z = (i as u64).wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A "photograph": large regions (a dark disc with a bright ring, an orange body, a
    /// blue band) with a little fine grain, 256 x 256.
    fn photo() -> Image {
        Image::from_fn(256, 256, |x, y| {
            let (fx, fy) = (x as f32, y as f32);
            let d = ((fx - 110.0).powi(2) + (fy - 90.0).powi(2)).sqrt();
            let mut c = if fy > 160.0 {
                [0.9, 0.45, 0.1]
            } else if fx > 200.0 {
                [0.1, 0.2, 0.7]
            } else {
                [0.75, 0.75, 0.7]
            };
            if d < 45.0 {
                c = [0.05, 0.05, 0.08];
            } else if d < 60.0 {
                c = [0.95, 0.95, 0.95];
            }
            let g = 0.06 * (hash(y * 256 + x) - 0.5);
            [c[0] + g, c[1] + g, c[2] + g]
        })
    }

    /// `f(original colour, pixel)` on the object, premultiplied by alpha.
    fn stylized(f: impl Fn([f32; 3], usize, usize) -> [f32; 3]) -> Image {
        let (o, a) = (original(), alpha());
        Image::from_fn(W, W, |x, y| {
            let p = y * W + x;
            let c = f([o.data[p * 3], o.data[p * 3 + 1], o.data[p * 3 + 2]], x, y);
            c.map(|v| v * a[p])
        })
    }

    fn score(s: &Image) -> f64 {
        let share = style_large_scale_share(&photo()).unwrap();
        view_leakage(&original(), s, &alpha(), share).unwrap()
    }

    /// The style's crop at the object, from (ox, oy).
    fn pasted(ox: usize, oy: usize) -> Image {
        let ph = photo();
        stylized(|_, x, y| {
            let q = ((y + oy) * 256 + x + ox) * 3;
            [ph.data[q], ph.data[q + 1], ph.data[q + 2]]
        })
    }

    #[test]
    fn a_pasted_crop_of_the_style_scores_near_one() {
        for (ox, oy) in [(40, 30), (60, 100), (100, 40)] {
            let l = score(&pasted(ox, oy));
            // An 80 px crop holds less of the style's large-scale structure than the
            // whole 256 px image: about half to all of a paste of it.
            assert!((0.4..1.6).contains(&l), "pasted at ({ox}, {oy}): {l}");
        }
        // Multiplied by the object's shading (what a projection does) it still leaks.
        let ph = photo();
        let shaded = stylized(|o, x, y| {
            let q = ((y + 100) * 256 + x + 60) * 3;
            [0, 1, 2].map(|c| ph.data[q + c] * o[0] / 0.6)
        });
        let l = score(&shaded);
        assert!(l > 0.3, "pasted and shaded: {l}");
    }

    #[test]
    fn the_original_and_colour_maps_of_it_score_zero() {
        assert!(score(&original()) < 1e-9);
        // Palette only: a nonlinear map of the original colour (a colour transfer, a
        // histogram finish) onto the style's orange and blue.
        let map = stylized(|o, _, _| {
            let t = o[0];
            [0.9 * t.sqrt(), 0.45 * t + 0.2 * t * t, 0.7 - 0.6 * t]
        });
        let l = score(&map);
        assert!(l < 0.01, "colour map: {l}");
    }

    #[test]
    fn fine_random_texture_scores_near_zero() {
        // Strong pixel noise over the shading, and noise alone replacing it.
        let over = stylized(|o, x, y| {
            let n = hash(y * W + x + 7);
            [o[0] * (0.4 + 1.2 * n), o[1] * (0.4 + 1.2 * n), o[2]]
        });
        let l = score(&over);
        assert!(l < 0.05, "noise over the shading: {l}");
        let alone = stylized(|_, x, y| [0, 1, 2].map(|c| hash(3 * (y * W + x) + c)));
        let l = score(&alone);
        assert!(l < 0.05, "noise alone: {l}");
        // Motifs of 3 x 3 px blocks in the style's colours.
        let blocks = stylized(|_, x, y| {
            let n = hash((y / 3) * 1000 + x / 3);
            if n < 0.5 {
                [0.9, 0.45, 0.1]
            } else {
                [0.1, 0.2, 0.7]
            }
        });
        let l = score(&blocks);
        assert!(l < 0.1, "3 px motifs: {l}");
    }

    #[test]
    fn invariant_to_brightness_and_contrast() {
        let base = score(&pasted(60, 100));
        let ph = photo();
        let dim = stylized(|_, x, y| {
            let q = ((y + 100) * 256 + x + 60) * 3;
            [0, 1, 2].map(|c| 0.1 + 0.5 * ph.data[q + c])
        });
        // (1e-6: the images hold f32.)
        assert!(
            (score(&dim) - base).abs() < 1e-6,
            "{} vs {base}",
            score(&dim)
        );
        // Of the original too: an affine map of its colour is absorbed by the colour map.
        let share = style_large_scale_share(&photo()).unwrap();
        let o = original();
        let a = alpha();
        let o2 = Image::from_fn(W, W, |x, y| {
            let p = y * W + x;
            [0, 1, 2].map(|c| (0.05 + 0.6 * o.data[p * 3 + c]) * a[p])
        });
        let l = view_leakage(&o2, &pasted(60, 100), &a, share).unwrap();
        assert!((l - base).abs() < 1e-6, "{l} vs {base}");
    }

    #[test]
    fn the_fit_is_exact_for_quadratic_colour_maps() {
        let x: Vec<[f64; 3]> = (0..200)
            .map(|i| [0, 1, 2].map(|c| hash(3 * i + c) as f64))
            .collect();
        let y: Vec<[f64; 3]> = x
            .iter()
            .map(|&[r, g, b]| [0.3 + r * g - 2.0 * b, b * b, 0.1 * r + g * b])
            .collect();
        assert!(residual_after_fit(&x, &y) < 1e-18);
        let z: Vec<[f64; 3]> = (0..200)
            .map(|i| [0, 1, 2].map(|c| hash(1000 + 3 * i + c) as f64))
            .collect();
        assert!(residual_after_fit(&x, &z) > 1.0);
    }

    #[test]
    fn blur_keeps_constants_and_taps_sum_to_one() {
        let t = gaussian_taps(SIGMA_PX);
        assert_eq!(t.len(), 2 * 24 + 1);
        assert!((t.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let b = blur(&vec![2.0; 64 * 64], 64, 64, &t);
        assert!((b[32 * 64 + 32] - 2.0).abs() < 1e-12);
        assert!(b[0] < 2.0 * 0.3, "zero outside: {}", b[0]);
    }

    #[test]
    fn student_t_interval() {
        assert_eq!(t95(1), 12.706);
        assert!((t95(31) - 2.040).abs() < 1e-3, "{}", t95(31));
        assert!((t95(120) - 1.980).abs() < 1e-3, "{}", t95(120));
        let (m, ci) = mean_ci95(&[1.0, 2.0, 3.0]);
        assert_eq!(m, Some(2.0));
        let [lo, hi] = ci.unwrap();
        assert!(
            (hi - 2.0 - 4.303 / 3f64.sqrt()).abs() < 1e-9 && (2.0 - lo - (hi - 2.0)).abs() < 1e-12
        );
        assert_eq!(mean_ci95(&[]), (None, None));
    }
}
