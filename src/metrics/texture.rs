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
//!
//! One module per measure: `object_gram`, `kid` (both KIDs' intervals; the kernel is
//! [`crate::maths::kid`]'s), `patches` (the object KID's squares), `motif` (the
//! spectra), `colour` (the object's colour) and `html` (the report's section).

mod colour;
mod html;
mod kid;
mod motif;
mod object_gram;
mod patches;

pub use colour::{ObjectColour, object_colour, stats_distance};
pub use html::html;
pub use kid::{KID_MIN_IMAGES, KidInterval, kid_interval, kid_jackknife};
pub use motif::{SpectrumMetrics, spectrum_metrics};
pub use object_gram::{GRAM_LAYERS, LayerGram, ObjectGram, pool_alpha, view_grams, weighted_gram};
pub use patches::{
    PATCH_COVERAGE, PATCH_SIDE, PATCH_STYLE_SIDE, PATCHES_PER_VIEW, STYLE_PATCHES,
    object_patch_positions, object_patches, style_patches,
};
use serde::Serialize;

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

fn ratio(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => Some(a / b),
        _ => None,
    }
}
