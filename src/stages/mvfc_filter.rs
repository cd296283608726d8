//! `mvfc-filter`: noise the target and source latents of one iteration with one shared
//! eps at the iteration's timestep and filter them with multi-view frequency consistency
//! along the camera path (FantasyStyle Sec. 4, MVFC; the filter is [`crate::mvfc`]), as
//! `distill` does ([`crate::distill::step::noise_branches`]).
//!
//! Reads the `latents` of the window's renders (z0; `encode-latents` of `render-views
//! --window`, which recorded the iteration in `meta.iteration`), the `latents` of every
//! source view (z0_src of the window's views are taken from them) and the model's
//! `model.json` (its noise schedule and timestep set, or the configuration's
//! `timesteps`). Replays the iteration's draws ([`crate::distill::step::Draws`]: the
//! window, checked against the record, then t (uniform over the set, or annealed with
//! `anneal_iters` as distill's), eps `[N, C, h, w]`, eps' `[C, h, w]`). Its parameters
//! are the method's configuration (`--preset`, `--config`, `--set`, as distill's):
//! `[mvfc]`, `timesteps`, `anneal_iters`, `seed`.
//!
//! Writes a `noised-latents` artifact: `z_tgt.npy` = MVFC(add_noise(z0, eps, t), eps'),
//! `z_src.npy` = add_noise(z0_src, eps, t) through the same filter with the same eps'
//! (`mvfc.source = false`: not filtered, as in the paper; `mvfc.enabled = false`: neither
//! is),
//! `eps.npy`, `eps_shared.npy`; `meta.timestep`, the filter and the latents'
//! `meta.iteration`. The
//! view axis is circular only when the window is a whole closed path; otherwise it is
//! mirror-extended ([`crate::mvfc::mvfc_path`]).
//!
//! Latents that record no iteration (encoded from any views artifact) are one window of
//! an open path of all their views, iteration `--iteration` of the configuration's seed.

use super::{ConfigArgs, Threads};
use crate::artifacts::{Latents, open_latents, read_latents, window_rows, write_array};
use crate::config::Config;
use crate::distill::step::{self, Draws, IterLatents, IterationWindow, Noise};
use crate::prior::model_timesteps;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use std::path::PathBuf;

/// Noise the target and source latents of one iteration with one shared eps at its
/// timestep and filter both with multi-view frequency consistency (MVFC) along the
/// camera path, as distill does. Writes a noised-latents artifact (z_src.npy, z_tgt.npy,
/// eps.npy, eps_shared.npy; meta.timestep, meta.iteration).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "mvfc-filter", version)]
pub struct Args {
    /// Latents artifact of the window's renders (z0; encode-latents of render-views
    /// --window, which records the iteration).
    #[arg(long)]
    pub latents: PathBuf,
    /// Latents artifact of the source views (encode-latents --fill of the original
    /// renders, every view): z0_src.
    #[arg(long)]
    pub source_latents: PathBuf,
    /// Model directory with model.json (its noise schedule and timestep set).
    #[arg(long)]
    pub model: PathBuf,
    /// The method's configuration (its `[mvfc]`, `timesteps`, `anneal_iters`, and `seed`
    /// for latents that record no iteration).
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Iteration index, for latents that record no iteration (else the recorded one).
    #[arg(long)]
    pub iteration: Option<u64>,
    /// Output noised-latents artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage; returns the timestep drawn.
pub fn run(a: Args) -> Result<usize> {
    let p = a.config.load()?;
    let lat = open_latents(&a.latents)?;
    let w = window(&a, &p, &lat)?;
    let src_file = a.source_latents.join("latents.npy");
    let z0_src = window_rows(&read_latents(&a.source_latents)?, &w, &src_file)?;
    if z0_src.shape() != lat.z.shape() {
        return Err(Error::input(
            &src_file,
            format!(
                "the window's source latents have shape {:?} but the target latents ({}) {:?}",
                z0_src.shape(),
                a.latents.join("latents.npy").display(),
                lat.z.shape()
            ),
        ));
    }
    let (schedule, model_set) = model_timesteps(&a.model)?;
    let set = super::timestep_set(&p, &schedule.config, model_set)?;
    // The iteration's draws after its window: t (by anneal_iters' schedule), eps, eps'.
    let mut draws = Draws::replay(&w)?;
    let t = draws.timestep(p.t_schedule(), &set);
    let sh = lat.z.shape();
    let noise = draws.noise([sh[0], sh[1], sh[2], sh[3]]);
    let circular = w.window.circular;
    let x = a.threads.install(|| {
        step::noise_branches(&schedule, lat.z, z0_src, &noise, t, &p.mvfc, circular)
    })??;
    tracing::info!(
        "mvfc-filter: iteration {} views {:?}, t = {t} (ab = {:.4}), {}",
        w.iteration,
        w.window.views,
        schedule.alpha_bar(t)?,
        serde_json::to_string(&p.mvfc).unwrap_or_default()
    );
    let meta = serde_json::json!({
        "timestep": t,
        "alpha_bar": schedule.alpha_bar(t)?,
        "filtered": p.mvfc.enabled,
        "source_filtered": p.mvfc.enabled && p.mvfc.source,
        "mvfc": p.mvfc,
        "draws": { "seed": w.seed, "iteration": w.iteration },
        "iteration": lat.iteration.is_some().then_some(&w),
    });
    write(&a, &p, &x, &noise, meta)?;
    Ok(t)
}

/// The iteration the latents record (their seed wins over the configuration's), or (none
/// recorded) iteration `--iteration` of the configuration's seed on an open path of all
/// their views.
fn window(a: &Args, p: &Config, lat: &Latents) -> Result<IterationWindow> {
    match (&lat.iteration, a.iteration) {
        (Some(w), None) => Ok(w.clone()),
        (Some(w), Some(_)) => Err(Error::param(format!(
            "{} records its iteration (seed {}, iteration {}); drop --iteration",
            a.latents.display(),
            w.seed,
            w.iteration
        ))),
        (None, it) => Ok(IterationWindow::whole_open_path(
            lat.z.shape()[0],
            p.seed,
            it.unwrap_or(0),
        )),
    }
}

/// Write the noised-latents artifact.
fn write(
    a: &Args,
    p: &Config,
    x: &IterLatents,
    noise: &Noise,
    meta: serde_json::Value,
) -> Result<()> {
    let params = serde_json::json!({
        "iteration": a.iteration, "seed": p.seed, "timesteps": p.timesteps,
        "anneal_iters": p.anneal_iters, "mvfc": p.mvfc,
    });
    let mut out = ArtifactWriter::create(
        &a.out,
        ArtifactKind::NoisedLatents,
        Producer::new("mvfc-filter", crate::VERSION, params),
    )?;
    out.add_input("latents", &a.latents)?;
    out.add_input("source-latents", &a.source_latents)?;
    out.add_input("model", &super::model_manifest(&a.model))?;
    write_array(&mut out, "z_src.npy", &x.z_src)?;
    write_array(&mut out, "z_tgt.npy", &x.z_tgt)?;
    write_array(&mut out, "eps.npy", &x.eps)?;
    write_array(&mut out, "eps_shared.npy", &noise.eps_shared)?;
    out.set_meta(meta);
    crate::timing::io(|| out.commit())?;
    tracing::info!("wrote noised latents at t = {}", x.t);
    Ok(())
}
