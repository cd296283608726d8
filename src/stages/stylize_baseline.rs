//! `stylize-baseline`: restyle a scene's colours with one of the baselines FantasyStyle is
//! compared against ([`crate::baselines`]), writing a `scene` artifact like
//! `update-gaussians` does, so the same `render-views` + `evaluate` steps follow.
//!
//! * `gram`: Gram-matrix style loss over VGG16 layers and two scales + content loss;
//! * `nnfm`: ARF's nearest-neighbour feature matching on the relu3 block + content loss;
//! * `refit`: stylize each original view with the 2D stylizer on its own, then fit colours
//!   to those images (`fit_colours`' L1 + D-SSIM), no MVFC, no distillation;
//! * `colour-transfer`: the object's colour mean and covariance moved onto the style
//!   image's by the linear Monge-Kantorovich map, written into the SH colours
//!   ([`crate::transfer::colour`]); no steps;
//! * `project`: the style image (at `--style-size`) texture-mapped onto the object by
//!   triplanar projection along each Gaussian's normal, one style pixel per render pixel
//!   at the object ([`crate::transfer::projection`]); no steps.
//!
//! Output (schema `scene` v1): `scene.ply` (geometry bit-identical to the input, colours
//! changed), `loss.json` (`method`, and per step the objective, its style and content
//! terms, and every `--monitor-every` steps the Gram distance to the style, mean over
//! views: relu1_2..relu4_3, scale 1; for `colour-transfer` the map and both statistics),
//! for `refit` also `target_000.png`.. (the stylized views it fitted), with `--save-at`
//! also `scene_step10.ply`.. (the scene after those steps); for `refit` also
//! `hf_agree_adjacent` in `loss.json`: how much of the per-view 2D stylizations'
//! high-frequency change agrees between path neighbours after depth reprojection
//! ([`crate::metrics::agreement::adjacent_agreement_of_views`]), the ceiling of the
//! distillation's per-iteration measure (and `hf_agree_adjacent_original`, the same
//! measure on the original renders' own high pass: what the warp allows). Style image handling:
//! grayscale expanded to RGB, alpha dropped, shorter side at least 92 px (relu4_3's
//! receptive field), resized to `--style-size`.
//!
//! **Time budget.** `--budget-s S` (or `--budget-from FILE`, a JSON object with
//! `budget_s`, e.g. another method's measured wall time) stops after the step during
//! which the stage's wall time, counted from its start (loading, rendering the originals
//! and the refit's 2D stylization included), reaches `S`; `--steps` stays the most steps.
//! Then, or with `--record-time`, `timing.json` records the wall time, the steps done
//! and the time of each saved checkpoint. Timing makes the artifact's bytes depend on the
//! machine, so it is written only when asked for (or implied by a budget); a budget
//! run's `steps_done` given back as `--steps` reproduces its scene bit for bit.

use super::{Background, SceneInput, Threads};
pub use crate::baselines::run::Method;
use crate::baselines::run::{Outcome, RunParams, checkpoint_name};
use crate::imageio::Image;
use crate::vgg::{Vgg16, prepare_style};
use crate::{Error, Result, Scene};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Restyle a scene's colours with a baseline (VGG Gram, VGG NNFM, per-view 2D stylize +
/// refit, or a colour-statistics transfer); geometry stays frozen. Writes a scene artifact
/// (scene.ply, loss.json).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "stylize-baseline", version)]
pub struct Args {
    /// The baseline.
    #[arg(long, value_enum)]
    pub method: Method,
    #[command(flatten)]
    pub input: SceneInput,
    /// Style image (PNG/JPEG; grayscale expanded, alpha dropped; shorter side >= 92 px).
    #[arg(long)]
    pub style: PathBuf,
    /// Optimisation steps (each: the step's views rendered, one Adam step); with a time
    /// budget, the most steps. Ignored by colour-transfer.
    #[arg(long)]
    pub steps: usize,
    /// Views per step (0: every view each step). Fewer: that many distinct views per
    /// step from seeded shuffles of all views (every view equally often), as ARF and SGSST
    /// sample one view per iteration; more steps for the same time.
    #[arg(long, default_value_t = 0)]
    pub views_per_step: usize,
    /// Seed of the view draws (with --views-per-step).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Wall-time budget in seconds from the stage's start: stop after the step during
    /// which it runs out (writes timing.json).
    #[arg(long, conflicts_with = "budget_from")]
    pub budget_s: Option<f64>,
    /// Read the budget from a JSON file with a number `budget_s` (e.g. the quality
    /// benchmark's measured wall time of our method on the same case).
    #[arg(long)]
    pub budget_from: Option<PathBuf>,
    /// Also write the scene after these step counts (comma-separated, e.g. 5,10,20) as
    /// scene_stepN.ply, for speed-accuracy curves.
    #[arg(long, value_delimiter = ',')]
    pub save_at: Vec<usize>,
    /// Write timing.json (wall time, steps done, checkpoint times) even without a budget.
    #[arg(long, default_value_t = false)]
    pub record_time: bool,
    /// Output artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Render width (>= 16).
    #[arg(long, default_value_t = 128)]
    pub width: u32,
    /// Render height (>= 16).
    #[arg(long, default_value_t = 128)]
    pub height: u32,
    #[command(flatten)]
    pub background: Background,
    /// Adam learning rate of the DC colour coefficients.
    #[arg(long, default_value_t = 0.01)]
    pub lr_dc: f32,
    /// Adam learning rate of the higher-order SH coefficients.
    #[arg(long, default_value_t = 0.0005)]
    pub lr_rest: f32,
    /// The style image is resized so its shorter side is this many pixels (>= 92).
    #[arg(long, default_value_t = 256)]
    pub style_size: usize,
    /// Weight of the style term (gram, nnfm).
    #[arg(long, default_value_t = 1.0)]
    pub style_weight: f64,
    /// Weight of the content term (default: 0.05 for gram, 0.005 for nnfm).
    #[arg(long)]
    pub content_weight: Option<f64>,
    /// Log the Gram distance to the style every this many steps (0: first and last only).
    #[arg(long, default_value_t = 10)]
    pub monitor_every: usize,
    /// No Gram-distance monitor (it renders and runs VGG on every view, which a timed run
    /// should not pay); the log then ends with the last step's loss.
    #[arg(long, default_value_t = false)]
    pub no_monitor: bool,
    /// VGG16 weights directory (conv{i}_weight.npy, made by scripts/setup.sh); default:
    /// lpips/vgg16 in the models directory ($FANTASYSTYLE_MODELS, else the nearest
    /// vendor/models above the executable or the current directory).
    #[arg(long)]
    pub vgg: Option<PathBuf>,
    /// Stylizer model directory for `refit` (model.json, made by scripts/setup.sh);
    /// default: stylizer in the models directory (see --vgg).
    #[arg(long)]
    pub stylizer: Option<PathBuf>,
    #[command(flatten)]
    pub threads: Threads,
}

impl Args {
    /// The run's parameters (the budget checked).
    pub fn params(&self) -> Result<RunParams> {
        Ok(RunParams {
            method: self.method,
            steps: self.steps,
            views_per_step: self.views_per_step,
            seed: self.seed,
            lr_dc: self.lr_dc,
            lr_rest: self.lr_rest,
            background: self.background.rgb,
            style_weight: self.style_weight,
            content_weight: self.content_weight,
            monitor_every: self.monitor_every,
            no_monitor: self.no_monitor,
            save_at: self.save_at.clone(),
            budget_s: budget(self)?,
            stylizer: self.stylizer.clone(),
        })
    }
}

/// The budget from `--budget-s` or `--budget-from` (finite, > 0).
fn budget(a: &Args) -> Result<Option<f64>> {
    let b = match (&a.budget_s, &a.budget_from) {
        (Some(b), _) => Some(*b),
        (None, Some(p)) => Some(read_budget(p)?),
        (None, None) => None,
    };
    match b {
        Some(v) if !(v.is_finite() && v > 0.0) => Err(Error::param(format!(
            "the time budget must be a positive number of seconds, got {v}"
        ))),
        b => Ok(b),
    }
}

/// `budget_s` of a JSON object in `p`.
fn read_budget(p: &Path) -> Result<f64> {
    let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::input(p, format!("not JSON: {e}")))?;
    v.get("budget_s")
        .and_then(|x| x.as_f64())
        .ok_or_else(|| Error::input(p, "no number `budget_s` in this JSON object"))
}

/// The stage: load, run the baseline ([`crate::baselines::run`]), write the artifact.
pub fn run(a: Args) -> Result<()> {
    let t0 = Instant::now();
    let p = a.params()?;
    if a.width < 16 || a.height < 16 {
        return Err(Error::param(format!(
            "image size {}x{}: the baselines need at least 16x16",
            a.width, a.height
        )));
    }
    let scene = a.input.load_scene()?;
    let cams = a.input.load_cameras(&scene, a.width, a.height)?;
    if cams.is_empty() {
        return Err(Error::param(format!(
            "{}: the view set is empty: nothing to stylize",
            a.input.cameras
        )));
    }
    let (style, vgg) = style_and_vgg(&a)?;
    let mut w = super::create_artifact(&a.out, ArtifactKind::Scene, producer(&a, &p))?;
    a.input.add_inputs(&mut w)?;
    w.add_input("style", &a.style)?;
    tracing::info!(
        "{:?} baseline: {} Gaussians, {} views at {}x{}, {} steps",
        a.method,
        scene.len(),
        cams.len(),
        a.width,
        a.height,
        a.steps
    );
    let out = a
        .threads
        .install(|| method(&a, &p, scene, &cams, vgg.as_ref(), &style, t0))??;
    write(&a, &p, w, out, cams.len())
}

/// The style image as the method takes it, and VGG16 for the methods with steps.
fn style_and_vgg(a: &Args) -> Result<(Image, Option<Vgg16>)> {
    let raw_style = crate::imageio::read_rgb(&a.style)?;
    if a.method == Method::ColourTransfer {
        return Ok((raw_style, None));
    }
    let style = prepare_style(&raw_style, a.style_size, &a.style)?;
    if a.method == Method::Project {
        return Ok((style, None));
    }
    let vgg_dir = match &a.vgg {
        Some(p) => p.clone(),
        None => crate::models::model_path("lpips/vgg16")?,
    };
    Ok((
        style,
        Some(super::fast_vgg(Vgg16::load(&vgg_dir)?, a.threads)?),
    ))
}

/// Run the method.
fn method(
    a: &Args,
    p: &RunParams,
    scene: Scene,
    cams: &[crate::Camera],
    vgg: Option<&Vgg16>,
    style: &Image,
    t0: Instant,
) -> Result<Outcome> {
    use crate::baselines::run::{optimise, project, transfer_colours};
    match (a.method, vgg) {
        (Method::ColourTransfer, _) => transfer_colours(scene, cams, style, p.background, t0),
        (Method::Project, _) => project(scene, cams, style, &a.input.cameras, t0),
        (_, Some(vgg)) => optimise(p, scene, cams, vgg, style, t0),
        (_, None) => Err(Error::Other("a method with steps needs VGG16".into())),
    }
}

/// The producer: the stage and its flags (those used only when used, so artifacts of
/// runs without them keep their hashes).
fn producer(a: &Args, p: &RunParams) -> Producer {
    let mut params = serde_json::json!({
        "method": a.method, "cameras": a.input.cameras, "steps": a.steps, "width": a.width,
        "height": a.height, "background": a.background.rgb, "lr_dc": a.lr_dc,
        "lr_rest": a.lr_rest, "style_size": a.style_size, "style_weight": a.style_weight,
        "content_weight": a.content_weight, "monitor_every": a.monitor_every,
    });
    let sampled = a.views_per_step > 0;
    let extra = [
        (
            "views_per_step",
            serde_json::json!(a.views_per_step),
            sampled,
        ),
        ("seed", serde_json::json!(a.seed), sampled),
        (
            "budget_s",
            serde_json::json!(p.budget_s),
            p.budget_s.is_some(),
        ),
        (
            "save_at",
            serde_json::json!(a.save_at),
            !a.save_at.is_empty(),
        ),
        ("no_monitor", serde_json::json!(true), a.no_monitor),
    ];
    for (k, v, used) in extra {
        if used {
            params[k] = v;
        }
    }
    Producer::new("stylize-baseline", crate::VERSION, params)
}

/// Write what the method produced into the artifact `w` and commit it.
fn write(
    a: &Args,
    p: &RunParams,
    mut w: fantasystyle_schemas::ArtifactWriter,
    out: Outcome,
    views: usize,
) -> Result<()> {
    let Outcome {
        scene,
        log,
        targets,
        checkpoints,
        mut timing,
    } = out;
    w.write_bytes("scene.ply", &crate::scene::ply::encode_ply(&scene))?;
    w.write_json("loss.json", &log)?;
    for (i, t) in targets.iter().enumerate() {
        w.write_bytes(
            &format!("target_{i:03}.png"),
            &crate::imageio::encode_png_rgb(&t.data, t.width, t.height)?,
        )?;
    }
    for c in &checkpoints {
        w.write_bytes(&checkpoint_name(c.step), &c.ply)?;
    }
    if p.budget_s.is_some() || a.record_time {
        timing.budget_s = p.budget_s;
        w.write_json("timing.json", &timing)?;
        tracing::info!(
            "{} steps in {:.1} s (budget {:?} s)",
            timing.steps_done,
            timing.wall_s,
            p.budget_s
        );
    }
    let first = log.steps.first().and_then(|s| s.gram_distance);
    let last = log.steps.last().and_then(|s| s.gram_distance);
    w.set_meta(serde_json::json!({
        "method": a.method, "views": views, "gram_distance_first": first,
        "gram_distance_last": last,
    }));
    crate::timing::io(|| w.commit())?;
    tracing::info!(
        "wrote {} (Gram distance {:?} -> {:?})",
        a.out.display(),
        first,
        last
    );
    Ok(())
}
