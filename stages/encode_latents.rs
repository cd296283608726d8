//! `encode-latents`: thin binary over `fantasystyle::stages::encode_latents`.
use clap::Parser;
use fantasystyle::stages::encode_latents::{EncodeLatents, encode_latents};
use std::path::PathBuf;

/// VAE-encode a views artifact's renders into a latents artifact (latents.npy [N,C,h,w]).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Views artifact directory (rgb.npy [N,H,W,3] in [0,1]).
    #[arg(long)]
    views: PathBuf,
    /// Model directory holding model.json (e.g. vendor/models/gaussian-prior).
    #[arg(long)]
    model: PathBuf,
    /// Output latents artifact directory (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// onnxruntime intra-op threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Views per VAE call (0 = all at once; lower it to bound memory with real VAEs).
    #[arg(long, default_value_t = 4)]
    batch: usize,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        encode_latents(&EncodeLatents {
            views: a.views,
            model: a.model,
            out: a.out,
            threads: a.threads,
            batch: a.batch,
        })
        .map(|_| ())
    })
}
