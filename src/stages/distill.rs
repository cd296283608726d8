//! `distill`: K iterations of the whole FantasyStyle loop in one process ([`crate::distill`]:
//! render N adjacent views, encode, noise, MVFC, CSD, one colour step), from a scene (after
//! the configuration's start) or from a checkpoint, then the configuration's finish,
//! writing a checkpoint. What it runs is the method's configuration
//! ([`crate::config`]: `--preset`, `--config`, `--set`, and the choices
//! `--terms`, `--start`, `--finish`); `distill --help` lists every key.
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
//! A checkpoint ([`crate::distill::checkpoint::write_checkpoint`]) is a `scene` artifact (anything
//! that reads a scene reads it) holding `scene.ply` (and `scene.splat`, `scene.spz` with
//! `--format ply,splat,spz`), the optimizer state (`adam_dc.npy`, `adam_rest.npy`: Adam's
//! moments; `state.json`: iteration and step counts), `history.json` (every iteration's
//! timestep, views, loss, clipped fraction, and the agreement of the prior's
//! high-frequency change across visits and neighbouring views,
//! [`crate::metrics::agreement`]: a measurement only `distill` makes, not the stage
//! chain), `hf_prev.npy` `[V, 3, H, W]` (each view's last high-pass change, which the
//! next chunk's revisit agreement compares with) and the last iteration's tensors for
//! `pipeline inspect`: `last_targets.npy` `[N, H, W, 3]` and, when the prior was called
//! (not when it asks nothing: no prior term, or csd at `csd.guidance = 0`), `last_z0.npy`,
//! `last_z_tgt.npy`, `last_z_src.npy` `[N, C, h, w]`. Every draw
//! depends only on (seed, iteration), so chunks of any size, and a resume after a kill,
//! give the same bytes as one uninterrupted run.

use super::{ConfigArgs, PriorArgs, Threads};
use crate::artifacts::{load_scene, read_selection, read_views};
use crate::distill::checkpoint::{
    CHECKPOINT_HF_PREV, CheckpointParts, extend_history, read_progress, write_checkpoint,
};
use crate::distill::{Config, Outcome, Progress, Run, SourceViews, distill};
use crate::ends::{self, EndInputs, Finish, Start};
use crate::prior::cost::CostModel;
use crate::prior::model_timesteps;
use crate::regions::{RegionSpec, Regions};
use crate::scene::colour::{Bands, drop_bands};
use crate::terms::Terms;
use crate::{Camera, Error, Result, Scene};
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

/// The configuration keys, for the end of `--help`.
fn config_help() -> String {
    format!(
        "Configuration keys (--set KEY=VALUE, or in a --config file; the defaults are \
         FantasyStyle's method, the presets are presets/NAME.toml):\n\n{}",
        Config::help()
    )
}

/// Distil a 2D prior into a scene's colours: from a scene (--scene, after the
/// configuration's start) or a checkpoint (--resume), K iterations of render -> encode ->
/// MVFC -> CSD -> colour step, then the configuration's finish; writes a checkpoint (a
/// scene artifact with the optimizer state).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "distill", version, after_long_help = config_help())]
pub struct Args {
    /// Start from this scene (an INRIA .ply, a .splat or a scene artifact) at iteration 0,
    /// after the configuration's start.
    #[arg(long, required_unless_present = "resume", conflicts_with = "resume")]
    pub scene: Option<PathBuf>,
    /// Continue from this checkpoint (written by distill; its start is done).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Views artifact of the ORIGINAL scene (render-views): cameras, the source branch's
    /// images and the alpha the targets are composited with.
    #[arg(long)]
    pub source_views: PathBuf,
    #[command(flatten)]
    pub prior: PriorArgs,
    /// Only these Gaussians change (a `selection` artifact, written by `select`, of the
    /// scene being stylized): each one's colour updates are scaled by its weight, and a
    /// Gaussian of weight 0 keeps its bytes through the start, the loop and the finish.
    #[arg(long)]
    pub selection: Option<PathBuf>,
    /// A region with its own style, repeatable: `SELECTION[=STYLE][@STRENGTH]`
    /// (docs/selection.md, "Regions"). SELECTION is a selection artifact, a source
    /// (`box:...`, `masks:DIR`, ...) or `rest` (what the other regions leave); STYLE an
    /// image or a blend `a.png:0.7,b.png:0.3` (default: --style); STRENGTH in [0, 1]
    /// (default 1). All regions are styled in one pass of the `patches` finish
    /// (`--iters 0`); a Gaussian in no region keeps its bytes.
    #[arg(long, value_parser = RegionSpec::parse, conflicts_with_all = ["selection", "regions"])]
    pub region: Vec<RegionSpec>,
    /// The regions from a TOML file of `[[regions]]` entries (`name`, `selection`,
    /// `style`, `strength`, as --region; paths relative to the file).
    #[arg(long, conflicts_with = "selection")]
    pub regions: Option<PathBuf>,
    /// Iterations to run in this process (0: only the start, from a scene, and the
    /// finish).
    #[arg(long)]
    pub iters: u64,
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The colour step's terms, `NAME=WEIGHT,...` (the key `terms`, given whole), e.g.
    /// `csd=1` (the paper) or `csd=1,nnfm=1,gram=0.1` (the arf preset's).
    #[arg(long, value_name = "TERMS", value_parser = Terms::parse)]
    pub terms: Option<Terms>,
    /// How a fresh run starts (the key `start`), an end of the registry: scene, colour
    /// or projection.
    #[arg(long, value_parser = ends::End::start)]
    pub start: Option<Start>,
    /// How the run ends (the key `finish`), an end of the registry: none, colour or
    /// patches. A chunk of a longer run gives `--finish none`; its last stage applies the
    /// finish.
    #[arg(long, value_parser = ends::End::finish)]
    pub finish: Option<Finish>,
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
    /// The configuration: the layers of `--preset`, `--config`, `--set`, then `--terms`,
    /// `--start`, `--finish`; checked.
    pub fn config(&self) -> Result<Config> {
        let mut c = self.config.load()?;
        if let Some(t) = self.terms {
            c.terms = t;
        }
        if let Some(s) = self.start {
            c.start = s;
        }
        if let Some(f) = self.finish {
            c.finish = f;
        }
        c.checked()
    }

    /// Where the run starts: the checkpoint, or the scene at iteration 0.
    fn progress(&self) -> Result<Progress> {
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
    let config = a.config()?;
    let style = a.prior.load_style()?;
    let mut start = a.progress()?;
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
    let regions = load_regions(&a, &config, &start.scene)?;
    let selection = match &a.selection {
        // Regions covering every Gaussian whole select nothing apart (a run without a
        // selection: `sh = drop` leaves degree 0).
        _ if regions.is_some() => regions
            .as_ref()
            .filter(|r| r.combined.weights.iter().any(|&w| w < 1.0))
            .map(|r| r.combined.clone()),
        Some(dir) => {
            let sel = crate::timing::load(|| read_selection(dir))?;
            sel.check_for(start.scene.len(), dir)?;
            Some(sel)
        }
        None => None,
    };
    // A selection holds every colour change to its weights: `keep` blends a change.
    let keep = |before: &Scene, after: Scene| match &selection {
        Some(s) => s.blend(before, &after),
        None => Ok(after),
    };
    // Strength 0 is "unchanged" exactly: no start, no iteration, no finish.
    let styled = config.strength > 0.0;
    let settings = config.table();
    let inputs = EndInputs {
        cameras: &cameras,
        cameras_from: &a.source_views,
        source: &source,
        style: &style,
        style_path: &a.prior.style,
        settings: &settings,
        selection: selection.as_ref(),
        regions: regions.as_ref(),
    };
    if styled && a.resume.is_none() {
        let started = ends::apply(config.start, &start.scene, &inputs)?;
        start.scene = keep(&start.scene, started)?;
        if config.sh == Bands::Drop && start.scene.sh_degree > 0 {
            start.scene = drop_bands(&start.scene, selection.as_ref());
            tracing::info!("sh = drop: the stylized Gaussians' view-dependent bands removed");
        }
    }
    let sel = selection.as_ref();
    let mut outcome = iterate(&a, &config, &start, &cameras, &source, &style, sel)?;
    if styled && !config.finish.keeps() {
        let scene = &outcome.scene;
        let finished = a
            .threads
            .install(|| ends::apply(config.finish, scene, &inputs))??;
        outcome.scene = keep(&outcome.scene, finished)?;
    }
    write(&a, &config, start, &outcome, regions.as_ref())
}

/// The run's regions (`--region`, `--regions`), loaded and checked against the scene
/// (none without either): only a fresh run of the `patches` finish with `--iters 0`
/// and the `scene` start takes them.
fn load_regions(a: &Args, config: &Config, scene: &Scene) -> Result<Option<Regions>> {
    let specs = match &a.regions {
        Some(file) => RegionSpec::read_file(file)?,
        None if a.region.is_empty() => return Ok(None),
        None => a.region.clone(),
    };
    if a.resume.is_some() || a.iters > 0 || !config.start.keeps() {
        return Err(Error::param(
            "regions are styled by the end alone: give --scene, --iters 0 and the `scene` start",
        ));
    }
    if config.finish.name() != "patches" {
        return Err(Error::param(format!(
            "regions need the `patches` finish (the configuration's finish is `{}`)",
            config.finish
        )));
    }
    let ctx = crate::selection::Context {
        cameras: Some(a.source_views.display().to_string()),
        ..Default::default()
    };
    let r = crate::timing::load(|| crate::regions::load(&specs, scene, &a.prior.style, &ctx))?;
    for reg in &r.list {
        let styles: Vec<String> = reg
            .styles
            .iter()
            .map(|(p, _, w)| format!("{} x {w:.2}", p.display()))
            .collect();
        tracing::info!(
            "region `{}`: {} Gaussians ({}), style {}, strength {}",
            reg.name,
            reg.weights.iter().filter(|&&w| w > 0.0).count(),
            reg.selection,
            styles.join(" + "),
            reg.strength
        );
    }
    Ok(Some(r))
}

/// The iterations of this process from `start` (none at strength 0 or `--iters 0`).
fn iterate(
    a: &Args,
    config: &Config,
    start: &Progress,
    cameras: &[Camera],
    source: &SourceViews,
    style: &crate::imageio::Image,
    selection: Option<&crate::selection::Selection>,
) -> Result<Outcome> {
    if config.strength == 0.0 || a.iters == 0 {
        // Strength 0 is "unchanged" exactly; 0 iterations only re-packages the input.
        if config.strength == 0.0 && a.iters > 0 {
            tracing::info!("strength 0: the scene is left unchanged");
        }
        return Ok(Outcome::unchanged(start));
    }
    let model = a.prior.model(config)?;
    let (_, model_set) = model_timesteps(&model)?;
    let mut prior = a.prior.open(style, config, a.threads)?;
    crate::csd::check_mode(config.csd.mode, prior.info())?;
    let set = super::timestep_set(config, &prior.info().scheduler, model_set)?;
    let cost = CostModel::for_model(&model, a.threads.n, a.prior.device.device)?;
    let texture = super::texture_term(config, &a.prior.style, Some(style), a.threads)?;
    let run = Run {
        params: config.clone(),
        set,
        iters: a.iters,
        texture,
        selection,
    };
    let (pr, c) = (prior.as_mut(), cost.as_ref());
    a.threads
        .install(|| distill(start, cameras, source, pr, run, c))?
}

/// Write the checkpoint: the scene files, the optimizer state, the history.
fn write(
    a: &Args,
    config: &Config,
    start: Progress,
    outcome: &Outcome,
    regions: Option<&Regions>,
) -> Result<()> {
    crate::distill::guard::checkpoint(&outcome.scene, &outcome.state)?;
    let _ph = crate::timing::span("checkpoint write");
    let iteration = start.iteration + a.iters;
    let producer = producer(a, config, start.iteration);
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    match (&a.resume, &a.scene) {
        (Some(dir), _) => out.add_input("resume", dir)?,
        (None, Some(p)) => out.add_input("scene", p)?,
        _ => {}
    }
    out.add_input("source-views", &a.source_views)?;
    if let Some(dir) = &a.selection {
        out.add_input("selection", dir)?;
    }
    a.prior
        .add_inputs(&mut out, config, a.iters > 0 && config.strength > 0.0)?;
    write_scene(&mut out, &outcome.scene, &a.format, &a.out)?;
    if let Some(r) = regions {
        crate::artifacts::write_regions(&mut out, r)?;
    }
    if iteration == 0 {
        // No iteration has run: a scene artifact, no optimizer state (a later run resumes
        // it at iteration 0 with a fresh one).
        crate::timing::io(|| out.commit())?;
        tracing::info!("wrote {} (no iteration: the scene alone)", a.out.display());
        return Ok(());
    }
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
    tracing::info!("wrote {} (iteration {iteration})", a.out.display());
    Ok(())
}

/// The checkpoint's producer: the stage, its flags and the whole configuration.
fn producer(a: &Args, config: &Config, start: u64) -> Producer {
    let own = serde_json::json!({
        "iters": a.iters, "start_iteration": start, "format": a.format,
        "config": config,
    });
    Producer::new(
        "distill",
        crate::VERSION,
        super::merge_params(&[own, a.prior.to_json()]),
    )
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
