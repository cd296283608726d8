//! The report's tables: the metrics of an evaluation (with its consistency rows) and
//! every view with its per-view measures.

use crate::imageio::Image;
use crate::metrics::evaluate::{ARTFID_NOTE, Metrics, SetDistance};
use crate::metrics::html::{esc, figure, fmt_opt, img_tag, table};
use crate::metrics::interior;
use crate::metrics::structure;
use crate::metrics::views::ViewSet;

/// The metrics table of an evaluation.
pub(super) fn metrics_table(m: &Metrics) -> String {
    let d = |x: &SetDistance, digits, flag: &str| {
        let mark = if x.reliable || x.value.is_none() {
            String::new()
        } else {
            format!(" ({flag})")
        };
        format!("{}{mark}", fmt_opt(x.value, digits))
    };
    let net = m.lpips_net.name();
    let inception = !m.fid_style.is_off();
    let mut rows = Vec::new();
    if inception {
        rows.push(vec![
            "ArtFID ↓".into(),
            fmt_opt(m.artfid, 3),
            esc(ARTFID_NOTE),
        ]);
    }
    rows.push(vec![
        format!("LPIPS_content ({net}) ↓"),
        fmt_opt(m.lpips_content, 4),
        "mean over views of LPIPS(original, stylized)".into(),
    ]);
    rows.extend(structure_rows(m));
    if inception {
        let sets = [
            (
                "style",
                &m.fid_style,
                &m.kid_style,
                "stylized views vs style crops",
            ),
            (
                "content",
                &m.fid_content,
                &m.kid_content,
                "stylized vs original views",
            ),
        ];
        for (what, fid, kid, against) in sets {
            rows.push(vec![
                format!("FID_{what} ↓"),
                d(fid, 2, "biased"),
                esc(&format!("{against}; {}", fid.note)),
            ]);
            rows.push(vec![
                format!("KID_{what} ↓"),
                d(kid, 5, "few images"),
                esc(&kid.note),
            ]);
        }
    } else {
        rows.push(vec![
            "FID, KID, ArtFID".into(),
            "off".into(),
            "the Inception measures are not computed in this run (at 8 to 16 views FID is \
             biased and KID noisy): `pipeline run --set eval.inception=true` or `evaluate \
             --inception true` adds them"
                .into(),
        ]);
    }
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

/// The metrics table's structure rows: structure kept, and inside the object
/// ([`interior`]) interior structure, edge recall, motif contrast and style texture.
fn structure_rows(m: &Metrics) -> Vec<Vec<String>> {
    vec![
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
            "interior structure ↑".into(),
            fmt_opt(m.interior.interior_structure, 3),
            format!(
                "the same correlation over the object's interior only (mask eroded by {} px, square): \
                 the inner edges and shading without the silhouette",
                interior::EROSION_PX
            ),
        ],
        vec![
            "edge recall ↑".into(),
            fmt_opt(m.interior.edge_recall, 3),
            format!(
                "inside the interior, the share of the original's strongest band-pass pixels (top 10%) \
                 that are among the stylized view's own strongest (top 25%) with the same sign; \
                 chance about {}, extra style edges not punished",
                interior::CHANCE_RECALL
            ),
        ],
        vec![
            "motif contrast (→ 1)".into(),
            fmt_opt(m.interior.motif_contrast, 3),
            format!(
                "band-pass standard deviation of the stylized interior over the style image's own \
                 (shorter side {} px: {}); about 1 = the style's contrast, 0 = a flat wash",
                m.interior.style_size,
                fmt_opt(m.interior.style_band_spread, 4)
            ),
        ],
        vec![
            "style texture (→ 1)".into(),
            fmt_opt(m.interior.style_texture, 3),
            "the same spread once the original's own band pass is projected out of the stylized \
             one (least squares): the style's motifs without the object's own edges, which motif \
             contrast counts; 0 = the original's detail only (or a flat wash), about 1 = the \
             style's contrast on top"
                .into(),
        ],
    ]
}

/// The metrics table's consistency rows: short and long range, LPIPS and RMSE.
fn consistency_rows(m: &Metrics) -> Vec<Vec<String>> {
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
        vec![
            format!("long-range excess LPIPS ({net}) ↓"),
            fmt_opt(m.long_range.excess_lpips_mean, 4),
            format!(
                "above the warp's own loss on the same content (a view warped there and back): \
                 seams and view-dependent blends; original renders: {}",
                fmt_opt(m.long_range.original_excess_lpips_mean, 4)
            ),
        ],
    ]
}

/// The style image and every view: original, stylized, LPIPS_content, structure kept,
/// interior structure, edge recall, motif contrast, style texture and Gram distance.
pub(super) fn views_table(m: &Metrics, orig: &ViewSet, styl: &ViewSet, style: &Image) -> String {
    let mut imgs = String::from("<p>Style image:</p>");
    imgs.push_str(&figure(style, 256, "style"));
    imgs.push_str("<table><tr><th>view</th><th>original</th><th>stylized</th><th>LPIPS</th><th>structure</th><th>interior</th><th>edge recall</th><th>motif contrast</th><th>style texture</th><th>Gram</th></tr>");
    for i in 0..m.views {
        let v = &m.interior.interior_per_view[i];
        imgs.push_str(&format!(
            "<tr><td>{i}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td></tr>",
            img_tag(&orig.images[i], 256, &format!("original {i}")),
            img_tag(&styl.images[i], 256, &format!("stylized {i}")),
            m.lpips_content_per_view[i],
            fmt_opt(m.structure_kept_per_view[i], 3),
            fmt_opt(v.interior_structure, 3),
            fmt_opt(v.edge_recall, 3),
            fmt_opt(v.motif_contrast, 3),
            fmt_opt(v.style_texture, 3),
            m.gram_style_per_view[i]
        ));
    }
    imgs.push_str("</table>");
    imgs
}
