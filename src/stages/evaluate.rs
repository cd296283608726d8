//! `evaluate`: compare a stylized views artifact with the original one and the style image,
//! and write an `evaluation` artifact (`metrics.json`, `report.html`).
//!
//! The metrics are [`crate::metrics::evaluate`] (FantasyStyle's experiments: LPIPS_content,
//! FID/KID, ArtFID, short/long-range consistency, Gram distance), the page
//! [`crate::metrics::report::evaluation_report`]; the metric networks come from the
//! models directory ([`crate::models`]).

use super::Threads;
use crate::imageio::Image;
use crate::metrics::evaluate::{EvalParams, Metrics, evaluate};
use crate::metrics::nets::LpipsNet;
use crate::metrics::report::{ReportPaths, evaluation_report, fmt_opt};
use crate::metrics::views::ViewSet;
use crate::sweep::Sweep;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Measure a stylized view set against the original views and the style image: LPIPS,
/// FID/KID (style and content), ArtFID, short/long-range view consistency, Gram distance.
/// Writes an evaluation artifact (metrics.json, report.html).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "evaluate", version)]
pub struct Args {
    /// Views artifact of the original (unstylized) scene.
    #[arg(long)]
    pub original: PathBuf,
    /// Views artifact of the stylized scene, rendered from the same cameras.
    #[arg(long)]
    pub stylized: PathBuf,
    /// The style image (PNG or JPEG).
    #[arg(long)]
    pub style: PathBuf,
    /// Output evaluation artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// LPIPS backbone for LPIPS_content and the consistency metrics.
    #[arg(long, value_enum, default_value = "alex")]
    pub lpips_net: LpipsNet,
    /// View offset of the short-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 1)]
    pub short_range: usize,
    /// View offset of the long-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 5)]
    pub long_range: usize,
    /// Seed of the style-image crops used by FID_style.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub threads: Threads,
    /// A sweep.json (from the `sweep` stage) to include as the speed-accuracy section.
    #[arg(long)]
    pub sweep: Option<PathBuf>,
}

/// The stage: read the views and the style, evaluate, write the artifact.
pub fn run(a: Args) -> Result<Metrics> {
    let p = EvalParams {
        lpips_net: a.lpips_net,
        short_range: a.short_range,
        long_range: a.long_range,
        seed: a.seed,
        threads: a.threads.n,
    };
    p.validate()?;
    let orig = crate::timing::load(|| ViewSet::load(&a.original))?;
    let styl = crate::timing::load(|| ViewSet::load(&a.stylized))?;
    orig.check_same_views(&styl)?;
    let style = Image::load(&a.style)?;
    let sweep = a.sweep.as_deref().map(Sweep::load).transpose()?;
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
        "lpips_net": p.lpips_net.name(), "short_range": p.short_range, "long_range": p.long_range, "seed": p.seed,
    });
    let mut wr = super::create_artifact(
        &a.out,
        ArtifactKind::Evaluation,
        Producer::new("evaluate", crate::VERSION, params),
    )?;
    let ev = evaluate(&models, &orig, &styl, &style, &p)?;
    let paths = ReportPaths {
        original: &a.original,
        stylized: &a.stylized,
        style: &a.style,
    };
    let sweep_html = sweep.as_ref().map(Sweep::html);
    let html = evaluation_report(paths, &ev, &orig, &styl, &style, sweep_html.as_deref());

    wr.add_input("original", &a.original)?;
    wr.add_input("stylized", &a.stylized)?;
    wr.add_input("style", &a.style)?;
    wr.write_json("metrics.json", &ev.metrics)?;
    wr.write_bytes("report.html", html.as_bytes())?;
    crate::timing::io(|| wr.commit())?;
    let m = ev.metrics;
    tracing::info!(
        "evaluate: LPIPS_content {} FID_style {} ArtFID {} short-range LPIPS {} -> {}",
        fmt_opt(m.lpips_content, 4),
        fmt_opt(m.fid_style.value, 2),
        fmt_opt(m.artfid, 2),
        fmt_opt(m.short_range.lpips_mean, 4),
        a.out.display()
    );
    Ok(m)
}
