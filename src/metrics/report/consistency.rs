//! The view-consistency section: how pairs are compared, the per-pair LPIPS and RMSE
//! plots and table of the short and long range, and a warped example.

use crate::maths::warp::Warped;
use crate::metrics::consistency::PairScore;
use crate::metrics::evaluate::{Metrics, RangeConsistency};
use crate::metrics::html::{Series, diff_image, esc, figure, fmt_opt, mask_image, svg_plot, table};
use crate::metrics::views::ViewSet;

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
                fmt_opt(a.excess_lpips, 4),
                fmt_opt(b.excess_lpips, 4),
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
            "excess LPIPS stylized",
            "excess LPIPS original",
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

/// The consistency section: how pairs are compared, short and long range.
pub(super) fn consistency_section(
    m: &Metrics,
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
