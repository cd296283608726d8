//! Motif scale: the radially averaged luminance power spectrum of the object
//! ([`crate::metrics::spectrum`]) against the style image's: the mean normalised
//! spectrum over views, its log distance to the style's and its peak, for the stylized
//! and the original views.

use super::ratio;
use crate::imageio::Image;
use crate::metrics::spectrum;
use crate::metrics::views::ViewSet;
use serde::Serialize;

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
