//! Measures that see texture (issue 21, item 5), beside the whole-image Gram distance of
//! [`super::gram`] (which the Gram baseline optimises directly, so it flatters it), and
//! the object measures the quality benchmark reads. All of them land in `metrics.json`
//! under `texture` and in a section of the report.
//!
//! * **Per-layer Gram distance over the object.** For each LPIPS-VGG16 tap relu1_2,
//!   relu2_2, relu3_3, relu4_3 (relu1_2 and relu2_2 carry the motifs), the mean squared
//!   difference `mean_{c,c'} (G(x) - G(s))^2` between the stylized view's Gram matrix and
//!   the style image's, and the same for the original view; the report gives both and
//!   their ratio (stylized / original: below 1 = closer to the style than the original
//!   was). **Object region:** the view's Gram is alpha-weighted,
//!   `G = sum_p w_p f_p f_p^T / sum_p w_p`, with the rendered alpha box-averaged to each
//!   tap's resolution as `w`, so the black background, which fills most of an orbit view,
//!   does not dominate the statistics (a whole-image Gram mostly measures how much black
//!   there is). Features near the silhouette still see some background through their
//!   receptive fields; the style image's Gram is over the whole image. Computed with
//!   [`crate::maths::gram::gram`] on `sqrt(w)`-scaled features. Mean over the views that show
//!   the object.
//! * **KID with its interval.** The unbiased KID of [`super::fid::kid`] (stylized views vs
//!   style crops) with a jackknife standard error (Arvesen's two-sample jackknife:
//!   leave one image out of each set in turn, `var = (n-1)/n sum (theta_-i - mean)^2`
//!   per set, summed), and `value +- 1.96 se`. Reliable when both sets have at least
//!   [`KID_MIN_IMAGES`] images.
//! * **KID over the object's surface** (`kid_object`). The whole-view KID compares
//!   orbit views (an object on black) with crops of the style image, so what it mostly
//!   measures is that difference of framing: on the quality benchmark the untouched
//!   original renders had a lower mean than every method (docs/evaluation.md "A KID that sees
//!   the object's surface"). This one compares like with like: [`PATCH_SIDE`]-pixel
//!   squares from inside the object (mean alpha of the original view at least
//!   [`PATCH_COVERAGE`], up to [`PATCHES_PER_VIEW`] per view by default (`evaluate
//!   --object-squares`; 0 skips the measure, whose Inception passes are most of its
//!   cost), at least half a side apart, drawn with the evaluation's seed; the same
//!   squares in the stylized and the original views) against [`STYLE_PATCHES`] squares of the same side
//!   from the style image at the scale the texture term and the VGG baselines draw it
//!   (shorter side [`PATCH_STYLE_SIDE`]). Inception resizes every square to 299 px. The
//!   original's value is reported beside the stylized one (the reference: a method that
//!   changes nothing gets it). Interval and reliability as for the KID above.
//! * **Motif scale.** The radially averaged luminance power spectrum of the object
//!   ([`super::spectrum`]) against the style image's: the mean normalised spectrum over
//!   views, its log distance to the style's and its peak, for the stylized and the
//!   original views (curves in `metrics.json`, plotted in the report).
//! * **Object colour.** Over covered pixels (alpha > 0.5) of the original views'
//!   alpha, colours un-premultiplied (divided by alpha; the views are rendered over black):
//!   the share of *clipped* pixels (all channels <= 0.02 or all >= 0.98), and the distance
//!   of the colour statistics to the style image's, `|mu - mu_s| + ||C - C_s||_F`
//!   (unbiased covariances of the colours clipped to [0, 1]); over the silhouette fringe
//!   (0.02 < alpha < 0.5), the mean brightening stylized - original over channels (the
//!   "glowing haze" of issue 11). These were `scripts/quality_summary.py`'s; the script
//!   now reads them from here.

use super::fid::FeatureSet;
use super::html::{Series, esc, fmt_opt, svg_plot, table};
use super::nets::Features;
use super::spectrum;
use super::views::ViewSet;
use crate::imageio::Image;
use crate::maths::gram::gram;
use crate::maths::kid::{kernel_matrix, mmd2};
use crate::vgg::Tensor3;
use serde::Serialize;

/// The LPIPS-VGG16 taps the per-layer Gram distance reports (taps 0..4 of the five).
pub const GRAM_LAYERS: [&str; 4] = ["relu1_2", "relu2_2", "relu3_3", "relu4_3"];

/// Fewest images per set for a KID the benchmark calls reliable (issue 21: 16 views).
pub const KID_MIN_IMAGES: usize = 16;

/// Views whose object covers less than this many pixels (sum of alpha) are skipped by the
/// object measures.
const MIN_COVERAGE: f64 = 16.0;

/// The per-layer Gram distance over the object.
#[derive(Debug, Clone, Serialize)]
pub struct LayerGram {
    pub layer: &'static str,
    /// Mean over views of the stylized view's distance to the style.
    pub stylized: Option<f64>,
    /// The same for the original views.
    pub original: Option<f64>,
    /// `stylized / original`.
    pub ratio: Option<f64>,
    /// Per view (`None`: no object in the view).
    pub stylized_per_view: Vec<Option<f64>>,
    pub original_per_view: Vec<Option<f64>>,
}

/// KID_style with its jackknife interval.
#[derive(Debug, Clone, Serialize)]
pub struct KidInterval {
    pub value: Option<f64>,
    /// Jackknife standard error.
    pub se: Option<f64>,
    /// `value -+ 1.96 se`.
    pub ci95: Option<[f64; 2]>,
    pub n_a: usize,
    pub n_b: usize,
    pub reliable: bool,
    pub note: String,
}

/// The motif-scale comparison.
#[derive(Debug, Clone, Serialize)]
pub struct SpectrumMetrics {
    /// Band centres, cycles per pixel.
    pub frequencies: Vec<f64>,
    /// Normalised radial spectra (`None`: empty band): mean over views with an object.
    pub stylized: Vec<Option<f64>>,
    pub original: Vec<Option<f64>>,
    pub style: Vec<Option<f64>>,
    /// Log-spectrum distance (decades, RMS) of the mean spectra to the style's.
    pub distance_stylized: Option<f64>,
    pub distance_original: Option<f64>,
    /// `distance_stylized / distance_original`.
    pub distance_ratio: Option<f64>,
    /// Per view: the stylized view's distance to the style.
    pub distance_per_view: Vec<Option<f64>>,
    /// Peak band centres, cycles per pixel (period = 1 / peak px).
    pub peak_stylized: Option<f64>,
    pub peak_original: Option<f64>,
    pub peak_style: Option<f64>,
}

/// Colour measures over the object (see module docs).
#[derive(Debug, Clone, Serialize)]
pub struct ObjectColour {
    pub clipped_original: Option<f64>,
    pub clipped_stylized: Option<f64>,
    /// Mean (stylized - original) over the fringe pixels and channels.
    pub fringe_brightening: Option<f64>,
    pub fringe_pixels: usize,
    pub stats_distance_original: Option<f64>,
    pub stats_distance_stylized: Option<f64>,
}

/// `metrics.json`'s `texture`.
#[derive(Debug, Clone, Serialize)]
pub struct TextureMetrics {
    pub gram_object: Vec<LayerGram>,
    pub kid_style: KidInterval,
    /// KID of squares inside the object against squares of the style (module docs).
    pub kid_object: KidInterval,
    /// The same for the original views' squares (the reference).
    pub kid_object_original: KidInterval,
    pub spectrum: SpectrumMetrics,
    pub object: ObjectColour,
    pub notes: Vec<&'static str>,
}

/// What each measure means, written beside the values.
pub const NOTES: [&str; 5] = [
    "gram_object: per LPIPS-VGG16 tap, mean over views of mean_{c,c'} (G(view) - G(style))^2 with the view's Gram \
     alpha-weighted over the object (alpha box-averaged to the tap's resolution); ratio = stylized / original",
    "kid_style: unbiased KID (cubic polynomial kernel) of the stylized views vs the style crops, with Arvesen's \
     two-sample jackknife standard error; reliable with at least 16 images per set",
    "kid_object: the same KID over 32 px squares inside the object (mean alpha >= 0.95, up to 4 per view, the \
     same squares in the original views: kid_object_original) vs 64 squares of the style at shorter side 256 \
     (the scale the texture term and the VGG baselines draw it); the whole-view kid_style mostly measures the \
     framing (an object on black vs a texture)",
    "spectrum: radially averaged power spectrum of the object's alpha-windowed zero-mean luminance (style: \
     Hann-windowed), 24 bands of a quarter octave from 1/128 to 1/2 cycle per pixel, normalised by the mean \
     non-DC power; distance = RMS of log10 ratios (decades); peak = band of most power per band",
    "object: covered = alpha > 0.5 of the original views, colours divided by alpha (views over black); clipped = \
     all channels <= 0.02 or >= 0.98; stats distance = |mean - style mean| + ||cov - style cov||_F; fringe = \
     0.02 < alpha < 0.5, mean stylized - original",
];

/// Box-average `alpha` (`h x w`) to `th x tw` with the integer factors `h / th`,
/// `w / tw` (VGG's floor poolings: position `y` of a tap `2^k` times smaller covers input
/// rows `y 2^k .. (y+1) 2^k`).
pub fn pool_alpha(alpha: &[f32], w: usize, h: usize, tw: usize, th: usize) -> Vec<f32> {
    let (fy, fx) = ((h / th.max(1)).max(1), (w / tw.max(1)).max(1));
    let inv = 1.0 / (fx * fy) as f32;
    let mut out = vec![0.0; tw * th];
    for y in 0..th {
        for x in 0..tw {
            let mut s = 0.0;
            for dy in 0..fy {
                let row = (y * fy + dy).min(h - 1) * w;
                for dx in 0..fx {
                    s += alpha[row + (x * fx + dx).min(w - 1)];
                }
            }
            out[y * tw + x] = s * inv;
        }
    }
    out
}

/// The Gram matrix of `t` weighted by `weights` (one per position):
/// `sum_p w_p f_p f_p^T / sum_p w_p`; `None` when the weights sum to less than 1e-6.
pub fn weighted_gram(t: &Tensor3, weights: &[f32]) -> Option<Vec<f64>> {
    let hw = t.h * t.w;
    assert_eq!(weights.len(), hw, "weighted_gram: weights size");
    let sw: f64 = weights.iter().map(|&v| v as f64).sum();
    if sw < 1e-6 {
        return None;
    }
    let root: Vec<f32> = weights.iter().map(|&v| v.max(0.0).sqrt()).collect();
    let mut scaled = t.clone();
    for ch in scaled.data.chunks_exact_mut(hw) {
        ch.iter_mut().zip(&root).for_each(|(f, r)| *f *= r);
    }
    let k = hw as f64 / sw;
    let mut g = gram(&scaled);
    g.iter_mut().for_each(|v| *v *= k);
    Some(g)
}

fn mean_sq_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64
}

fn mean_some(v: &[Option<f64>]) -> Option<f64> {
    let s: Vec<f64> = v.iter().flatten().copied().collect();
    (!s.is_empty()).then(|| s.iter().sum::<f64>() / s.len() as f64)
}

fn ratio(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => Some(a / b),
        _ => None,
    }
}

/// Accumulates the per-layer object Gram distances view by view (the evaluation's VGG
/// loop feeds it the features it computes anyway).
#[derive(Debug, Clone)]
pub struct ObjectGram {
    style: Vec<Vec<f64>>,
    stylized: Vec<Vec<Option<f64>>>,
    original: Vec<Vec<Option<f64>>>,
}

impl ObjectGram {
    /// `style_grams`: the style image's Gram matrices per tap (at least the four of
    /// [`GRAM_LAYERS`], in tap order).
    pub fn new(style_grams: &[Vec<f64>]) -> ObjectGram {
        assert!(style_grams.len() >= GRAM_LAYERS.len(), "ObjectGram: taps");
        ObjectGram {
            style: style_grams[..GRAM_LAYERS.len()].to_vec(),
            stylized: vec![Vec::new(); GRAM_LAYERS.len()],
            original: vec![Vec::new(); GRAM_LAYERS.len()],
        }
    }

    /// One view's distance to the style per layer of [`GRAM_LAYERS`] (`None` where the
    /// view covers less than `MIN_COVERAGE`), from its features and its alpha (`h x w`,
    /// the image's).
    pub fn view_distances(
        &self,
        f: &Features,
        alpha: &[f32],
        w: usize,
        h: usize,
    ) -> Vec<Option<f64>> {
        let covered = alpha.iter().map(|&a| a as f64).sum::<f64>() >= MIN_COVERAGE;
        (0..GRAM_LAYERS.len())
            .map(|k| {
                let f = &f[k];
                covered
                    .then(|| weighted_gram(f, &pool_alpha(alpha, w, h, f.w, f.h)))
                    .flatten()
                    .map(|g| mean_sq_diff(&g, &self.style[k]))
            })
            .collect()
    }

    /// One view: the [`Self::view_distances`] of its stylized and of its original render.
    pub fn push(&mut self, stylized: &[Option<f64>], original: &[Option<f64>]) {
        for k in 0..GRAM_LAYERS.len() {
            self.stylized[k].push(stylized[k]);
            self.original[k].push(original[k]);
        }
    }

    /// The per-layer summary.
    pub fn finish(self) -> Vec<LayerGram> {
        GRAM_LAYERS
            .iter()
            .enumerate()
            .map(|(k, &layer)| {
                let (s, o) = (mean_some(&self.stylized[k]), mean_some(&self.original[k]));
                LayerGram {
                    layer,
                    stylized: s,
                    original: o,
                    ratio: ratio(s, o),
                    stylized_per_view: self.stylized[k].clone(),
                    original_per_view: self.original[k].clone(),
                }
            })
            .collect()
    }
}

/// KID (the value of [`super::fid::kid`]) and its two-sample jackknife standard error;
/// `None` for the error when a set has fewer than 3 images.
pub fn kid_jackknife(a: &FeatureSet, b: &FeatureSet) -> Option<(f64, Option<f64>)> {
    if a.n < 2 || b.n < 2 || a.d != b.d {
        return None;
    }
    let kaa = kernel_matrix(&a.data, a.n, &a.data, a.n, a.d);
    let kbb = kernel_matrix(&b.data, b.n, &b.data, b.n, b.d);
    let kab = kernel_matrix(&a.data, a.n, &b.data, b.n, a.d);
    let (mut ka, mut kb) = (vec![true; a.n], vec![true; b.n]);
    let full = mmd2(&kaa, &kbb, &kab, a.n, b.n, &ka, &kb);
    if a.n < 3 || b.n < 3 {
        return Some((full, None));
    }
    let mut var = 0.0;
    for side in 0..2 {
        let n = if side == 0 { a.n } else { b.n };
        let mut th = Vec::with_capacity(n);
        for i in 0..n {
            let keep = if side == 0 { &mut ka } else { &mut kb };
            keep[i] = false;
            th.push(mmd2(&kaa, &kbb, &kab, a.n, b.n, &ka, &kb));
            let keep = if side == 0 { &mut ka } else { &mut kb };
            keep[i] = true;
        }
        let m = th.iter().sum::<f64>() / n as f64;
        var += (n - 1) as f64 / n as f64 * th.iter().map(|t| (t - m) * (t - m)).sum::<f64>();
    }
    Some((full, Some(var.sqrt())))
}

/// KID_style with its interval from the Inception features of the stylized views and of
/// the style crops.
pub fn kid_interval(styl: &[Vec<f32>], crops: &[Vec<f32>], sets: [&str; 2]) -> KidInterval {
    let (na, nb) = (styl.len(), crops.len());
    let r = (na >= 2 && nb >= 2)
        .then(|| kid_jackknife(&FeatureSet::from_rows(styl), &FeatureSet::from_rows(crops)))
        .flatten();
    let (value, se) = match r {
        Some((v, se)) => (Some(v), se),
        None => (None, None),
    };
    let reliable = na.min(nb) >= KID_MIN_IMAGES;
    KidInterval {
        value,
        se,
        ci95: value.zip(se).map(|(v, s)| [v - 1.96 * s, v + 1.96 * s]),
        n_a: na,
        n_b: nb,
        reliable,
        note: format!(
            "{na} {} vs {nb} {}; {}",
            sets[0],
            sets[1],
            if reliable {
                "interval from the two-sample jackknife".to_string()
            } else {
                format!(
                    "fewer than {KID_MIN_IMAGES} images per set: high variance, compare with care"
                )
            }
        ),
    }
}

/// Side of the object KID's squares, pixels: fixed in pixels, since the methods draw the
/// style at a fixed pixel scale; 32 is what fits inside the benchmark's objects (7-9% of
/// a 256 px view: the plant's pot, the fish's body; no 48 px square fits the plant).
pub const PATCH_SIDE: usize = 32;
/// Least mean alpha of an object square.
pub const PATCH_COVERAGE: f64 = 0.95;
/// Object squares per view, at most (`evaluate --object-squares`'s default).
pub const PATCHES_PER_VIEW: usize = 4;
/// Squares of the style image.
pub const STYLE_PATCHES: usize = 64;
/// The style's shorter side for its squares (the texture term's and the VGG baselines'
/// default `--style-size`).
pub const PATCH_STYLE_SIDE: usize = 256;
const _: () = assert!(
    PATCH_STYLE_SIDE >= PATCH_SIDE,
    "a style square must fit the style"
);

/// Where the object squares lie: `(view, x0, y0)` of [`PATCH_SIDE`]-pixel squares whose
/// mean alpha is at least [`PATCH_COVERAGE`], on a grid of stride `PATCH_SIDE / 4`, drawn
/// in a seeded order, each kept only if it is at least half a side away (in x or in y)
/// from the ones kept before it, up to `per_view` per view. `alpha` holds the
/// `w x h` alpha of each view, one after the other (a [`ViewSet`]'s `alpha`).
pub fn object_patch_positions(
    alpha: &[f32],
    w: usize,
    h: usize,
    per_view: usize,
    seed: u64,
) -> Vec<(usize, usize, usize)> {
    let p = PATCH_SIDE;
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-object-patches");
    let mut out = Vec::new();
    if w < p || h < p {
        return out;
    }
    let stride = p / 4;
    for (i, alpha) in alpha.chunks_exact(w * h).enumerate() {
        // Summed-area table, (h + 1) x (w + 1).
        let mut sat = vec![0.0f64; (h + 1) * (w + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += alpha[y * w + x] as f64;
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        let sum = |x: usize, y: usize| {
            sat[(y + p) * (w + 1) + x + p] - sat[y * (w + 1) + x + p] - sat[(y + p) * (w + 1) + x]
                + sat[y * (w + 1) + x]
        };
        let mut cand: Vec<(usize, usize)> = (0..=(h - p) / stride)
            .flat_map(|gy| (0..=(w - p) / stride).map(move |gx| (gx * stride, gy * stride)))
            .filter(|&(x, y)| sum(x, y) >= PATCH_COVERAGE * (p * p) as f64)
            .collect();
        let mut kept: Vec<(usize, usize)> = Vec::new();
        while kept.len() < per_view && !cand.is_empty() {
            let k = ((rng.uniform() * cand.len() as f64) as usize).min(cand.len() - 1);
            let (x, y) = cand.swap_remove(k);
            if kept
                .iter()
                .all(|&(a, b)| x.abs_diff(a) >= p / 2 || y.abs_diff(b) >= p / 2)
            {
                kept.push((x, y));
            }
        }
        out.extend(kept.into_iter().map(|(x, y)| (i, x, y)));
    }
    out
}

/// The squares of `views` at `positions` (from [`object_patch_positions`]).
pub fn object_patches(views: &ViewSet, positions: &[(usize, usize, usize)]) -> Vec<Image> {
    positions
        .iter()
        .map(|&(i, x, y)| views.images[i].crop(x, y, PATCH_SIDE, PATCH_SIDE))
        .collect()
}

/// [`STYLE_PATCHES`] seeded squares of the style at shorter side [`PATCH_STYLE_SIDE`].
pub fn style_patches(style: &Image, seed: u64) -> Vec<Image> {
    // Shorter side PATCH_STYLE_SIDE >= PATCH_SIDE: every square fits.
    let (s, p) = (style.with_shorter_side(PATCH_STYLE_SIDE), PATCH_SIDE);
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-style-patches");
    (0..STYLE_PATCHES)
        .map(|_| {
            let x = ((rng.uniform() * (s.width - p + 1) as f64) as usize).min(s.width - p);
            let y = ((rng.uniform() * (s.height - p + 1) as f64) as usize).min(s.height - p);
            s.crop(x, y, p, p)
        })
        .collect()
}

/// The motif-scale comparison of the views and the style image.
pub fn spectrum_metrics(orig: &ViewSet, styl: &ViewSet, style: &Image) -> SpectrumMetrics {
    let (w, h) = (orig.width, orig.height);
    let mut ss = Vec::new();
    let mut os = Vec::new();
    let st =
        spectrum::radial_spectrum(&spectrum::windowed_signal(style), style.width, style.height);
    let mut per_view = Vec::with_capacity(orig.n);
    for i in 0..orig.n {
        let (_, alpha) = orig.geometry(i);
        let s = spectrum::object_signal(&styl.images[i], alpha)
            .map(|sig| spectrum::radial_spectrum(&sig, w, h));
        let o = spectrum::object_signal(&orig.images[i], alpha)
            .map(|sig| spectrum::radial_spectrum(&sig, w, h));
        per_view.push(s.as_ref().and_then(|s| spectrum::distance(s, &st)));
        ss.extend(s);
        os.extend(o);
    }
    let (ms, mo) = (spectrum::mean_spectrum(&ss), spectrum::mean_spectrum(&os));
    let nonempty = |v: &[Vec<Option<f64>>], m: Vec<Option<f64>>| (!v.is_empty()).then_some(m);
    let (ms, mo) = (nonempty(&ss, ms), nonempty(&os, mo));
    let ds = ms.as_ref().and_then(|m| spectrum::distance(m, &st));
    let dor = mo.as_ref().and_then(|m| spectrum::distance(m, &st));
    SpectrumMetrics {
        frequencies: (0..spectrum::BINS).map(spectrum::band_centre).collect(),
        peak_stylized: ms.as_ref().and_then(|m| spectrum::peak(m)),
        peak_original: mo.as_ref().and_then(|m| spectrum::peak(m)),
        peak_style: spectrum::peak(&st),
        stylized: ms.unwrap_or_else(|| vec![None; spectrum::BINS]),
        original: mo.unwrap_or_else(|| vec![None; spectrum::BINS]),
        style: st,
        distance_stylized: ds,
        distance_original: dor,
        distance_ratio: ratio(ds, dor),
        distance_per_view: per_view,
    }
}

/// `|mu_a - mu_b| + ||C_a - C_b||_F` of two RGB sets (unbiased covariances).
pub fn stats_distance(a: &[[f64; 3]], b: &[[f64; 3]]) -> Option<f64> {
    if a.len() < 2 || b.len() < 2 {
        return None;
    }
    let stats = |v: &[[f64; 3]]| {
        let n = v.len() as f64;
        let mut mu = [0.0; 3];
        for p in v {
            (0..3).for_each(|c| mu[c] += p[c] / n);
        }
        let mut cov = [0.0; 9];
        for p in v {
            for i in 0..3 {
                for j in 0..3 {
                    cov[i * 3 + j] += (p[i] - mu[i]) * (p[j] - mu[j]) / (n - 1.0);
                }
            }
        }
        (mu, cov)
    };
    let ((ma, ca), (mb, cb)) = (stats(a), stats(b));
    let dm = (0..3).map(|c| (ma[c] - mb[c]).powi(2)).sum::<f64>().sqrt();
    let dc = (0..9).map(|k| (ca[k] - cb[k]).powi(2)).sum::<f64>().sqrt();
    Some(dm + dc)
}

/// Clipped share, colour-statistics distance and fringe brightening (see module docs).
pub fn object_colour(orig: &ViewSet, styl: &ViewSet, style: &Image) -> ObjectColour {
    let sty: Vec<[f64; 3]> = style
        .data
        .chunks_exact(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let (mut uo, mut us) = (Vec::new(), Vec::new());
    let (mut fringe, mut nf) = (0.0, 0usize);
    for i in 0..orig.n {
        let (_, alpha) = orig.geometry(i);
        let (o, s) = (&orig.images[i].data, &styl.images[i].data);
        for (p, &a) in alpha.iter().enumerate() {
            if a > 0.5 {
                let un = |d: &[f32]| {
                    let q = &d[p * 3..p * 3 + 3];
                    [
                        q[0] as f64 / a as f64,
                        q[1] as f64 / a as f64,
                        q[2] as f64 / a as f64,
                    ]
                };
                uo.push(un(o));
                us.push(un(s));
            } else if a > 0.02 {
                for c in 0..3 {
                    fringe += (s[p * 3 + c] - o[p * 3 + c]) as f64;
                }
                nf += 1;
            }
        }
    }
    let clipped = |v: &[[f64; 3]]| {
        (!v.is_empty()).then(|| {
            v.iter()
                .filter(|p| p.iter().all(|&x| x <= 0.02) || p.iter().all(|&x| x >= 0.98))
                .count() as f64
                / v.len() as f64
        })
    };
    let clip01 = |v: &[[f64; 3]]| -> Vec<[f64; 3]> {
        v.iter().map(|p| p.map(|x| x.clamp(0.0, 1.0))).collect()
    };
    ObjectColour {
        clipped_original: clipped(&uo),
        clipped_stylized: clipped(&us),
        fringe_brightening: (nf > 0).then(|| fringe / (3 * nf) as f64),
        fringe_pixels: nf,
        stats_distance_original: stats_distance(&clip01(&uo), &sty),
        stats_distance_stylized: stats_distance(&clip01(&us), &sty),
    }
}

/// The report's "Texture" section.
pub fn html(t: &TextureMetrics) -> String {
    let mut rows = gram_and_spectrum_rows(t);
    rows.extend(object_rows(t));
    let mut out = table(
        &["measure", "stylized", "original", "stylized / original"],
        &rows,
    );
    let s = &t.spectrum;
    let curve = |label: &str, colour: &'static str, v: &[Option<f64>]| Series {
        label: label.into(),
        colour,
        points: s
            .frequencies
            .iter()
            .zip(v)
            .map(|(fr, p)| (fr.log2(), p.filter(|x| *x > 0.0).map(f64::log10)))
            .collect(),
        markers_only: false,
        names: Vec::new(),
    };
    out.push_str(&svg_plot(
        "Radially averaged luminance power spectrum (normalised)",
        "log2 frequency (cycles per pixel)",
        "log10 power",
        &[
            curve("style", "#d62728", &s.style),
            curve("stylized", "#1f77b4", &s.stylized),
            curve("original", "#7f7f7f", &s.original),
        ],
    ));
    out.push_str("<ul class=\"note\">");
    for n in &t.notes {
        out.push_str(&format!("<li>{}</li>", esc(n)));
    }
    out.push_str("</ul>");
    out
}

/// The table's rows of the per-layer object Gram distances and the spectrum.
fn gram_and_spectrum_rows(t: &TextureMetrics) -> Vec<Vec<String>> {
    let f = |v: Option<f64>, d: usize| fmt_opt(v, d);
    let mut rows: Vec<Vec<String>> = t
        .gram_object
        .iter()
        .map(|l| {
            vec![
                format!("Gram over the object, {} ↓", l.layer),
                f(l.stylized, 4),
                f(l.original, 4),
                f(l.ratio, 3),
            ]
        })
        .collect();
    let s = &t.spectrum;
    rows.push(vec![
        "luminance spectrum distance to the style (decades) ↓".into(),
        f(s.distance_stylized, 3),
        f(s.distance_original, 3),
        f(s.distance_ratio, 3),
    ]);
    let per =
        |v: Option<f64>| v.map_or("-".into(), |p| format!("{p:.4} (period {:.1} px)", 1.0 / p));
    rows.push(vec![
        "spectrum peak, cycles/px (style: ".to_string() + &per(s.peak_style) + ")",
        per(s.peak_stylized),
        per(s.peak_original),
        String::new(),
    ]);
    rows
}

/// The table's rows of the object's colour, clipping, fringe and KID measures.
fn object_rows(t: &TextureMetrics) -> Vec<Vec<String>> {
    let f = |v: Option<f64>, d: usize| fmt_opt(v, d);
    let o = &t.object;
    let pct = |v: Option<f64>| v.map_or("-".into(), |x| format!("{:.1}%", 100.0 * x));
    let mut rows = vec![
        vec![
            "clipped object pixels".into(),
            pct(o.clipped_stylized),
            pct(o.clipped_original),
            String::new(),
        ],
        vec![
            "colour statistics distance to the style ↓".into(),
            f(o.stats_distance_stylized, 3),
            f(o.stats_distance_original, 3),
            f(
                ratio(o.stats_distance_stylized, o.stats_distance_original),
                3,
            ),
        ],
        vec![
            format!("silhouette-fringe brightening ({} px)", o.fringe_pixels),
            o.fringe_brightening
                .map_or("-".into(), |v| format!("{v:+.4}")),
            String::new(),
            String::new(),
        ],
    ];
    let kid = |k: &KidInterval| match (k.value, k.se) {
        (Some(v), Some(se)) => format!("{v:.5} ± {:.5}", 1.96 * se),
        (v, _) => f(v, 5),
    };
    let few = |k: &KidInterval| if k.reliable { "" } else { " (few images)" };
    let k = &t.kid_style;
    rows.push(vec![
        format!("KID_style (whole views) ± 1.96 se{} ↓", few(k)),
        kid(k),
        String::new(),
        String::new(),
    ]);
    let (k, ko) = (&t.kid_object, &t.kid_object_original);
    rows.push(vec![
        format!(
            "KID of object squares vs style squares ± 1.96 se{} ↓",
            few(k)
        ),
        kid(k),
        kid(ko),
        f(ratio(k.value, ko.value), 3),
    ]);
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// The object squares lie inside the object (by their mean alpha, recomputed here
    /// pixel by pixel), inside the view, at most four per view, half a side apart; none in
    /// an empty view or on a thin ring; the same seed gives the same squares.
    #[test]
    fn object_squares_lie_inside_the_object() {
        let (w, h) = (200, 160);
        // View 0: a disk of radius 70 (alpha 1 inside); view 1: empty; view 2: a ring
        // 20 px wide (no 32 px square fits); view 3: the disk again.
        let disk = |x: usize, y: usize, r0: f64, r1: f64| {
            let r = ((x as f64 - 100.0).powi(2) + (y as f64 - 80.0).powi(2)).sqrt();
            if r >= r0 && r < r1 { 1.0f32 } else { 0.0 }
        };
        let mut alpha = Vec::new();
        for v in 0..4 {
            for y in 0..h {
                for x in 0..w {
                    alpha.push(match v {
                        0 | 3 => disk(x, y, 0.0, 70.0),
                        1 => 0.0,
                        _ => disk(x, y, 50.0, 70.0),
                    });
                }
            }
        }
        let at = object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 7);
        let p = PATCH_SIDE;
        for v in 0..4 {
            let here: Vec<_> = at.iter().filter(|q| q.0 == v).collect();
            match v {
                0 | 3 => assert_eq!(here.len(), PATCHES_PER_VIEW, "view {v}: {here:?}"),
                _ => assert!(here.is_empty(), "view {v}: {here:?}"),
            }
            for (k, &&(_, x, y)) in here.iter().enumerate() {
                assert!(x + p <= w && y + p <= h);
                let mean: f64 = (y..y + p)
                    .flat_map(|yy| (x..x + p).map(move |xx| (xx, yy)))
                    .map(|(xx, yy)| alpha[(v * h + yy) * w + xx] as f64)
                    .sum::<f64>()
                    / (p * p) as f64;
                assert!(
                    mean >= PATCH_COVERAGE,
                    "view {v} square {k} at ({x}, {y}): mean alpha {mean}"
                );
                for &&(_, a, b) in &here[..k] {
                    assert!(x.abs_diff(a) >= p / 2 || y.abs_diff(b) >= p / 2);
                }
            }
        }
        assert_eq!(
            at,
            object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 7)
        );
        assert_ne!(
            at,
            object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 8)
        );
        // Views smaller than a square give none.
        let n = PATCH_SIDE - 1;
        assert!(object_patch_positions(&vec![1.0; n * n], n, n, 4, 7).is_empty());
        // A view exactly one square in size, fully covered, gives that one square.
        let n = PATCH_SIDE;
        assert_eq!(
            object_patch_positions(&vec![1.0; n * n], n, n, 4, 7),
            vec![(0, 0, 0)]
        );
    }

    /// The note written beside kid_object states the constants the code uses.
    #[test]
    fn object_kid_note_states_the_constants() {
        let note = NOTES.iter().find(|n| n.starts_with("kid_object")).unwrap();
        for want in [
            format!("{PATCH_SIDE} px squares"),
            format!("mean alpha >= {PATCH_COVERAGE}"),
            format!("up to {PATCHES_PER_VIEW} per view"),
            format!("vs {STYLE_PATCHES} squares"),
            format!("shorter side {PATCH_STYLE_SIDE}"),
        ] {
            assert!(note.contains(&want), "the note lacks `{want}`: {note}");
        }
    }

    /// The style squares: the right count and side, crops of the style at shorter side
    /// 256 (a style already that size is cropped as it is; a twice larger one is halved
    /// first, which a square's span of a linear ramp shows).
    #[test]
    fn style_squares_come_from_the_style_at_the_drawing_scale() {
        let ramp = |w: usize, h: usize| {
            Image::from_fn(w, h, |x, y| {
                [x as f32 / (w - 1) as f32, y as f32 / (h - 1) as f32, 0.5]
            })
        };
        let style = ramp(256, 512);
        let sq = style_patches(&style, 3);
        assert_eq!(sq.len(), STYLE_PATCHES);
        for q in &sq {
            assert_eq!((q.width, q.height), (PATCH_SIDE, PATCH_SIDE));
            let [r, g, _] = q.px(0, 0);
            let (x0, y0) = ((r * 255.0).round() as usize, (g * 511.0).round() as usize);
            assert_eq!(q.data, style.crop(x0, y0, PATCH_SIDE, PATCH_SIDE).data);
        }
        // Twice the size: a square spans its side at the 256 px scale, not at 512 px.
        for q in style_patches(&ramp(512, 1024), 3) {
            let span = q.px(PATCH_SIDE - 1, 0)[0] - q.px(0, 0)[0];
            let want = (PATCH_SIDE - 1) as f32 / 255.0;
            assert!((span - want).abs() < 0.01, "span {span}, want {want}");
        }
    }

    fn rand_tensor(c: usize, h: usize, w: usize, seed: u64) -> Tensor3 {
        let mut r = Rng::new(seed);
        Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(|_| r.normal().abs() as f32).collect(),
        }
    }

    /// Weighted Gram against the plain weighted sum; 0/1 weights equal the Gram of the
    /// kept positions alone.
    #[test]
    fn weighted_gram_by_definition() {
        let (c, h, w) = (5, 4, 6);
        let t = rand_tensor(c, h, w, 1);
        let mut r = Rng::new(2);
        let wts: Vec<f32> = (0..h * w).map(|_| r.uniform() as f32).collect();
        let g = weighted_gram(&t, &wts).unwrap();
        let sw: f64 = wts.iter().map(|&v| v as f64).sum();
        for a in 0..c {
            for b in 0..c {
                let s: f64 = (0..h * w)
                    .map(|p| {
                        wts[p] as f64 * t.data[a * h * w + p] as f64 * t.data[b * h * w + p] as f64
                    })
                    .sum();
                assert!(
                    (g[a * c + b] - s / sw).abs() < 1e-6 * (1.0 + s.abs()),
                    "{a},{b}"
                );
            }
        }
        // Positions with weight 0 do not count; with weight 1 it is their Gram.
        let keep: Vec<f32> = (0..h * w)
            .map(|p| if p % 3 == 0 { 1.0 } else { 0.0 })
            .collect();
        let kept: Vec<usize> = (0..h * w).filter(|p| p % 3 == 0).collect();
        let sub = Tensor3 {
            c,
            h: 1,
            w: kept.len(),
            data: (0..c)
                .flat_map(|a| kept.iter().map(move |&p| (a, p)))
                .map(|(a, p)| t.data[a * h * w + p])
                .collect(),
        };
        let (g1, g2) = (weighted_gram(&t, &keep).unwrap(), gram(&sub));
        for (x, y) in g1.iter().zip(&g2) {
            assert!((x - y).abs() < 1e-6 * (1.0 + y.abs()));
        }
        assert!(weighted_gram(&t, &vec![0.0; h * w]).is_none());
    }

    #[test]
    fn pool_alpha_matches_floor_pooling() {
        // 5 wide x 4 high pooled by 2 (floor): 2 x 2 output, the last column dropped.
        let a: Vec<f32> = (0..20).map(|v| v as f32).collect();
        let p = pool_alpha(&a, 5, 4, 2, 2);
        assert_eq!(p, vec![3.0, 5.0, 13.0, 15.0]);
    }

    fn set(rows: &[Vec<f64>]) -> FeatureSet {
        FeatureSet {
            n: rows.len(),
            d: rows[0].len(),
            data: rows.iter().flatten().copied().collect(),
        }
    }

    /// The jackknife KID equals fid::kid, and its standard error equals a direct
    /// leave-one-out recomputation with fid::kid on the reduced sets.
    #[test]
    fn kid_jackknife_against_fid_kid() {
        let mut r = Rng::new(7);
        let rows = |n: usize, shift: f64, r: &mut Rng| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..6).map(|_| shift + r.normal()).collect())
                .collect()
        };
        let (ra, rb) = (rows(7, 0.0, &mut r), rows(5, 0.4, &mut r));
        let (a, b) = (set(&ra), set(&rb));
        let (v, se) = kid_jackknife(&a, &b).unwrap();
        let want = super::super::fid::kid(&a, &b).unwrap();
        assert!(
            (v - want).abs() < 1e-9 * want.abs().max(1.0),
            "{v} vs {want}"
        );
        let mut var = 0.0;
        for (rows_, other, first) in [(&ra, &rb, true), (&rb, &ra, false)] {
            let n = rows_.len();
            let th: Vec<f64> = (0..n)
                .map(|i| {
                    let less: Vec<Vec<f64>> = rows_
                        .iter()
                        .enumerate()
                        .filter(|(j, _)| *j != i)
                        .map(|(_, x)| x.clone())
                        .collect();
                    let (x, y) = if first {
                        (set(&less), set(other))
                    } else {
                        (set(other), set(&less))
                    };
                    super::super::fid::kid(&x, &y).unwrap()
                })
                .collect();
            let m = th.iter().sum::<f64>() / n as f64;
            var += (n - 1) as f64 / n as f64 * th.iter().map(|t| (t - m).powi(2)).sum::<f64>();
        }
        let se = se.unwrap();
        assert!(
            (se - var.sqrt()).abs() < 1e-9 * se.max(1e-12),
            "{se} vs {}",
            var.sqrt()
        );
        assert!(se > 0.0);
        // Two images per set: a value but no error.
        let (v2, se2) = kid_jackknife(&set(&ra[..2]), &set(&rb[..2])).unwrap();
        assert!(v2.is_finite() && se2.is_none());
    }

    #[test]
    fn stats_distance_by_hand() {
        // a: two points, mean (0.5, 0, 0), cov only in R: var = 0.5
        let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let b = [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        // |mu diff| = sqrt(0.25 + 1) ; ||cov diff|| = 0.5
        let d = stats_distance(&a, &b).unwrap();
        assert!((d - (1.25f64.sqrt() + 0.5)).abs() < 1e-12, "{d}");
        assert_eq!(stats_distance(&a, &a), Some(0.0));
    }
}
