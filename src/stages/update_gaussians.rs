//! `update-gaussians`: fit a scene's SH colours to target images with geometry frozen
//! (the paper's "Gaussians are updated toward the targets" step).
//!
//! Two uses, told apart by the targets:
//!
//! * **One iteration of the stage chain** (targets of `csd-step`, which record their
//!   iteration): the colour step of `distill` ([`crate::distill::step::colour_step`]):
//!   one Adam step on the window's views, continuing the optimizer state of the `--scene`
//!   checkpoint (a plain scene: iteration 0, zero state), which must be at the targets'
//!   iteration. Writes the next checkpoint, as `distill` does
//!   ([`crate::distill::checkpoint::write_checkpoint`]: `scene.ply`, the optimizer state,
//!   `history.json` with this iteration's report; not `distill`'s agreement measurement,
//!   which the chain does not make). The step is configured by the method's
//!   configuration as distill's (`--preset`, `--config`, `--set`: `lr_dc`, `sh`,
//!   `colour_loss`, the `terms` and their `[texture]`, `fill`); the fit's own flags
//!   (`--lr-dc`, `--lr-rest`, `--ssim-weight`, `--mask-alpha`, `--cache`) do not apply.
//!   Texture terms need `--style` and `--source-views` (whose alpha masks them); `--steps`
//!   must be absent or 1.
//! * **A colour fit to any images** (a `targets` artifact without an iteration, or a
//!   `views` artifact with one image per camera): [`crate::optim::fit_colours`] (L1 +
//!   D-SSIM, Adam from zero; the method's configuration does not apply) for
//!   `--steps` steps; writes a `scene` artifact with
//!   `scene.ply` (every non-colour field bit-identical to the input) and `loss.json`
//!   (the mean loss over views per step, plus cache statistics).

use super::{Background, ConfigArgs, SceneInput, Threads};
use crate::artifacts::{Targets, read_targets, read_views};
use crate::distill::checkpoint::{
    CheckpointParts, extend_history, load_progress, write_checkpoint,
};
use crate::distill::step::{ColourStep, IterationWindow, TargetStats, colour_step};
use crate::distill::{Config, IterReport};
use crate::optim::{ColourFit, FitParams, fit_colours};
use crate::render::CacheMode;
use crate::scene::ply;
use crate::terms::PriorTerm;
use crate::terms::texture::TextureTerm;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Fit the SH colours of a splat scene to target images (geometry frozen) and write
/// the updated scene artifact (scene.ply, loss.json).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "update-gaussians", version)]
pub struct Args {
    /// The scene, and the cameras: one per target image, at the targets' size.
    #[command(flatten)]
    pub input: SceneInput,
    /// Targets: a `targets` or `views` artifact directory whose rgb.npy is `[N,H,W,3]`.
    #[arg(long)]
    pub targets: PathBuf,
    /// Number of Adam steps; each step renders every view once (>= 1). Required for a
    /// colour fit; one iteration of the stage chain is one step.
    #[arg(long)]
    pub steps: Option<usize>,
    /// Output scene artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Adam learning rate of the degree-0 SH coefficients f_dc. 3DGS trains from scratch
    /// at 0.0025 over 30k steps; a colour fit of tens to hundreds of steps needs more
    /// (docs/method.md, "Colour-fit learning rate": 300 steps reach 30 dB at 0.0025, 53 dB
    /// at 0.01).
    #[arg(long, default_value_t = 0.01)]
    pub lr_dc: f32,
    /// Adam learning rate of the higher SH coefficients f_rest (default: lr-dc / 20).
    #[arg(long)]
    pub lr_rest: Option<f32>,
    /// SH degree of the fitted scene (a colour fit only): the input's bands kept, new
    /// ones starting at zero, bands above it removed (default: the input's degree).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub sh_degree: Option<u8>,
    /// Weight lambda of the D-SSIM term: loss = (1 - lambda) L1 + lambda (1 - SSIM).
    #[arg(long, default_value_t = 0.2)]
    pub ssim_weight: f32,
    /// Multiply render and target by the rendered alpha before the loss.
    #[arg(long)]
    pub mask_alpha: bool,
    /// Contribution cache: `on` (every view), `off` (re-rasterize every step), or
    /// `budget=MB` (cache views in order while they fit in MB megabytes).
    #[arg(long, default_value = "on")]
    pub cache: String,
    #[command(flatten)]
    pub background: Background,
    /// One iteration's targets: the method's configuration, as distill's.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Style image of the texture terms (one iteration's targets).
    #[arg(long)]
    pub style: Option<PathBuf>,
    /// Views artifact of the ORIGINAL scene, every camera (as distill's
    /// --source-views): its alpha masks the texture terms (one iteration's targets).
    #[arg(long)]
    pub source_views: Option<PathBuf>,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage: load, fit (or step), write the artifact.
pub fn run(a: Args) -> Result<()> {
    let cache: CacheMode = a.cache.parse()?;
    let targets = read_targets(&a.targets)?;
    let params = FitParams {
        lr_dc: a.lr_dc,
        lr_rest: a.lr_rest.unwrap_or(a.lr_dc / 20.0),
        ssim_weight: a.ssim_weight,
        mask_alpha: a.mask_alpha,
        cache,
        background: a.background.rgb,
        progress: true,
    };
    let own = serde_json::json!({
        "cameras": a.input.cameras, "steps": a.steps, "background": a.background.rgb,
    });
    match targets.step.clone() {
        Some(step) => {
            let config = a.config.load()?;
            let own = super::merge_params(&[own, serde_json::json!({ "config": config })]);
            let producer = Producer::new("update-gaussians", crate::VERSION, own);
            iteration(&a, &config, &targets, step, producer)
        }
        None => {
            let fit_flags = serde_json::json!({
                "lr_dc": params.lr_dc, "lr_rest": params.lr_rest, "ssim_weight": a.ssim_weight,
                "mask_alpha": a.mask_alpha, "cache": a.cache, "sh_degree": a.sh_degree,
            });
            let own = super::merge_params(&[own, fit_flags]);
            let producer = Producer::new("update-gaussians", crate::VERSION, own);
            fit(&a, &targets, &params, producer)
        }
    }
}

/// One iteration's colour step from a checkpoint to the next, configured by `config`.
fn iteration(
    a: &Args,
    config: &Config,
    targets: &Targets,
    (w, t, stats): (IterationWindow, usize, TargetStats),
    producer: Producer,
) -> Result<()> {
    if a.steps.is_some_and(|s| s != 1) {
        return Err(Error::param(
            "--steps: the targets are one iteration's (csd-step), which is one step",
        ));
    }
    if a.sh_degree.is_some() {
        return Err(Error::param(
            "--sh-degree: the targets are one iteration's (csd-step); the checkpoint's degree stays (the configuration's `sh` chose it)",
        ));
    }
    let (start, cams) = checkpoint_and_cameras(a, targets, &w)?;
    let (_, h, wd, _) = targets.rgb.dim();
    let cams: Vec<_> = w.window.views.iter().map(|&v| cams[v].clone()).collect();
    let (texture, alpha) = texture_inputs(a, config, &w, (h, wd))?;
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    a.input.add_inputs(&mut out)?;
    out.add_input("targets", &a.targets)?;
    if texture.is_some() {
        for (name, p) in [("style", &a.style), ("source-views", &a.source_views)] {
            if let Some(p) = p {
                out.add_input(name, p)?;
            }
        }
    }
    let view_terms = config.terms.view_terms();
    let cs = ColourStep {
        prior: config.terms.prior().map(|(_, weight)| PriorTerm {
            loss: config.colour_loss,
            weight,
        }),
        texture: texture.as_ref(),
        views: &view_terms,
        background: a.background.rgb,
        fill: config.fill,
        iteration: w.iteration,
    };
    let params = crate::distill::step::fit_params(config, a.background.rgb);
    let (scene, state, losses) = a.threads.install(|| -> Result<_> {
        let mut fit = ColourFit::without_targets(&start.scene, &cams, &params)?;
        fit.set_optimizer_state(start.state())?;
        let views: Vec<usize> = (0..cams.len()).collect();
        let alpha: Vec<&[f32]> = alpha.iter().map(|x| x.as_slice()).collect();
        let losses = colour_step(&mut fit, &views, targets.rgb.view(), &alpha, &cs)?;
        Ok((fit.scene().clone(), fit.optimizer_state(), losses))
    })??;
    crate::distill::guard::checkpoint(&scene, &state)?;
    let (loss, _) = losses;
    let report = IterReport::new(&w, t, stats, losses);
    let mut history = start.history;
    extend_history(&mut history, &[report])?;
    out.write_bytes("scene.ply", &ply::encode_ply(&scene))?;
    let parts = CheckpointParts {
        scene: &scene,
        state: &state,
        iteration: w.iteration + 1,
        history: &history,
        hf_prev: None,
        last: None,
    };
    write_checkpoint(&mut out, &parts)?;
    crate::timing::io(|| out.commit())?;
    tracing::info!(
        "iteration {} (views {:?}, t = {t}): loss {loss:.5}; wrote {}",
        w.iteration,
        w.window.views,
        a.out.display()
    );
    Ok(())
}

/// The checkpoint the iteration starts from (at the targets' iteration) and the cameras of
/// the iteration's whole path, at the targets' size.
fn checkpoint_and_cameras(
    a: &Args,
    targets: &Targets,
    w: &IterationWindow,
) -> Result<(crate::distill::Progress, Vec<crate::Camera>)> {
    let start = crate::timing::load(|| load_progress(&a.input.scene))?;
    if start.iteration != w.iteration {
        return Err(Error::input(
            &a.input.scene,
            format!(
                "has done {} iterations, but the targets ({}) are of iteration {}",
                start.iteration,
                a.targets.display(),
                w.iteration
            ),
        ));
    }
    let (_, h, wd, _) = targets.rgb.dim();
    let cams = a.input.load_cameras(&start.scene, wd as u32, h as u32)?;
    if cams.len() != w.path.len {
        return Err(Error::input(
            &a.targets,
            format!(
                "the iteration's path has {} cameras, `{}` {}",
                w.path.len,
                a.input.cameras,
                cams.len()
            ),
        ));
    }
    Ok((start, cams))
}

/// The texture terms of one iteration's colour step (`None` without a VGG term) and the
/// source coverage `[H, W]` of each of the window's views they are masked with (zero
/// planes without them).
fn texture_inputs(
    a: &Args,
    config: &Config,
    w: &IterationWindow,
    (h, wd): (usize, usize),
) -> Result<(Option<TextureTerm>, Vec<Vec<f32>>)> {
    let texture = match (
        &a.style,
        config.terms.statistics(&config.texture.layers)?.len(),
    ) {
        (_, 0) => None,
        (None, _) => {
            return Err(Error::param(format!(
                "the texture terms ({}) need the style image (--style)",
                config.terms
            )));
        }
        (Some(style), _) => super::texture_term(config, style, None, a.threads)?,
    };
    let alpha: Vec<Vec<f32>> = match (&texture, &a.source_views) {
        (None, _) => vec![vec![0.0; h * wd]; w.window.views.len()],
        (Some(_), None) => {
            return Err(Error::param(
                "the texture term needs --source-views (its alpha masks the term)",
            ));
        }
        (Some(_), Some(dir)) => {
            let src = crate::timing::load(|| read_views(dir))?;
            let (n, sh, sw) = src.dim();
            if n != w.path.len || (sh, sw) != (h, wd) {
                return Err(Error::input(
                    src.art.path("alpha.npy"),
                    format!(
                        "{n} views of {sw}x{sh}, but the iteration's path has {} cameras of \
                         {wd}x{h}",
                        w.path.len
                    ),
                ));
            }
            let plane = |v: usize| -> Vec<f32> {
                src.alpha
                    .index_axis(ndarray::Axis(0), v)
                    .iter()
                    .copied()
                    .collect()
            };
            w.window.views.iter().map(|&v| plane(v)).collect()
        }
    };
    Ok((texture, alpha))
}

/// A colour fit of `--steps` steps to the targets, one per camera.
fn fit(a: &Args, targets: &Targets, params: &FitParams, producer: Producer) -> Result<()> {
    let Some(steps) = a.steps.filter(|s| *s > 0) else {
        return Err(Error::param("--steps must be at least 1"));
    };
    let mut scene = a.input.load_scene()?;
    if let Some(d) = a.sh_degree {
        scene = crate::scene::colour::with_degree(&scene, d as usize);
    }
    let rgb_path = targets.art.path("rgb.npy");
    let (n, h, w, _) = targets.rgb.dim();
    let cams = a.input.load_cameras(&scene, w as u32, h as u32)?;
    if cams.len() != n {
        return Err(Error::input(
            &rgb_path,
            format!(
                "{n} target images but {} cameras in `{}`",
                cams.len(),
                a.input.cameras
            ),
        ));
    }
    let per = h * w * 3;
    let rgb = targets.rgb.as_slice().expect("standard layout");
    let targets: Vec<Vec<f32>> = rgb.chunks(per).map(|c| c.to_vec()).collect();
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    a.input.add_inputs(&mut out)?;
    out.add_input("targets", &a.targets)?;
    let (fitted, report) = a
        .threads
        .install(|| fit_colours(&scene, &cams, &targets, steps, params))??;
    out.write_bytes("scene.ply", &ply::encode_ply(&fitted))?;
    out.write_json(
        "loss.json",
        &serde_json::json!({
            "loss": report.losses,
            "steps": steps,
            "views": n,
            "cached_views": report.cached_views,
            "cache_bytes": report.cache_bytes,
        }),
    )?;
    out.set_meta(serde_json::json!({
        "gaussians": fitted.len(), "sh_degree": fitted.sh_degree,
        "final_loss": report.losses.last(),
    }));
    crate::timing::io(|| out.commit())?;
    tracing::info!(
        "loss {:.5} -> {:.5}; wrote {}",
        report.losses.first().unwrap_or(&f32::NAN),
        report.losses.last().unwrap_or(&f32::NAN),
        a.out.display()
    );
    Ok(())
}
