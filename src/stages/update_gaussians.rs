//! `update-gaussians`: fit a scene's SH colours to target images with geometry frozen
//! (issue: update-gaussians; the paper's "Gaussians are updated toward z0_tgt" step).
//!
//! Reads the scene, the cameras and a `targets` (or `views`) artifact whose `rgb.npy`
//! is `[N, H, W, 3]` with one image per camera; runs [`crate::optim::fit_colours`]
//! (L1 + D-SSIM, Adam) for `--steps` steps; writes a `scene` artifact with `scene.ply`
//! (every non-colour field bit-identical to the input) and `loss.json` (the mean loss
//! over views per step, plus cache statistics).

use super::{Background, SceneInput, Threads};
use crate::artifacts::read_targets;
use crate::optim::{FitParams, fit_colours};
use crate::render::CacheMode;
use crate::scene::ply;
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
    /// Targets: a `targets` or `views` artifact directory whose rgb.npy is [N,H,W,3].
    #[arg(long)]
    pub targets: PathBuf,
    /// Number of Adam steps; each step renders every view once (>= 1).
    #[arg(long)]
    pub steps: usize,
    /// Output scene artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Adam learning rate of the degree-0 SH coefficients f_dc. 3DGS trains from scratch
    /// at 0.0025 over 30k steps; a colour fit of tens to hundreds of steps needs more
    /// (BENCHMARKS.md, "Colour-fit learning rate": 300 steps reach 30 dB at 0.0025, 53 dB
    /// at 0.01).
    #[arg(long, default_value_t = 0.01)]
    pub lr_dc: f32,
    /// Adam learning rate of the higher SH coefficients f_rest (default: lr-dc / 20).
    #[arg(long)]
    pub lr_rest: Option<f32>,
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
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage: load, fit, write the artifact.
pub fn run(a: Args) -> Result<()> {
    let cache: CacheMode = a.cache.parse()?;
    if a.steps == 0 {
        return Err(Error::param("--steps must be at least 1"));
    }
    let scene = a.input.load_scene()?;
    let targets = read_targets(&a.targets)?;
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
    let params = FitParams {
        lr_dc: a.lr_dc,
        lr_rest: a.lr_rest.unwrap_or(a.lr_dc / 20.0),
        ssim_weight: a.ssim_weight,
        mask_alpha: a.mask_alpha,
        cache,
        background: a.background.rgb,
        progress: true,
    };
    let producer = Producer::new(
        "update-gaussians",
        crate::VERSION,
        serde_json::json!({
            "cameras": a.input.cameras, "steps": a.steps, "lr_dc": params.lr_dc,
            "lr_rest": params.lr_rest, "ssim_weight": a.ssim_weight,
            "mask_alpha": a.mask_alpha, "cache": a.cache, "background": a.background.rgb,
        }),
    );
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    a.input.add_inputs(&mut out)?;
    out.add_input("targets", &a.targets)?;
    let (fitted, report) = a
        .threads
        .install(|| fit_colours(&scene, &cams, &targets, a.steps, &params))??;
    out.write_bytes("scene.ply", &ply::encode_ply(&fitted))?;
    out.write_json(
        "loss.json",
        &serde_json::json!({
            "loss": report.losses,
            "steps": a.steps,
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
