//! `mvfc-filter`: thin binary over `fantasystyle::stages::mvfc_filter`.
use clap::Parser;
use fantasystyle::mvfc::MvfcParams;
use fantasystyle::stages::mvfc_filter::{MvfcFilterArgs, TimestepChoice, mvfc_filter};
use std::path::PathBuf;

/// Noise target and source latents with one shared eps at a DDIM timestep and apply
/// multi-view frequency consistency (MVFC) to the noisy target latents. Writes a
/// noised-latents artifact (z_src.npy, z_tgt.npy, eps.npy, eps_shared.npy; meta.timestep).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// Target latents artifact (latents of the current renders).
    #[arg(long)]
    latents: PathBuf,
    /// Source latents artifact (latents of the original renders), same shape.
    #[arg(long)]
    source_latents: PathBuf,
    /// Model directory with model.json (its noise schedule and timestep set).
    #[arg(long)]
    model: PathBuf,
    /// Timestep: an integer from the model's DDIM set, or `auto` to draw one with (seed, round).
    #[arg(long, default_value = "auto")]
    timestep: TimestepChoice,
    /// Seed for t (auto), eps and the shared MVFC noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Iteration index: with the seed, selects t and the noise of this round.
    #[arg(long, default_value_t = 0)]
    round: u64,
    /// Output noised-latents artifact directory (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// Weight of the target's own low frequencies (1 = no change, 0 = shared noise only).
    #[arg(long, default_value_t = 0.9)]
    gamma: f32,
    /// Spatial cut-off d_s of the Gaussian low-pass mask (normalised frequency; `inf` allowed).
    #[arg(long, default_value_t = 0.25)]
    ds: f32,
    /// View cut-off d_t of the Gaussian low-pass mask (normalised frequency; `inf` allowed).
    #[arg(long, default_value_t = 0.25)]
    dt: f32,
    /// Skip MVFC (the paper's "w/o MVFC" ablation): z_tgt is only noised.
    #[arg(long)]
    no_filter: bool,
    /// Views per MVFC group: the 3D FFT runs over runs of this many adjacent views
    /// (0 = all views in one group).
    #[arg(long, default_value_t = 0)]
    group_size: usize,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        mvfc_filter(&MvfcFilterArgs {
            latents: a.latents,
            source_latents: a.source_latents,
            model: a.model,
            timestep: a.timestep,
            seed: a.seed,
            round: a.round,
            out: a.out,
            params: MvfcParams {
                gamma: a.gamma,
                d_s: a.ds,
                d_t: a.dt,
            },
            no_filter: a.no_filter,
            group_size: a.group_size,
            threads: a.threads,
        })
        .map(|t| tracing::info!("wrote noised latents at t = {t}"))
    })
}
