//! The report's "Texture" section: the table of the texture measures, the plot of the
//! spectra and the notes.

use super::{KidInterval, TextureMetrics, ratio};
use crate::metrics::html::{Series, esc, fmt_opt, svg_plot, table};

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
