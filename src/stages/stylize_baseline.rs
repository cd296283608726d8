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
//!   ([`crate::distill::colour_transfer`]); no steps;
//! * `project`: the style image (at `--style-size`) texture-mapped onto the object by
//!   triplanar projection along each Gaussian's normal, one style pixel per render pixel
//!   at the object ([`crate::distill::projection`]); no steps.
//!
//! Output (schema `scene` v1): `scene.ply` (geometry bit-identical to the input, colours
//! changed), `loss.json` (`method`, and per step the objective, its style and content
//! terms, and every `--monitor-every` steps the Gram distance to the style, mean over
//! views: relu1_2..relu4_3, scale 1; for `colour-transfer` the map and both statistics),
//! for `refit` also `target_000.png`.. (the stylized views it fitted), with `--save-at`
//! also `scene_step10.ply`.. (the scene after those steps); for `refit` also
//! `hf_agree_adjacent` in `loss.json`: how much of the per-view 2D stylizations'
//! high-frequency change agrees between path neighbours after depth reprojection
//! ([`crate::distill::agreement::adjacent_agreement_of_views`]), the ceiling of the
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
use crate::baselines::fit::{FitOptions, fit_objective};
use crate::baselines::gram::{GramConfig, GramObjective, GramTargets};
use crate::baselines::nnfm::{NnfmConfig, NnfmObjective};
use crate::baselines::{Objective, gram_distance};
use crate::imageio::Image;
use crate::vgg::Vgg16;
use crate::vgg::prepare_style;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which baseline to run.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Gram-matrix style loss (Gatys; SGSST-like), relu1_2..relu4_3 at 1x and 0.5x.
    Gram,
    /// Nearest-neighbour feature matching (ARF), relu3 block, cosine distance.
    Nnfm,
    /// Per-view 2D stylization with the stylizer, then a colour refit to those images.
    Refit,
    /// The object's colour mean and covariance moved onto the style image's (linear
    /// Monge-Kantorovich map on the SH colours; no steps).
    ColourTransfer,
    /// The style image texture-mapped onto the object (triplanar projection along each
    /// Gaussian's normal, shaded by its relative brightness; no steps).
    Project,
}

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

/// What a run produced (also used by tests).
#[derive(Debug, Clone, serde::Serialize)]
pub struct LossLog {
    pub method: Method,
    /// `refit` only: the Gram distance of the stylized target views (mean over views).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub targets_gram_distance: Option<f64>,
    /// `refit` only: agreement of the stylizations' high-pass change between neighbouring
    /// views after depth reprojection (module docs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hf_agree_adjacent: Option<f64>,
    /// `refit` only: the same measure on the original renders' own high pass (the scene's
    /// texture, consistent by construction): how much agreement the warp allows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hf_agree_adjacent_original: Option<f64>,
    pub steps: Vec<crate::baselines::fit::StepLog>,
    /// `colour-transfer` only: the map and the statistics it matched.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colour_map: Option<ColourMapLog>,
}

/// What `colour-transfer` did (`loss.json`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ColourMapLog {
    /// `c' = T c + b`, T row-major.
    pub t: [f64; 9],
    pub b: [f64; 3],
    pub source_mean: [f64; 3],
    pub source_cov: [f64; 9],
    pub style_mean: [f64; 3],
    pub style_cov: [f64; 9],
}

/// `timing.json`: when a run's steps ended (only with a budget or --record-time).
#[derive(Debug, Clone, serde::Serialize)]
pub struct TimingLog {
    pub budget_s: Option<f64>,
    /// Seconds from the stage's start to the end of the last step (before writing).
    pub wall_s: f64,
    pub steps_done: usize,
    /// Seconds from the stage's start to the end of the originals' rendering (and, for
    /// refit, the 2D stylization): the fixed cost before the first step.
    pub setup_s: f64,
    pub checkpoints: Vec<CheckpointTime>,
}

/// A saved intermediate scene.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CheckpointTime {
    pub step: usize,
    pub elapsed_s: f64,
    pub file: String,
}

/// The scene after some steps, kept until the artifact is written.
struct Checkpoint {
    step: usize,
    elapsed_s: f64,
    ply: Vec<u8>,
}

fn checkpoint_name(step: usize) -> String {
    format!("scene_step{step}.ply")
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

/// Stylize every view on its own with the 2D stylizer (the refit baseline's targets).
fn stylize_views(dir: &std::path::Path, style: &Image, views: &[Image]) -> Result<Vec<Image>> {
    if !dir.join("model.json").is_file() {
        return Err(Error::Missing(format!(
            "{}: stylizer model is absent (run scripts/setup.sh, step 20_stylizer.py)",
            dir.display()
        )));
    }
    let mut p = crate::prior::stylizer::StylizerPrior::open(dir, None, 0)?;
    let s = p.style_vector(style.to_chw().view())?;
    views
        .iter()
        .map(|v| {
            let mut out = Image::from_chw(p.stylize(v.to_chw().view(), &s)?.view());
            out.data.iter_mut().for_each(|x| *x = x.clamp(0.0, 1.0));
            Ok(out)
        })
        .collect()
}

/// The stage: load, optimise, write the artifact.
pub fn run(a: Args) -> Result<()> {
    let t0 = Instant::now();
    let budget_s = budget(&a)?;
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
    let raw_style = crate::imageio::read_rgb(&a.style)?;
    let transfer = a.method == Method::ColourTransfer;
    let no_steps = transfer || a.method == Method::Project;
    let style = if transfer {
        raw_style
    } else {
        prepare_style(&raw_style, a.style_size, &a.style)?
    };
    let vgg = if no_steps {
        None
    } else {
        let vgg_dir = match &a.vgg {
            Some(p) => p.clone(),
            None => crate::models::model_path("lpips/vgg16")?,
        };
        Some(super::fast_vgg(Vgg16::load(&vgg_dir)?, a.threads)?)
    };
    let mut params = serde_json::json!({
        "method": a.method, "cameras": a.input.cameras, "steps": a.steps, "width": a.width,
        "height": a.height, "background": a.background.rgb, "lr_dc": a.lr_dc,
        "lr_rest": a.lr_rest, "style_size": a.style_size, "style_weight": a.style_weight,
        "content_weight": a.content_weight, "monitor_every": a.monitor_every,
    });
    // Recorded only when used, so artifacts of runs without them keep their hashes.
    let extra = [
        (
            "views_per_step",
            serde_json::json!(a.views_per_step),
            a.views_per_step > 0,
        ),
        ("seed", serde_json::json!(a.seed), a.views_per_step > 0),
        ("budget_s", serde_json::json!(budget_s), budget_s.is_some()),
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
    let producer = Producer::new("stylize-baseline", crate::VERSION, params);
    let mut w = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
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
    let out = a.threads.install(|| match &vgg {
        Some(vgg) => optimise(&a, scene, &cams, vgg, &style, t0, budget_s),
        None if transfer => transfer_colours(&a, scene, &cams, &style, t0),
        None => project(&a, scene, &cams, &style, t0),
    })??;
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
    if budget_s.is_some() || a.record_time {
        timing.budget_s = budget_s;
        w.write_json("timing.json", &timing)?;
        tracing::info!(
            "{} steps in {:.1} s (budget {:?} s)",
            timing.steps_done,
            timing.wall_s,
            budget_s
        );
    }
    let first = log.steps.first().and_then(|s| s.gram_distance);
    let last = log.steps.last().and_then(|s| s.gram_distance);
    w.set_meta(serde_json::json!({
        "method": a.method, "views": cams.len(), "gram_distance_first": first,
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

/// What a method produced.
struct Outcome {
    scene: crate::Scene,
    log: LossLog,
    targets: Vec<Image>,
    checkpoints: Vec<Checkpoint>,
    timing: TimingLog,
}

impl Outcome {
    /// The outcome of a method without steps (colour transfer, projection): its scene and
    /// log, no targets or checkpoints, the wall time since `t0` all set-up.
    fn without_steps(
        a: &Args,
        scene: crate::Scene,
        colour_map: Option<ColourMapLog>,
        t0: Instant,
    ) -> Outcome {
        let wall = t0.elapsed().as_secs_f64();
        Outcome {
            scene,
            log: LossLog {
                method: a.method,
                targets_gram_distance: None,
                hf_agree_adjacent: None,
                hf_agree_adjacent_original: None,
                steps: Vec::new(),
                colour_map,
            },
            targets: Vec::new(),
            checkpoints: Vec::new(),
            timing: TimingLog {
                budget_s: None,
                wall_s: wall,
                steps_done: 0,
                setup_s: wall,
                checkpoints: Vec::new(),
            },
        }
    }
}

/// The original renders (rgb, alpha) of every camera.
fn render_originals(
    a: &Args,
    scene: &crate::Scene,
    cams: &[crate::Camera],
) -> Result<Vec<crate::render::RenderOutput>> {
    crate::render::render_all(scene, cams, a.background.rgb)
}

/// `colour-transfer`: the statistics of the object in the original renders, the map onto
/// the style image's, applied to the SH colours.
fn transfer_colours(
    a: &Args,
    scene: crate::Scene,
    cams: &[crate::Camera],
    style: &Image,
    t0: Instant,
) -> Result<Outcome> {
    let renders = render_originals(a, &scene, cams)?;
    let views: Vec<(&[f32], &[f32])> = renders.iter().map(|r| (&r.rgb[..], &r.alpha[..])).collect();
    let (out, tr) =
        crate::distill::colour_transfer::transfer_scene(&scene, &views, a.background.rgb, style)?;
    let (src, dst) = (tr.source, tr.style);
    tracing::info!(
        "colour transfer: object mean {:.3?} -> style mean {:.3?}",
        src.mean,
        dst.mean
    );
    let map = ColourMapLog {
        t: tr.t,
        b: tr.b,
        source_mean: src.mean,
        source_cov: src.cov,
        style_mean: dst.mean,
        style_cov: dst.cov,
    };
    Ok(Outcome::without_steps(a, out, Some(map), t0))
}

/// `project`: the style texture-mapped onto the object ([`crate::distill::projection`]).
fn project(
    a: &Args,
    scene: crate::Scene,
    cams: &[crate::Camera],
    style: &Image,
    t0: Instant,
) -> Result<Outcome> {
    use crate::distill::projection::{Placement, project_style, rendered_normals};
    let at =
        Placement::of(&scene, cams).map_err(|e| Error::input(&a.input.cameras, e.to_string()))?;
    tracing::info!(
        "style projection: {:.3e} world units per style px, centre {:.3?}",
        at.world_per_pixel,
        at.centre
    );
    let normals = rendered_normals(&scene, cams)?;
    tracing::info!("style projection: {normals}");
    let out = project_style(&scene, style, &at, &normals.normals);
    Ok(Outcome::without_steps(a, out, None, t0))
}

/// Render the originals, build the objective and the monitor, and run the fit.
fn optimise(
    a: &Args,
    scene: crate::Scene,
    cams: &[crate::Camera],
    vgg: &Vgg16,
    style: &Image,
    t0: Instant,
    budget_s: Option<f64>,
) -> Result<Outcome> {
    let renders = render_originals(a, &scene, cams)?;
    let originals: Vec<Image> = renders
        .iter()
        .map(|r| Image {
            width: r.width,
            height: r.height,
            data: r.rgb.clone(),
        })
        .collect();
    crate::baselines::check_views(&originals)?;
    let gram_cfg = GramConfig::default();
    let monitor_targets = GramTargets::new(vgg, style, &gram_cfg.layers, &[1])?;
    let monitor = |imgs: &[Image]| -> Result<f64> {
        let mut s = 0.0;
        for i in imgs {
            s += gram_distance(vgg, &monitor_targets, i)?;
        }
        Ok(s / imgs.len() as f64)
    };
    let mut targets = Vec::new();
    let mut targets_gram = None;
    let (mut hf_agree, mut hf_agree_orig) = (None, None);
    let obj: Option<Box<dyn Objective + '_>> = match a.method {
        Method::ColourTransfer | Method::Project => {
            return Err(Error::Other(format!(
                "{:?} has no objective to optimise",
                a.method
            )));
        }
        Method::Gram => Some(Box::new(GramObjective::new(
            vgg,
            GramConfig {
                style_weight: a.style_weight,
                content_weight: a.content_weight.unwrap_or(gram_cfg.content_weight),
                ..gram_cfg.clone()
            },
            style,
            &originals,
        )?)),
        Method::Nnfm => {
            let d = NnfmConfig::default();
            Some(Box::new(NnfmObjective::new(
                vgg,
                NnfmConfig {
                    style_weight: a.style_weight,
                    content_weight: a.content_weight.unwrap_or(d.content_weight),
                },
                style,
                &originals,
            )?))
        }
        Method::Refit => {
            let dir = match &a.stylizer {
                Some(p) => p.clone(),
                None => crate::models::model_path("stylizer")?,
            };
            targets = stylize_views(&dir, style, &originals)?;
            if !a.no_monitor {
                let d = monitor(&targets)?;
                tracing::info!("refit targets: Gram distance to the style {d:.4}");
                targets_gram = Some(d);
            }
            let changes: Vec<_> = targets
                .iter()
                .zip(&originals)
                .map(|(t, o)| t.to_chw() - o.to_chw())
                .collect();
            let alpha: Vec<Vec<f32>> = renders.iter().map(|r| r.alpha.clone()).collect();
            let depth: Vec<Vec<f32>> = renders.iter().map(|r| r.depth.clone()).collect();
            let closed = crate::distill::path::ViewPath::of(cams).closed;
            use crate::distill::agreement::adjacent_agreement_of_views as agree;
            hf_agree = agree(cams, &changes, &alpha, &depth, closed);
            let own: Vec<_> = originals.iter().map(Image::to_chw).collect();
            hf_agree_orig = agree(cams, &own, &alpha, &depth, closed);
            tracing::info!(
                "refit targets: high-frequency change agreement between neighbouring views {} \
                 (the original renders' own high pass: {})",
                crate::metrics::html::fmt_opt(hf_agree, 3),
                crate::metrics::html::fmt_opt(hf_agree_orig, 3)
            );
            None
        }
    };
    let fit_targets: Vec<Vec<f32>> = if targets.is_empty() {
        originals.iter().map(|i| i.data.clone()).collect()
    } else {
        targets.iter().map(|i| i.data.clone()).collect()
    };
    let opts = FitOptions {
        steps: a.steps,
        fit: crate::optim::FitParams {
            lr_dc: a.lr_dc,
            lr_rest: a.lr_rest,
            background: a.background.rgb,
            ..crate::optim::FitParams::default()
        },
        monitor_every: a.monitor_every,
        views_per_step: (a.views_per_step > 0).then_some(a.views_per_step),
        seed: a.seed,
    };
    let setup_s = t0.elapsed().as_secs_f64();
    let bar = indicatif::ProgressBar::new(a.steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("stylize-baseline");
    let mut checkpoints = Vec::new();
    let mut steps_done = 0;
    let mut wall_s = setup_s;
    let (scene, steps) = fit_objective(
        &scene,
        cams,
        &fit_targets,
        obj.as_deref(),
        &opts,
        (!a.no_monitor).then_some(&monitor as &dyn Fn(&[Image]) -> Result<f64>),
        &mut |s, sc| {
            bar.set_position(s as u64);
            steps_done = s;
            wall_s = t0.elapsed().as_secs_f64();
            if a.save_at.contains(&s) {
                checkpoints.push(Checkpoint {
                    step: s,
                    elapsed_s: wall_s,
                    ply: crate::scene::ply::encode_ply(sc),
                });
            }
            Ok(budget_s.is_none_or(|b| wall_s < b))
        },
    )?;
    bar.finish_and_clear();
    let timing = TimingLog {
        budget_s,
        wall_s,
        steps_done,
        setup_s,
        checkpoints: checkpoints
            .iter()
            .map(|c| CheckpointTime {
                step: c.step,
                elapsed_s: c.elapsed_s,
                file: checkpoint_name(c.step),
            })
            .collect(),
    };
    Ok(Outcome {
        scene,
        log: LossLog {
            method: a.method,
            targets_gram_distance: targets_gram,
            hf_agree_adjacent: hf_agree,
            hf_agree_adjacent_original: hf_agree_orig,
            steps,
            colour_map: None,
        },
        targets,
        checkpoints,
        timing,
    })
}
