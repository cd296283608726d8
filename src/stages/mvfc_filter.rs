//! `mvfc-filter`: noise the source and target latents with one shared eps at a
//! timestep of the fixed DDIM set, and MVFC-filter the noisy target (FantasyStyle
//! Sec. 3.2; the filter is [`crate::mvfc`]).
//!
//! Reads two `latents` artifacts (target = current renders, source = original renders,
//! same shape `[N, C, h, w]`) and the model's `model.json` (its noise schedule and
//! timestep set). Draws, from `--seed` and `--round`:
//! * t: given explicitly (must be in the set) or `auto`: uniform over the set,
//!   deterministic in (seed, round) ([`crate::scheduler::TimestepSet::sample_for_round`]);
//! * eps `[N, C, h, w]` (stream `mvfc/eps/<round>`), shared by source and target;
//! * eps' `[C, h, w]` (stream `mvfc/shared/<round>`), the MVFC noise shared by all views.
//!
//! Writes a `noised-latents` artifact: `z_src.npy` = add_noise(z0_src, eps, t),
//! `z_tgt.npy` = MVFC(add_noise(z0_tgt, eps, t), eps') (or unfiltered with `no_filter`,
//! the paper's "w/o MVFC" ablation), `eps.npy`, `eps_shared.npy`; `meta.timestep` and
//! the filter parameters.
//!
//! The timestep set: [`crate::prior::model_timesteps`] (the model manifest's
//! `stylizer.timesteps` range if present, else 50 steps over [0.02 T, 0.98 T]).

use super::Threads;
use crate::artifacts::read_latents;
use crate::mvfc::{MvfcParams, mvfc_grouped};
use crate::prior::model_timesteps;
use crate::rng::Rng;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use ndarray::{Array3, Array4};
use std::path::PathBuf;

/// Which timestep to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimestepChoice {
    /// Draw from the set with (seed, round).
    Auto,
    /// This timestep (must be in the set).
    Fixed(usize),
}

impl std::str::FromStr for TimestepChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "auto" {
            return Ok(TimestepChoice::Auto);
        }
        s.parse::<usize>()
            .map(TimestepChoice::Fixed)
            .map_err(|_| format!("`{s}` is neither `auto` nor a non-negative integer timestep"))
    }
}

/// Noise target and source latents with one shared eps at a DDIM timestep and apply
/// multi-view frequency consistency (MVFC) to the noisy target latents. Writes a
/// noised-latents artifact (z_src.npy, z_tgt.npy, eps.npy, eps_shared.npy; meta.timestep).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "mvfc-filter", version)]
pub struct Args {
    /// Target latents artifact (latents of the current renders).
    #[arg(long)]
    pub latents: PathBuf,
    /// Source latents artifact (latents of the original renders), same shape.
    #[arg(long)]
    pub source_latents: PathBuf,
    /// Model directory with model.json (its noise schedule and timestep set).
    #[arg(long)]
    pub model: PathBuf,
    /// Timestep: an integer from the model's DDIM set, or `auto` to draw one with (seed, round).
    #[arg(long, default_value = "auto")]
    pub timestep: TimestepChoice,
    /// Seed for t (auto), eps and the shared MVFC noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Iteration index: with the seed, selects t and the noise of this round.
    #[arg(long, default_value_t = 0)]
    pub round: u64,
    /// Output noised-latents artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub params: MvfcParams,
    /// Skip MVFC (the paper's "w/o MVFC" ablation): z_tgt is only noised.
    #[arg(long)]
    pub no_filter: bool,
    /// Views per MVFC group: the 3D FFT runs over runs of this many adjacent views
    /// (0 = all views in one group).
    #[arg(long, default_value_t = 0)]
    pub group_size: usize,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage; returns the timestep used.
pub fn run(a: Args) -> Result<usize> {
    a.params.validate()?;
    let z0_tgt = read_latents(&a.latents)?;
    let z0_src = read_latents(&a.source_latents)?;
    if z0_tgt.shape() != z0_src.shape() {
        return Err(Error::input(
            a.source_latents.join("latents.npy"),
            format!(
                "source latents have shape {:?} but the target latents ({}) have {:?}",
                z0_src.shape(),
                a.latents.join("latents.npy").display(),
                z0_tgt.shape()
            ),
        ));
    }
    let (schedule, set) = model_timesteps(&a.model)?;
    let t = match a.timestep {
        TimestepChoice::Auto => set.sample_for_round(a.seed, a.round),
        TimestepChoice::Fixed(t) => {
            set.check(t)?;
            t
        }
    };
    let s = z0_tgt.shape();
    let shape = [s[0], s[1], s[2], s[3]];
    let eps = Array4::from_shape_vec(
        shape,
        Rng::derive(a.seed, &format!("mvfc/eps/{}", a.round)).normals_f32(z0_tgt.len()),
    )
    .expect("length matches");
    let eps_shared = Array3::from_shape_vec(
        [shape[1], shape[2], shape[3]],
        Rng::derive(a.seed, &format!("mvfc/shared/{}", a.round))
            .normals_f32(shape[1] * shape[2] * shape[3]),
    )
    .expect("length matches");
    let z_src = schedule.add_noise(z0_src.view(), eps.view(), t)?;
    let z_noisy = schedule.add_noise(z0_tgt.view(), eps.view(), t)?;
    let z_tgt = if a.no_filter {
        z_noisy
    } else {
        a.threads
            .install(|| mvfc_grouped(z_noisy.view(), eps_shared.view(), a.params, a.group_size))??
    };
    tracing::info!(
        "mvfc-filter: t = {t} (ab = {:.4}), latents {shape:?}, {}",
        schedule.alpha_bar(t)?,
        if a.no_filter {
            "no filter".to_string()
        } else {
            format!(
                "gamma {} d_s {} d_t {}, views per group {}",
                a.params.gamma, a.params.d_s, a.params.d_t, a.group_size
            )
        }
    );

    let params = serde_json::json!({
        "timestep": match a.timestep { TimestepChoice::Auto => "auto".to_string(), TimestepChoice::Fixed(t) => t.to_string() },
        "seed": a.seed, "round": a.round,
        "gamma": a.params.gamma, "d_s": a.params.d_s, "d_t": a.params.d_t,
        "no_filter": a.no_filter, "group_size": a.group_size,
    });
    let mut w = ArtifactWriter::create(
        &a.out,
        ArtifactKind::NoisedLatents,
        Producer::new("mvfc-filter", crate::VERSION, params),
    )?;
    w.add_input("latents", &a.latents)?;
    w.add_input("source-latents", &a.source_latents)?;
    let mpath = if a.model.is_file() {
        a.model.clone()
    } else {
        a.model.join("model.json")
    };
    w.add_input("model", &mpath)?;
    let sl = |x: &Array4<f32>| x.as_standard_layout().iter().copied().collect::<Vec<_>>();
    w.write_tensor("z_src.npy", &shape, &sl(&z_src))?;
    w.write_tensor("z_tgt.npy", &shape, &sl(&z_tgt))?;
    w.write_tensor("eps.npy", &shape, &sl(&eps))?;
    w.write_tensor(
        "eps_shared.npy",
        &[shape[1], shape[2], shape[3]],
        eps_shared.as_slice().expect("standard layout"),
    )?;
    w.set_meta(serde_json::json!({
        "timestep": t,
        "alpha_bar": schedule.alpha_bar(t)?,
        "filtered": !a.no_filter,
        "gamma": a.params.gamma,
        "d_s": a.params.d_s,
        "d_t": a.params.d_t,
        "seed": a.seed,
        "round": a.round,
    }));
    crate::timing::io(|| w.commit())?;
    tracing::info!("wrote noised latents at t = {t}");
    Ok(t)
}
