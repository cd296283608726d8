//! A baseline run, start to end: the method's objective, the monitor, the colour fit
//! under a step count, a time budget and checkpoints ([`optimise`]), or the methods without
//! steps ([`transfer_colours`], [`project`]); what it produced ([`Outcome`]) for the
//! `stylize-baseline` stage to write.
//!
//! * `gram`, `nnfm`: the VGG objectives ([`mod@super::gram`], [`mod@super::nnfm`]) against the
//!   original renders (content) and the style;
//! * `refit`: each original view stylized by the 2D stylizer on its own, then the colours
//!   fitted to those images (L1 + D-SSIM); the stylizations' high-frequency agreement
//!   between neighbouring views is measured ([`crate::metrics::agreement`]);
//! * `colour-transfer`, `project`: the method's colour start and projected start alone
//!   ([`crate::transfer::colour`], [`crate::transfer::projection`]).

use super::fit::{FitOptions, StepLog, fit_objective};
use super::gram::{GramConfig, GramObjective, GramTargets};
use super::nnfm::{NnfmConfig, NnfmObjective};
use super::{Objective, gram_distance};
use crate::imageio::Image;
use crate::render::RenderOutput;
use crate::vgg::Vgg16;
use crate::{Camera, Error, Result, Scene};
use std::path::PathBuf;
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

/// How a run goes: the method and the colour fit's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct RunParams {
    pub method: Method,
    /// Most steps.
    pub steps: usize,
    /// Views per step (0: every view).
    pub views_per_step: usize,
    /// Seed of the view draws.
    pub seed: u64,
    pub lr_dc: f32,
    pub lr_rest: f32,
    pub background: [f32; 3],
    pub style_weight: f64,
    /// The method's own content weight when `None`.
    pub content_weight: Option<f64>,
    /// Evaluate the Gram-distance monitor every this many steps (and at the ends).
    pub monitor_every: usize,
    /// No monitor at all.
    pub no_monitor: bool,
    /// Also keep the scene after these step counts.
    pub save_at: Vec<usize>,
    /// Stop after the step during which the wall time since the start reaches this.
    pub budget_s: Option<f64>,
    /// The stylizer model of `refit` (`None`: the models directory's).
    pub stylizer: Option<PathBuf>,
}

/// What a run produced (`loss.json`; also used by tests).
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
    pub steps: Vec<StepLog>,
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
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub step: usize,
    pub elapsed_s: f64,
    /// The scene as `.ply` bytes.
    pub ply: Vec<u8>,
}

/// The file name of the scene after `step` steps.
pub fn checkpoint_name(step: usize) -> String {
    format!("scene_step{step}.ply")
}

/// What a method produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub scene: Scene,
    pub log: LossLog,
    /// `refit`: the stylized views it fitted.
    pub targets: Vec<Image>,
    pub checkpoints: Vec<Checkpoint>,
    pub timing: TimingLog,
}

impl Outcome {
    /// The outcome of a method without steps (colour transfer, projection): its scene and
    /// log, no targets or checkpoints, the wall time since `t0` all set-up.
    fn without_steps(
        method: Method,
        scene: Scene,
        colour_map: Option<ColourMapLog>,
        t0: Instant,
    ) -> Outcome {
        let wall = t0.elapsed().as_secs_f64();
        Outcome {
            scene,
            log: LossLog {
                method,
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

/// `colour-transfer`: the statistics of the object in the original renders (over
/// `background`), the map onto the style image's, applied to the SH colours.
pub fn transfer_colours(
    scene: Scene,
    cams: &[Camera],
    style: &Image,
    background: [f32; 3],
    t0: Instant,
) -> Result<Outcome> {
    let renders = crate::render::render_all(&scene, cams, background)?;
    let views: Vec<(&[f32], &[f32])> = renders.iter().map(|r| (&r.rgb[..], &r.alpha[..])).collect();
    let (out, tr) = crate::transfer::colour::transfer_scene(&scene, &views, background, style)?;
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
    Ok(Outcome::without_steps(
        Method::ColourTransfer,
        out,
        Some(map),
        t0,
    ))
}

/// `project`: the style texture-mapped onto the object ([`crate::transfer::projection`]);
/// a placement error is about the cameras, named by `cameras_from`.
pub fn project(
    scene: Scene,
    cams: &[Camera],
    style: &Image,
    cameras_from: &str,
    t0: Instant,
) -> Result<Outcome> {
    use crate::transfer::projection::{Placement, project_style, rendered_normals};
    let at = Placement::of(&scene, cams).map_err(|e| Error::input(cameras_from, e.to_string()))?;
    tracing::info!(
        "style projection: {:.3e} world units per style px, centre {:.3?}",
        at.world_per_pixel,
        at.centre
    );
    let normals = rendered_normals(&scene, cams)?;
    tracing::info!("style projection: {normals}");
    let out = project_style(&scene, style, &at, &normals.normals);
    Ok(Outcome::without_steps(Method::Project, out, None, t0))
}

/// What the method fits before the loop: its objective (none for `refit`), the targets
/// (the stylized views for `refit`, else the original renders) and `refit`'s measures.
struct Prepared<'a> {
    objective: Option<Box<dyn Objective + 'a>>,
    /// `refit`: the stylized views.
    stylized: Vec<Image>,
    targets_gram: Option<f64>,
    hf_agree: Option<f64>,
    hf_agree_orig: Option<f64>,
}

/// The objective of `p.method` against `style` and the `originals`.
fn objective<'a>(
    p: &RunParams,
    vgg: &'a Vgg16,
    style: &Image,
    originals: &[Image],
) -> Result<Option<Box<dyn Objective + 'a>>> {
    let gram_cfg = GramConfig::default();
    Ok(match p.method {
        Method::ColourTransfer | Method::Project | Method::Refit => None,
        Method::Gram => Some(Box::new(GramObjective::new(
            vgg,
            GramConfig {
                style_weight: p.style_weight,
                content_weight: p.content_weight.unwrap_or(gram_cfg.content_weight),
                ..gram_cfg.clone()
            },
            style,
            originals,
        )?)),
        Method::Nnfm => {
            let d = NnfmConfig::default();
            Some(Box::new(NnfmObjective::new(
                vgg,
                NnfmConfig {
                    style_weight: p.style_weight,
                    content_weight: p.content_weight.unwrap_or(d.content_weight),
                },
                style,
                originals,
            )?))
        }
    })
}

/// `refit`'s targets, the stylized views, with their Gram distance (`monitor`, unless
/// `no_monitor`) and the high-frequency agreement of their change between neighbouring
/// views and of the originals' own high pass.
fn refit_targets(
    p: &RunParams,
    style: &Image,
    originals: &[Image],
    renders: &[RenderOutput],
    cams: &[Camera],
    monitor: &dyn Fn(&[Image]) -> Result<f64>,
) -> Result<Prepared<'static>> {
    let dir = match &p.stylizer {
        Some(d) => d.clone(),
        None => crate::models::model_path("stylizer")?,
    };
    let stylized = stylize_views(&dir, style, originals)?;
    let mut targets_gram = None;
    if !p.no_monitor {
        let d = monitor(&stylized)?;
        tracing::info!("refit targets: Gram distance to the style {d:.4}");
        targets_gram = Some(d);
    }
    let changes: Vec<_> = stylized
        .iter()
        .zip(originals)
        .map(|(t, o)| t.to_chw() - o.to_chw())
        .collect();
    let alpha: Vec<Vec<f32>> = renders.iter().map(|r| r.alpha.clone()).collect();
    let depth: Vec<Vec<f32>> = renders.iter().map(|r| r.depth.clone()).collect();
    let closed = crate::camera::path::ViewPath::of(cams).closed;
    use crate::metrics::agreement::adjacent_agreement_of_views as agree;
    let hf_agree = agree(cams, &changes, &alpha, &depth, closed);
    let own: Vec<_> = originals.iter().map(Image::to_chw).collect();
    let hf_agree_orig = agree(cams, &own, &alpha, &depth, closed);
    tracing::info!(
        "refit targets: high-frequency change agreement between neighbouring views {} \
         (the original renders' own high pass: {})",
        crate::metrics::html::fmt_opt(hf_agree, 3),
        crate::metrics::html::fmt_opt(hf_agree_orig, 3)
    );
    Ok(Prepared {
        objective: None,
        stylized,
        targets_gram,
        hf_agree,
        hf_agree_orig,
    })
}

/// A method with steps (`gram`, `nnfm`, `refit`): render the originals, build the
/// objective (or `refit`'s targets) and the Gram-distance monitor, and run the fit from
/// `t0` under the step count, the budget and the checkpoints.
pub fn optimise(
    p: &RunParams,
    scene: Scene,
    cams: &[Camera],
    vgg: &Vgg16,
    style: &Image,
    t0: Instant,
) -> Result<Outcome> {
    if matches!(p.method, Method::ColourTransfer | Method::Project) {
        return Err(Error::Other(format!(
            "{:?} has no objective to optimise",
            p.method
        )));
    }
    let renders = crate::render::render_all(&scene, cams, p.background)?;
    let originals: Vec<Image> = renders
        .iter()
        .map(|r| Image {
            width: r.width,
            height: r.height,
            data: r.rgb.clone(),
        })
        .collect();
    super::check_views(&originals)?;
    let monitor_targets = GramTargets::new(vgg, style, &GramConfig::default().layers, &[1])?;
    let monitor = |imgs: &[Image]| -> Result<f64> {
        let mut s = 0.0;
        for i in imgs {
            s += gram_distance(vgg, &monitor_targets, i)?;
        }
        Ok(s / imgs.len() as f64)
    };
    let prepared = if p.method == Method::Refit {
        refit_targets(p, style, &originals, &renders, cams, &monitor)?
    } else {
        Prepared {
            objective: objective(p, vgg, style, &originals)?,
            stylized: Vec::new(),
            targets_gram: None,
            hf_agree: None,
            hf_agree_orig: None,
        }
    };
    fit(p, scene, cams, &originals, prepared, &monitor, t0)
}

/// The colour fit's options from the run's parameters.
fn fit_options(p: &RunParams) -> FitOptions {
    FitOptions {
        steps: p.steps,
        fit: crate::optim::FitParams {
            lr_dc: p.lr_dc,
            lr_rest: p.lr_rest,
            background: p.background,
            ..crate::optim::FitParams::default()
        },
        monitor_every: p.monitor_every,
        views_per_step: (p.views_per_step > 0).then_some(p.views_per_step),
        seed: p.seed,
    }
}

/// The fit's progress bar over `steps` steps.
fn progress_bar(steps: usize) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("stylize-baseline");
    bar
}

/// The fit of a prepared method, with a progress bar, the checkpoints of `p.save_at` and
/// the budget; its outcome.
fn fit(
    p: &RunParams,
    scene: Scene,
    cams: &[Camera],
    originals: &[Image],
    prepared: Prepared<'_>,
    monitor: &dyn Fn(&[Image]) -> Result<f64>,
    t0: Instant,
) -> Result<Outcome> {
    let fit_targets: Vec<Vec<f32>> = if prepared.stylized.is_empty() {
        originals.iter().map(|i| i.data.clone()).collect()
    } else {
        prepared.stylized.iter().map(|i| i.data.clone()).collect()
    };
    let opts = fit_options(p);
    let setup_s = t0.elapsed().as_secs_f64();
    let bar = progress_bar(p.steps);
    let mut checkpoints = Vec::new();
    let (mut steps_done, mut wall_s) = (0, setup_s);
    let (scene, steps) = fit_objective(
        &scene,
        cams,
        &fit_targets,
        prepared.objective.as_deref(),
        &opts,
        (!p.no_monitor).then_some(monitor),
        &mut |s, sc| {
            bar.set_position(s as u64);
            steps_done = s;
            wall_s = t0.elapsed().as_secs_f64();
            if p.save_at.contains(&s) {
                checkpoints.push(Checkpoint {
                    step: s,
                    elapsed_s: wall_s,
                    ply: crate::scene::ply::encode_ply(sc),
                });
            }
            Ok(p.budget_s.is_none_or(|b| wall_s < b))
        },
    )?;
    bar.finish_and_clear();
    let timing = TimingLog {
        budget_s: p.budget_s,
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
    let log = LossLog {
        method: p.method,
        targets_gram_distance: prepared.targets_gram,
        hf_agree_adjacent: prepared.hf_agree,
        hf_agree_adjacent_original: prepared.hf_agree_orig,
        steps,
        colour_map: None,
    };
    Ok(Outcome {
        scene,
        log,
        targets: prepared.stylized,
        checkpoints,
        timing,
    })
}
