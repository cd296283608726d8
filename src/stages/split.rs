//! `split`: the configuration's `split` ([`crate::ends::split`]): every Gaussian longer
//! than `split` render pixels at the object (2 sigma along its longest axis; one pixel is
//! the style projection's, from the source views' cameras) split in two, up to 8 rounds,
//! before a run. Not part of FantasyStyle, and the one step of a run that changes the
//! geometry (with the geometry frozen, a colour changes only as finely as the Gaussians
//! that carry it); opt-in: at `split = 0` (the default) or strength 0 it writes the scene
//! as it is.
//!
//! Writes a `scene` artifact: `scene.ply` (and `meta`: the Gaussians before and after,
//! the splits and rounds), which `distill --scene` starts from; it logs the Gaussians it
//! added and the output's size.

use super::{ConfigArgs, Threads};
use crate::artifacts::{load_scene, read_views};
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Split a scene's long Gaussians before a run (the configuration's `split`, in render
/// pixels at the object; 0: the scene as it is). Writes a scene artifact (scene.ply).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "split", version)]
pub struct Args {
    /// The scene (an INRIA .ply, a .splat, a .spz or a scene artifact).
    #[arg(long)]
    pub scene: PathBuf,
    /// Views artifact of the scene (render-views): the cameras that set the pixel.
    #[arg(long)]
    pub source_views: PathBuf,
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Output scene artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage; returns the split's report (`None`: written as it is).
pub fn run(a: Args) -> Result<Option<crate::ends::split::SplitReport>> {
    let config = a.config.load()?;
    let scene = crate::timing::load(|| load_scene(&a.scene))?;
    let cameras = crate::timing::load(|| read_views(&a.source_views))?.cameras_per_view()?;
    let (scene, report) = if config.split > 0.0 && config.strength > 0.0 {
        let (s, r) = a
            .threads
            .install(|| crate::ends::split::split_to_pixels(&scene, &cameras, config.split))?
            .map_err(|e| Error::input(&a.source_views, e.to_string()))?;
        (s, Some(r))
    } else {
        tracing::info!("split: off (split = {}); the scene as it is", config.split);
        (scene, None)
    };
    let params = serde_json::json!({ "split": config.split, "strength": config.strength });
    let mut out = super::create_artifact(
        &a.out,
        ArtifactKind::Scene,
        Producer::new("split", crate::VERSION, params),
    )?;
    out.add_input("scene", &a.scene)?;
    out.add_input("source-views", &a.source_views)?;
    let bytes = crate::scene::ply::encode_ply(&scene);
    if let Some(r) = &report {
        tracing::info!(
            "split: {} Gaussians added ({r}); scene.ply is {:.1} MB",
            r.after - r.before,
            bytes.len() as f64 / 1e6
        );
        out.set_meta(serde_json::json!({
            "before": r.before, "after": r.after, "splits": r.splits, "rounds": r.rounds,
            "left_above": r.left_above, "capped": r.capped,
        }));
    }
    out.write_bytes("scene.ply", &bytes)?;
    crate::timing::io(|| out.commit())?;
    Ok(report)
}
