//! `select`: make a selection of a scene's Gaussians (which ones a stylization may change)
//! from one source of [`crate::selection::SOURCES`] (a box, an ellipsoid, a half-space,
//! or masks drawn on views lifted to the Gaussians: FlashSplat, ECCV 2024), optionally
//! combined with other selections (union, intersection) and inverted.
//!
//! Writes a `selection` artifact: `weights.npy` `[N]` (and `meta`: the Gaussians, how
//! many are selected, the bounds of their centres, what it was made from), which
//! `distill --selection` reads. An empty result is refused (exit 2, nothing written).

use super::Threads;
use crate::artifacts::{load_scene, read_selection, write_selection};
use crate::selection::{Context, lift::LiftOptions, ops, parse_source};
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// Select Gaussians of a scene (a box, an ellipsoid, a half-space, or masks lifted from
/// views). Writes a selection artifact (weights.npy: a weight in [0, 1] per Gaussian).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "select", version)]
pub struct Args {
    /// The scene (an INRIA .ply, a .splat, a .spz or a scene artifact).
    #[arg(long)]
    pub scene: PathBuf,
    /// The source, KIND:SPEC: `box:MINX,MINY,MINZ,MAXX,MAXY,MAXZ`,
    /// `ellipsoid:CX,CY,CZ,RX,RY,RZ`, `half-space:NX,NY,NZ,D` (n . p >= d), all in scene
    /// coordinates around the Gaussians' centres; or `masks:DIR` (one PNG per camera of
    /// --cameras, named after it, white = selected, at the camera's size).
    #[arg(long, value_name = "KIND:SPEC")]
    pub from: String,
    /// The cameras masks were drawn on: `orbit:N[,...]`, a camera file or directory, or
    /// a views artifact.
    #[arg(long)]
    pub cameras: Option<String>,
    /// Masks: background bias (>= 0): a Gaussian is selected when its blending weight in
    /// masked pixels exceeds (1 + bias) times that in unmasked ones.
    #[arg(long, default_value_t = 0.0)]
    pub bias: f32,
    /// Masks: weights in [0, 1] (in / (in + (1 + bias) out)) instead of 0 or 1.
    #[arg(long)]
    pub soft: bool,
    /// Masks: the share of a pixel's light (in [0, 1]) that must reach a Gaussian at some
    /// masked pixel for it to vote; one the views show only behind other surfaces (the
    /// ground under an object) takes the weight of the Gaussians it overlaps instead. 0:
    /// every Gaussian that blends votes (FlashSplat as published).
    #[arg(long, value_name = "T", default_value_t = crate::selection::lift::DEFAULT_OCCLUSION)]
    pub occlusion: f32,
    /// Add another selection artifact of the same scene (max of the weights).
    #[arg(long, value_name = "SELECTION")]
    pub union: Vec<PathBuf>,
    /// Keep only what another selection artifact also selects (min of the weights).
    #[arg(long, value_name = "SELECTION")]
    pub intersect: Vec<PathBuf>,
    /// Invert the result (1 - weight), after --union and --intersect.
    #[arg(long)]
    pub invert: bool,
    /// Output selection artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage; returns the selection written.
pub fn run(a: Args) -> Result<crate::selection::Selection> {
    if !(a.bias.is_finite() && a.bias >= 0.0) {
        return Err(Error::param(format!("--bias {}: must be >= 0", a.bias)));
    }
    if !(0.0..=1.0).contains(&a.occlusion) {
        return Err(Error::param(format!(
            "--occlusion {}: must be in [0, 1]",
            a.occlusion
        )));
    }
    let source = parse_source(&a.from)?;
    let scene = crate::timing::load(|| load_scene(&a.scene))?;
    let ctx = Context {
        cameras: a.cameras.clone(),
        lift: LiftOptions {
            bias: a.bias,
            soft: a.soft,
            occlusion: a.occlusion,
        },
    };
    let mut sel = a.threads.install(|| source.make(&scene, &ctx))??;
    for p in &a.union {
        sel = ops::union(&sel, &read_selection(p)?, p)?;
    }
    for p in &a.intersect {
        sel = ops::intersection(&sel, &read_selection(p)?, p)?;
    }
    if a.invert {
        sel = ops::complement(&sel);
    }
    if sel.selected() == 0 {
        return Err(Error::param(format!(
            "the selection is empty: {} selects none of the {} Gaussians of {}{}",
            a.from,
            scene.len(),
            a.scene.display(),
            if a.union.is_empty() && a.intersect.is_empty() && !a.invert {
                ""
            } else {
                " (after --union, --intersect, --invert)"
            }
        )));
    }
    let b = sel.bounds(&scene);
    tracing::info!(
        "select: {} of {} Gaussians, centres in [{:?}, {:?}]",
        sel.selected(),
        scene.len(),
        b.min.to_array(),
        b.max.to_array()
    );
    let params = serde_json::json!({
        "from": a.from, "cameras": a.cameras, "bias": a.bias, "soft": a.soft,
        "occlusion": a.occlusion,
        "invert": a.invert,
    });
    let mut out = super::create_artifact(
        &a.out,
        ArtifactKind::Selection,
        Producer::new("select", crate::VERSION, params),
    )?;
    out.add_input("scene", &a.scene)?;
    for (role, paths) in [("union", &a.union), ("intersect", &a.intersect)] {
        for p in paths {
            out.add_input(role, p)?;
        }
    }
    let meta = serde_json::json!({
        "source": source.describe(&ctx),
        "bounds": {"min": b.min.to_array(), "max": b.max.to_array()},
        "union": a.union.len(), "intersect": a.intersect.len(), "invert": a.invert,
    });
    write_selection(&mut out, &sel, meta)?;
    crate::timing::io(|| out.commit())?;
    Ok(sel)
}
