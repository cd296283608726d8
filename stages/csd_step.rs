//! `csd-step`: thin binary over `fantasystyle::stages::csd_step`.
use clap::Parser;
use fantasystyle::csd::{CsdParams, Mode, Weighting};
use fantasystyle::stages::csd_step::{CsdStepArgs, csd_step};
use std::path::PathBuf;

/// One controllable stylized distillation (CSD) step: from noised latents (mvfc-filter),
/// the clean target latents and the renders, compute z0' = z0 - lr w(t) grad and write
/// target images render + decode(z0') - decode(z0) as a targets artifact
/// (rgb.npy [N,H,W,3], cameras.json, delta.npy, PNG previews).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Noised-latents artifact from mvfc-filter (z_src, z_tgt, eps; meta.timestep).
    #[arg(long)]
    noised: PathBuf,
    /// Latents artifact of the current renders (the clean target latents z0).
    #[arg(long)]
    latents: PathBuf,
    /// Views artifact of the current renders (the targets are built on them; cameras copied).
    #[arg(long)]
    views: PathBuf,
    /// Views artifact of the original renders (control image for ControlNet priors).
    #[arg(long)]
    source_views: PathBuf,
    /// Model directory with model.json (e.g. vendor/models/stylizer, vendor/models/gaussian-prior).
    #[arg(long)]
    model: PathBuf,
    /// Style image (PNG or JPEG).
    #[arg(long)]
    style: PathBuf,
    /// Text of one of the model's exported prompts (default: its first); ignored by the stylizer.
    #[arg(long)]
    prompt: Option<String>,
    /// Distillation gradient: csd (paper), sds, dds, or csd-no-neg (no negative content guidance).
    #[arg(long, value_enum, default_value = "csd")]
    mode: Mode,
    /// Classifier-free guidance scale beta.
    #[arg(long, default_value_t = 7.5)]
    guidance: f32,
    /// Timestep weighting w(t): 1-ab, uniform, or sqrt-ab-1-ab (= sqrt(ab)(1-ab)).
    #[arg(long, value_enum, default_value = "1-ab")]
    weighting: Weighting,
    /// Step size on the clean latents: z0' = z0 - lr * w(t) * grad.
    #[arg(long, default_value_t = 0.1)]
    lr: f32,
    /// Output targets artifact directory (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// Threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        csd_step(&CsdStepArgs {
            noised: a.noised,
            latents: a.latents,
            views: a.views,
            source_views: a.source_views,
            model: a.model,
            style: a.style,
            prompt: a.prompt,
            params: CsdParams {
                mode: a.mode,
                guidance: a.guidance,
                weighting: a.weighting,
                lr: a.lr,
            },
            out: a.out,
            threads: a.threads,
        })
        .map(|_| ())
    })
}
