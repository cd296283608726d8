//! `distill`: K iterations of the whole FantasyStyle loop in one process ([`crate::distill`]:
//! render N adjacent views, encode, noise, MVFC, CSD, one colour step), from a scene or
//! from a checkpoint, writing a checkpoint.
//!
//! Why in one process: an iteration of the stylizer prior on four 256x256 views takes
//! well under a second; as five stage processes with artifacts between them it would pay
//! process start, model loading and artifact hashing every iteration (the first version's
//! rounds spent about as long outside the computation as in it). The DAG runs chunks of K
//! iterations (`distill@c1`, `distill@c2`, ...) and every chunk writes a checkpoint, so a
//! run still resumes after a failure. The same iteration runs as five stages, one
//! artifact per step, in `data-sample/stylize-stages.toml` (the same library functions,
//! [`crate::distill::step`]; the same bytes, tested), to look inside it.
//!
//! A checkpoint ([`crate::artifacts::write_checkpoint`]) is a `scene` artifact (anything
//! that reads a scene reads it) holding `scene.ply` (and `scene.splat`, `scene.spz` with
//! `--format ply,splat,spz`), the optimizer state (`adam_dc.npy`, `adam_rest.npy`: Adam's
//! moments; `state.json`: iteration and step counts), `history.json` (every iteration's
//! timestep, views, loss, clipped fraction, and the agreement of the prior's
//! high-frequency change across visits and neighbouring views,
//! [`crate::distill::agreement`]: a measurement only `distill` makes, not the stage
//! chain), `hf_prev.npy` `[V, 3, H, W]` (each view's last high-pass change, which the
//! next chunk's revisit agreement compares with) and the last iteration's tensors for
//! `pipeline inspect`: `last_targets.npy` `[N, H, W, 3]` and, when the prior was called
//! (not for csd at `--guidance 0`, which asks nothing of it), `last_z0.npy`,
//! `last_z_tgt.npy`, `last_z_src.npy` `[N, C, h, w]`. Every draw
//! depends only on (seed, iteration), so chunks of any size, and a resume after a kill,
//! give the same bytes as one uninterrupted run.

use super::{ColourArgs, MvfcArgs, PriorArgs, SplitArgs, TextureArgs, Threads, TimestepArgs};
use crate::artifacts::{
    CHECKPOINT_HF_PREV, CheckpointParts, extend_history, load_scene, read_progress, read_views,
    write_checkpoint,
};
use crate::csd::{self, CsdParams};
use crate::distill::{DistillParams, Outcome, Progress, Run, SourceViews, distill};
use crate::prior::cost::CostModel;
use crate::prior::model_timesteps;
use crate::{Error, Result, Scene};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Which scene files a checkpoint holds (`--format ply,splat,spz`; scene.ply always).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneFormat {
    /// scene.ply (INRIA layout, every SH coefficient).
    Ply,
    /// scene.splat too (32 bytes per Gaussian, SH degree 0, for web viewers).
    Splat,
    /// scene.spz too (Niantic's compressed format, version 3).
    Spz,
    /// scene.ply and scene.splat (the same as `ply,splat`).
    Both,
}

/// Distil a 2D prior into a scene's colours: K iterations of render -> encode -> MVFC ->
/// CSD -> colour step, from a scene (--scene) or a checkpoint (--resume), writing a
/// checkpoint (a scene artifact with the optimizer state).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "distill", version)]
pub struct Args {
    /// Start from this scene (an INRIA .ply, a .splat or a scene artifact) at iteration 0.
    #[arg(long, required_unless_present = "resume", conflicts_with = "resume")]
    pub scene: Option<PathBuf>,
    /// Continue from this checkpoint (written by distill).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Views artifact of the ORIGINAL scene (render-views): cameras, the source branch's
    /// images and the alpha the targets are composited with.
    #[arg(long)]
    pub source_views: PathBuf,
    #[command(flatten)]
    pub prior: PriorArgs,
    /// Iterations to run in this process (0: only write the checkpoint).
    #[arg(long)]
    pub iters: u64,
    /// Adjacent views per iteration (the paper's N).
    #[arg(long, default_value_t = 4)]
    pub views_per_iter: usize,
    /// Keep the scene's own colours (chroma); change luminance (texture, contrast) only.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub preserve_color: bool,
    /// Let view-dependent colour (f_rest) change too (default: only f_dc).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub fit_rest: bool,
    #[command(flatten)]
    pub csd: CsdParams,
    /// Adam learning rate of the SH DC colours (f_rest: / 20); 0.05 as the sample and
    /// quality DAGs use (BENCHMARKS.md "Colour-fit learning rate").
    #[arg(long, default_value_t = 0.05)]
    pub lr_dc: f32,
    #[command(flatten)]
    pub mvfc: MvfcArgs,
    #[command(flatten)]
    pub timesteps: TimestepArgs,
    #[command(flatten)]
    pub colour: ColourArgs,
    #[command(flatten)]
    pub texture: TextureArgs,
    /// Before the first iteration, move the object's colour mean and covariance onto the
    /// style image's (the colour-transfer baseline, `src/baselines/colour.rs`; ARF's
    /// colour pre-transfer), each Gaussian's colour then clamped into the style's extent
    /// along its principal axes (so a one-sided style brings in no opposite hue): the
    /// loop then starts from the style's palette. Only with `--scene` (a resumed
    /// checkpoint has its colours already); not with `--preserve-color`. The source
    /// branch still sees the original renders.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub colour_init: bool,
    /// Before the first iteration, texture-map the style image onto the object instead:
    /// triplanar projection along each Gaussian's normal, the style resized to
    /// --texture-style-size and one style pixel per render pixel at the object (the
    /// texture term's motif scale), shaded by each Gaussian's relative brightness
    /// (`src/baselines/projection.rs`; not part of FantasyStyle). The loop then starts
    /// from the style's motifs, the same from every view. Only with `--scene`; not with
    /// --colour-init or --preserve-color.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub project_style: bool,
    #[command(flatten)]
    pub split: SplitArgs,
    /// After the iterations, move the result's colour mean and covariance (over its
    /// renders from the source views' cameras) onto the style image's, clamped like
    /// --colour-init (ARF's colour transfer after the optimisation): the palette drift of
    /// the loop taken back, the texture's arrangement kept. Works on a resumed checkpoint
    /// with --iters 0 (the sample DAG's final stage); not with --preserve-color.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub colour_finish: bool,
    /// Give the prior the raw render (object over the background) instead of the object
    /// over a fill of its own colours.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub no_fill: bool,
    /// Seed of every draw (views, timesteps, noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Scene files written into the checkpoint, comma-separated (scene.ply always).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "ply")]
    pub format: Vec<SceneFormat>,
    /// Output checkpoint directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

impl Args {
    /// The loop's parameters, checked.
    pub fn params(&self) -> Result<DistillParams> {
        self.csd.validate()?;
        if !(self.lr_dc.is_finite() && self.lr_dc >= 0.0) {
            return Err(Error::param("--lr-dc must be finite and >= 0"));
        }
        if self.views_per_iter == 0 {
            return Err(Error::param("--views-per-iter must be at least 1"));
        }
        Ok(DistillParams {
            views_per_iter: self.views_per_iter,
            csd: self.csd,
            mvfc: self.mvfc.filter()?,
            mvfc_source: self.mvfc.mvfc_source,
            preserve_color: self.preserve_color,
            fit_rest: self.fit_rest,
            lr_dc: self.lr_dc,
            fill_background: !self.no_fill,
            colour_loss: self.colour.colour_loss,
            t_schedule: self.timesteps.schedule(),
            seed: self.seed,
            ..DistillParams::default()
        })
    }

    /// Where the run starts: the checkpoint, or the scene at iteration 0.
    fn start(&self) -> Result<Progress> {
        crate::timing::load(|| match (&self.scene, &self.resume) {
            (_, Some(dir)) => crate::timing::phase("checkpoint read", || read_progress(dir)),
            (Some(p), None) => Ok(Progress::fresh(load_scene(p)?)),
            (None, None) => Err(Error::param("give --scene or --resume")),
        })
    }
}

/// Run the stage.
pub fn run(a: Args) -> Result<()> {
    // Inputs, all checked before the prior is loaded.
    let p = a.params()?;
    let background = p.background;
    let style = a.prior.load_style()?;
    let mut start = a.start()?;
    let views = crate::timing::load(|| read_views(&a.source_views))?;
    let (cameras, source) = (views.cameras_per_view()?, views.source_views());
    let (n, h, w) = views.dim();
    if let (Some((shape, _)), Some(dir)) = (&start.hf_prev, &start.from)
        && shape[..] != [n, 3, h, w]
    {
        return Err(Error::input(
            dir.join(CHECKPOINT_HF_PREV),
            format!("shape {shape:?}, but the source views need [{n}, 3, {h}, {w}]"),
        ));
    }
    if a.preserve_color && (a.colour_init || a.colour_finish) {
        return Err(Error::param(
            "--colour-init and --colour-finish move the colours onto the style's, \
             --preserve-color keeps the scene's: choose one",
        ));
    }
    if a.project_style && (a.colour_init || a.preserve_color) {
        return Err(Error::param(
            "--project-style paints the style onto the object, --colour-init moves the \
             object's colours and --preserve-color keeps them: choose one",
        ));
    }
    let split = a.split.wanted()?;
    // The starts change a fresh scene; a resumed checkpoint has been through them.
    // Checked before the strength test, so that `--strength 0` does not hide the mistake.
    for (set, flag) in [
        (a.colour_init, "--colour-init"),
        (a.project_style, "--project-style"),
        (split, "--split-px"),
    ] {
        if set && a.resume.is_some() {
            return Err(Error::param(format!(
                "{flag} applies to a fresh start (--scene); a resumed checkpoint has been \
                 through it already"
            )));
        }
    }
    if split && a.prior.strength > 0.0 {
        start.scene = a.split.split(&start.scene, &cameras, &a.source_views)?;
    }
    if a.colour_init && a.prior.strength > 0.0 {
        start.scene = colour_init(&start, &source, &style, p.background)?;
    }
    if a.project_style && a.prior.strength > 0.0 {
        start.scene = project_style(&a, &start, &cameras, &source, &style)?;
    }
    let (_, model_set) = model_timesteps(&a.prior.model)?;
    let mut outcome = if a.prior.strength == 0.0 || a.iters == 0 {
        // Strength 0 is "unchanged" exactly; 0 iterations only re-packages the input.
        if a.prior.strength == 0.0 && a.iters > 0 {
            tracing::info!("strength 0: the scene is left unchanged");
        }
        Outcome::unchanged(&start)
    } else {
        let mut prior = a.prior.open(&style, a.threads)?;
        csd::check_mode(a.csd.mode, prior.info())?;
        let set = a.timesteps.set(&prior.info().scheduler, model_set)?;
        let cost = CostModel::for_model(&a.prior.model, a.threads.n, a.prior.device.device)?;
        let texture = a
            .texture
            .term(Some(&a.prior.style), Some(&style), a.threads)?;
        let run = Run {
            params: p,
            set,
            iters: a.iters,
            texture,
        };
        let (pr, c) = (prior.as_mut(), cost.as_ref());
        a.threads
            .install(|| distill(&start, &cameras, &source, pr, run, c))??
    };

    if a.colour_finish && a.prior.strength > 0.0 {
        let scene = &outcome.scene;
        outcome.scene = a
            .threads
            .install(|| colour_finish(scene, &cameras, &style, background))??;
    }

    // The checkpoint.
    crate::distill::guard::checkpoint(&outcome.scene, &outcome.state)?;
    let ph = crate::timing::span("checkpoint write");
    let iteration = start.iteration + a.iters;
    let producer = producer(&a, start.iteration);
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    match (&a.resume, &a.scene) {
        (Some(dir), _) => out.add_input("resume", dir)?,
        (None, Some(p)) => out.add_input("scene", p)?,
        _ => {}
    }
    out.add_input("source-views", &a.source_views)?;
    a.prior.add_inputs(&mut out)?;
    write_scene(&mut out, &outcome.scene, &a.format, &a.out)?;
    let mut history = start.history;
    extend_history(&mut history, &outcome.reports)?;
    let parts = CheckpointParts {
        scene: &outcome.scene,
        state: &outcome.state,
        iteration,
        history: &history,
        hf_prev: outcome
            .hf_prev
            .as_ref()
            .map(|(s, d)| (s.as_slice(), d.as_slice())),
        last: outcome.last.as_ref(),
    };
    write_checkpoint(&mut out, &parts)?;
    crate::timing::io(|| out.commit())?;
    drop(ph);
    tracing::info!("wrote {} (iteration {iteration})", a.out.display());
    Ok(())
}

/// `--colour-init`: the start scene with the object's colour statistics (over the source
/// views) moved onto those of the style image (as loaded for the prior).
fn colour_init(
    start: &crate::distill::Progress,
    source: &SourceViews,
    style: &crate::imageio::Image,
    background: [f32; 3],
) -> Result<crate::Scene> {
    let views: Vec<(&[f32], &[f32])> = (0..source.rgb.len())
        .map(|v| (&source.rgb[v][..], &source.alpha[v][..]))
        .collect();
    move_palette("colour init", &start.scene, &views, background, style)
}

/// `--project-style`: the start scene with the style image (at the texture term's size)
/// texture-mapped onto it.
fn project_style(
    a: &Args,
    start: &crate::distill::Progress,
    cameras: &[crate::Camera],
    source: &SourceViews,
    style: &crate::imageio::Image,
) -> Result<crate::Scene> {
    use crate::distill::projection::{Placement, depth_views, project_style, surface_normals};
    use crate::maths::warp::surface_depth;
    let _ph = crate::timing::span("style projection");
    // The cameras are the source views': a placement error is about them.
    let at = Placement::of(&start.scene, cameras)
        .map_err(|e| Error::input(&a.source_views, e.to_string()))?;
    let img = crate::vgg::prepare_style(style, a.texture.texture_style_size, &a.prior.style)?;
    tracing::info!(
        "style projection: {}x{} style px, {:.3e} world units per px, centre {:.3?}",
        img.width,
        img.height,
        at.world_per_pixel,
        at.centre
    );
    let surfaces: Vec<Vec<f32>> = (source.depth.iter().zip(&source.alpha))
        .map(|(depth, alpha)| surface_depth(depth, alpha))
        .collect();
    let normals = surface_normals(&start.scene, &depth_views(cameras, &surfaces));
    tracing::info!("style projection: {normals}");
    Ok(project_style(&start.scene, &img, &at, &normals.normals))
}

/// `--colour-finish`: `scene` with the colour statistics of its own renders from
/// `cameras` moved onto those of the style image.
fn colour_finish(
    scene: &Scene,
    cameras: &[crate::Camera],
    style: &crate::imageio::Image,
    background: [f32; 3],
) -> Result<Scene> {
    let _ph = crate::timing::span("colour finish");
    let renders = crate::render::render_all(scene, cameras, background)?;
    let views: Vec<(&[f32], &[f32])> = renders.iter().map(|r| (&r.rgb[..], &r.alpha[..])).collect();
    move_palette("colour finish", scene, &views, background, style)
}

/// [`crate::distill::colour_transfer::move_palette`], logged as `what`.
fn move_palette(
    what: &str,
    scene: &Scene,
    views: &[(&[f32], &[f32])],
    background: [f32; 3],
    style: &crate::imageio::Image,
) -> Result<Scene> {
    let (scene, tr, clamped) =
        crate::distill::colour_transfer::move_palette(scene, views, background, style)?;
    tracing::info!(
        "{what}: object mean {:.3?} -> style mean {:.3?}; {clamped} of {} Gaussians \
         clamped into the style's colour extent",
        tr.source.mean,
        tr.style.mean,
        scene.len()
    );
    Ok(scene)
}

/// The checkpoint's producer: the stage and its flags.
fn producer(a: &Args, start: u64) -> Producer {
    let own = serde_json::json!({
        "iters": a.iters, "start": start, "views_per_iter": a.views_per_iter,
        "preserve_color": a.preserve_color, "fit_rest": a.fit_rest, "csd": a.csd,
        "lr_dc": a.lr_dc, "fill": !a.no_fill, "seed": a.seed, "format": a.format,
        "colour_init": a.colour_init, "colour_finish": a.colour_finish,
        "project_style": a.project_style, "split_px": a.split.split_px,
    });
    let params = super::merge_params(&[
        own,
        a.mvfc.to_json(),
        a.timesteps.to_json(),
        a.colour.to_json(),
        a.texture.to_json(),
        a.prior.to_json(),
    ]);
    Producer::new("distill", crate::VERSION, params)
}

fn write_scene(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    scene: &Scene,
    format: &[SceneFormat],
    dir: &std::path::Path,
) -> Result<()> {
    let has = |f| format.contains(&f);
    let extra = crate::scene::ExtraFormats {
        splat: has(SceneFormat::Splat) || has(SceneFormat::Both),
        spz: has(SceneFormat::Spz),
    };
    for (name, bytes) in crate::scene::encode_files(dir, scene, extra)? {
        out.write_bytes(name, &bytes)?;
    }
    Ok(())
}
