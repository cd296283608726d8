//! `stylize-baseline`: restyle a scene's colours with one of the baselines FantasyStyle is
//! compared against ([`crate::baselines`]), writing a `scene` artifact like
//! `update-gaussians` does, so the same `render-views` + `evaluate` steps follow.
//!
//! * `gram`: Gram-matrix style loss over VGG16 layers and two scales + content loss;
//! * `nnfm`: ARF's nearest-neighbour feature matching on the relu3 block + content loss;
//! * `refit`: stylize each original view with the 2D stylizer on its own, then fit colours
//!   to those images (`fit_colours`' L1 + D-SSIM), no MVFC, no distillation.
//!
//! Output (schema `scene` v1): `scene.ply` (geometry bit-identical to the input, colours
//! changed), `loss.json` (`method`, and per step the objective, its style and content
//! terms, and every `--monitor-every` steps the Gram distance to the style, mean over
//! views: relu1_2..relu4_3, scale 1), for `refit` also `target_000.png`.. (the stylized
//! views it fitted) and `hf_agree_adjacent` in `loss.json`: how much of the per-view 2D
//! stylizations' high-frequency change agrees between path neighbours after depth
//! reprojection ([`crate::distill::agreement::adjacent_agreement_of_views`]), the ceiling
//! of the distillation's per-iteration measure (and `hf_agree_adjacent_original`, the same
//! measure on the original renders' own high pass: what the warp allows). Style image handling: grayscale expanded to RGB, alpha dropped,
//! shorter side at least 92 px (relu4_3's receptive field), resized to `--style-size`.

use super::{Background, SceneInput, Threads};
use crate::baselines::fit::{FitOptions, fit_objective};
use crate::baselines::gram::{GramConfig, GramObjective, GramTargets};
use crate::baselines::nnfm::{NnfmConfig, NnfmObjective};
use crate::baselines::{Objective, gram_distance, prepare_style};
use crate::imageio::Image;
use crate::vgg::Vgg16;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Which baseline to run.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Gram-matrix style loss (Gatys; SGSST-like), relu1_2..relu4_3 at 1x and 0.5x.
    Gram,
    /// Nearest-neighbour feature matching (ARF), relu3 block, cosine distance.
    Nnfm,
    /// Per-view 2D stylization with the stylizer, then a colour refit to those images.
    Refit,
}

/// Restyle a scene's colours with a baseline (VGG Gram, VGG NNFM, or per-view 2D
/// stylize + refit); geometry stays frozen. Writes a scene artifact (scene.ply, loss.json).
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
    /// Optimisation steps (each: every view rendered, one Adam step).
    #[arg(long)]
    pub steps: usize,
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
    let style = prepare_style(&raw_style, a.style_size, &a.style)?;
    let vgg_dir = match &a.vgg {
        Some(p) => p.clone(),
        None => crate::models::model_path("lpips/vgg16")?,
    };
    let vgg = Vgg16::load(&vgg_dir)?;
    let params = serde_json::json!({
        "method": a.method, "cameras": a.input.cameras, "steps": a.steps, "width": a.width,
        "height": a.height, "background": a.background.rgb, "lr_dc": a.lr_dc,
        "lr_rest": a.lr_rest, "style_size": a.style_size, "style_weight": a.style_weight,
        "content_weight": a.content_weight, "monitor_every": a.monitor_every,
    });
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
    let (scene, log, targets) = a
        .threads
        .install(|| optimise(&a, scene, &cams, &vgg, &style))??;
    w.write_bytes("scene.ply", &crate::scene::ply::encode_ply(&scene))?;
    w.write_json("loss.json", &log)?;
    for (i, t) in targets.iter().enumerate() {
        w.write_bytes(
            &format!("target_{i:03}.png"),
            &crate::imageio::encode_png_rgb(&t.data, t.width, t.height)?,
        )?;
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

/// Render the originals, build the objective and the monitor, and run the fit.
fn optimise(
    a: &Args,
    scene: crate::Scene,
    cams: &[crate::Camera],
    vgg: &Vgg16,
    style: &Image,
) -> Result<(crate::Scene, LossLog, Vec<Image>)> {
    let ropts = crate::render::RenderOptions {
        background: a.background.rgb,
    };
    let renders = cams
        .iter()
        .map(|c| crate::render::render(&scene, c, &ropts))
        .collect::<Result<Vec<_>>>()?;
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
            let d = monitor(&targets)?;
            tracing::info!("refit targets: Gram distance to the style {d:.4}");
            targets_gram = Some(d);
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
                crate::metrics::report::fmt_opt(hf_agree, 3),
                crate::metrics::report::fmt_opt(hf_agree_orig, 3)
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
    };
    let bar = indicatif::ProgressBar::new(a.steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("stylize-baseline");
    let (scene, steps) = fit_objective(
        &scene,
        cams,
        &fit_targets,
        obj.as_deref(),
        &opts,
        Some(&monitor),
        &mut |s| bar.set_position(s as u64),
    )?;
    bar.finish_and_clear();
    Ok((
        scene,
        LossLog {
            method: a.method,
            targets_gram_distance: targets_gram,
            hf_agree_adjacent: hf_agree,
            hf_agree_adjacent_original: hf_agree_orig,
            steps,
        },
        targets,
    ))
}
