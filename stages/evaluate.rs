//! `evaluate`: thin binary over [`fantasystyle::stages::evaluate`].
use clap::Parser;
use fantasystyle::metrics::nets::LpipsNet;
use fantasystyle::stages::evaluate::{EvaluateOptions, run};
use std::path::PathBuf;

/// Measure a stylized view set against the original views and the style image: LPIPS,
/// FID/KID (style and content), ArtFID, short/long-range view consistency, Gram distance.
/// Writes an evaluation artifact (metrics.json, report.html).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Views artifact of the original (unstylized) scene.
    #[arg(long)]
    original: PathBuf,
    /// Views artifact of the stylized scene, rendered from the same cameras.
    #[arg(long)]
    stylized: PathBuf,
    /// The style image (PNG or JPEG).
    #[arg(long)]
    style: PathBuf,
    /// Output evaluation artifact directory (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// LPIPS backbone for LPIPS_content and the consistency metrics.
    #[arg(long, value_enum, default_value = "alex")]
    lpips_net: LpipsNet,
    /// View offset of the short-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 1)]
    short_range: usize,
    /// View offset of the long-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 5)]
    long_range: usize,
    /// Seed of the style-image crops used by FID_style.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// onnxruntime threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// A sweep.json (from scripts/sweep.sh) to include as the speed-accuracy section.
    #[arg(long)]
    sweep: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        run(&EvaluateOptions {
            original: a.original,
            stylized: a.stylized,
            style: a.style,
            out: a.out,
            lpips_net: a.lpips_net,
            short_range: a.short_range,
            long_range: a.long_range,
            seed: a.seed,
            threads: a.threads,
            sweep: a.sweep,
        })
        .map(|_| ())
    })
}
