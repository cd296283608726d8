//! How a run starts and how it ends: the configuration's `start` and `finish`, each one
//! choice. FantasyStyle starts from the scene as it is and ends with the last iteration
//! (`start = "scene"`, `finish = "none"`); the other choices are techniques of ARF's
//! recipe (the `arf` preset), not part of FantasyStyle:
//!
//! | choice | what | technique |
//! |---|---|---|
//! | `start = "colour"` | the object's colour mean and covariance (over the source views) moved onto the style image's, each Gaussian then clamped into the style's colour extent (ARF's colour pre-transfer) | [`super::colour_transfer`] |
//! | `start = "projection"` | the style image texture-mapped onto the object: triplanar projection along each Gaussian's normal, one style pixel per render pixel at the object (the texture terms' motif scale, `texture.style_size`), shaded by each Gaussian's relative brightness | [`super::projection`] |
//! | `finish = "patches"` | the patch prior's deterministic t -> 0 end: the colours fitted, coarse to fine, to every view's average of its nearest style patches, targets held, patch use balanced (texture optimisation, Kwatra et al. 2005) | [`super::synthesis`] |
//! | `finish = "colour"` | the result's colour statistics (over its renders from the source cameras) moved onto the style's once more (ARF's colour transfer after the optimisation): the loop's palette drift taken back, the texture's arrangement kept | [`super::colour_transfer`] |
//!
//! A start applies to a fresh run (from a scene, iteration 0): a checkpoint has been
//! through it. A chunked run (the sample DAG) gives the finish to its last stage only.
//! Splitting long Gaussians is a start of another kind, a change of the geometry: its
//! own stage (`split`, [`super::split`]).

use super::SourceViews;
use crate::imageio::Image;
use crate::{Camera, Error, Result, Scene};
use std::path::Path;

/// How a fresh run starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Start {
    /// From the scene as it is (FantasyStyle).
    #[default]
    Scene,
    /// From the object's colours moved onto the style's mean and covariance (ARF's colour
    /// pre-transfer).
    Colour,
    /// From the style image texture-mapped onto the object (triplanar projection).
    Projection,
}

/// How a run ends, after its last iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Finish {
    /// With the last iteration's colours (FantasyStyle).
    #[default]
    None,
    /// With the colours moved onto the style's mean and covariance once more (ARF's
    /// colour transfer after the optimisation).
    Colour,
    /// With the patch prior's deterministic end: texture optimisation of the colours
    /// with the style's patches, coarse to fine (`[synthesis]`).
    Patches,
}

crate::params::serde_by_value_name!(Start, Finish);

/// What a start needs besides the scene: the source views (their cameras; `cameras_from`
/// names them in errors), the style image as loaded for the prior, the style image sized
/// for the texture terms (`style_size` on its shorter side; `style_path` in errors), and
/// the background.
#[derive(Debug, Clone, Copy)]
pub struct StartInputs<'a> {
    pub cameras: &'a [Camera],
    pub cameras_from: &'a Path,
    pub source: &'a SourceViews,
    pub style: &'a Image,
    pub style_path: &'a Path,
    pub style_size: usize,
}

/// `scene` after the start `kind`.
pub fn start(kind: Start, scene: &Scene, inputs: &StartInputs<'_>) -> Result<Scene> {
    match kind {
        Start::Scene => Ok(scene.clone()),
        Start::Colour => {
            let s = inputs.source;
            let views: Vec<(&[f32], &[f32])> = (0..s.rgb.len())
                .map(|v| (&s.rgb[v][..], &s.alpha[v][..]))
                .collect();
            move_palette("colour start", scene, &views, s.background, inputs.style)
        }
        Start::Projection => project(scene, inputs),
    }
}

/// The style image (at the texture terms' size) texture-mapped onto `scene`.
fn project(scene: &Scene, inputs: &StartInputs<'_>) -> Result<Scene> {
    use super::projection::{Placement, depth_views, project_style, surface_normals};
    use crate::maths::warp::surface_depth;
    let _ph = crate::timing::span("style projection");
    // The cameras are the source views': a placement error is about them.
    let at = Placement::of(scene, inputs.cameras)
        .map_err(|e| Error::input(inputs.cameras_from, e.to_string()))?;
    let img = crate::vgg::prepare_style(inputs.style, inputs.style_size, inputs.style_path)?;
    tracing::info!(
        "style projection: {}x{} style px, {:.3e} world units per px, centre {:.3?}",
        img.width,
        img.height,
        at.world_per_pixel,
        at.centre
    );
    let source = inputs.source;
    let surfaces: Vec<Vec<f32>> = (source.depth.iter().zip(&source.alpha))
        .map(|(depth, alpha)| surface_depth(depth, alpha))
        .collect();
    let normals = surface_normals(scene, &depth_views(inputs.cameras, &surfaces));
    tracing::info!("style projection: {normals}");
    Ok(project_style(scene, &img, &at, &normals.normals))
}

/// What a finish needs besides the scene: the cameras, the style image, the background,
/// the configuration (`texture.style_size`, `[synthesis]`) and the selection, if any.
#[derive(Debug, Clone, Copy)]
pub struct FinishInputs<'a> {
    pub cameras: &'a [Camera],
    pub style: &'a Image,
    pub background: [f32; 3],
    pub config: &'a super::Config,
    pub selection: Option<&'a crate::selection::Selection>,
    /// The source views' colours (`[H, W, 3]` per camera), if the run has them: the
    /// patch synthesis takes its structure guide and source branch from them.
    pub source: Option<&'a [Vec<f32>]>,
}

/// `scene` after the finish `kind`: for `colour`, the colour statistics of its own renders
/// from the cameras moved onto those of the style image; for `patches`, the patch
/// synthesis ([`super::synthesis`]).
pub fn finish(kind: Finish, scene: &Scene, inputs: &FinishInputs<'_>) -> Result<Scene> {
    let (cameras, style, background) = (inputs.cameras, inputs.style, inputs.background);
    match kind {
        Finish::None => Ok(scene.clone()),
        Finish::Colour => {
            let _ph = crate::timing::span("colour finish");
            let renders = crate::render::render_all(scene, cameras, background)?;
            let views: Vec<(&[f32], &[f32])> =
                renders.iter().map(|r| (&r.rgb[..], &r.alpha[..])).collect();
            move_palette("colour finish", scene, &views, background, style)
        }
        Finish::Patches => {
            let c = inputs.config;
            let size = c.texture.style_size;
            let (out, _) = super::synthesis::synthesize(
                scene,
                cameras,
                style,
                background,
                size,
                &c.synthesis,
                inputs.selection,
                inputs.source,
            )?;
            Ok(out)
        }
    }
}

/// [`super::colour_transfer::move_palette`], logged as `what`.
fn move_palette(
    what: &str,
    scene: &Scene,
    views: &[(&[f32], &[f32])],
    background: [f32; 3],
    style: &Image,
) -> Result<Scene> {
    let (scene, tr, clamped) =
        super::colour_transfer::move_palette(scene, views, background, style)?;
    tracing::info!(
        "{what}: object mean {:.3?} -> style mean {:.3?}; {clamped} of {} Gaussians \
         clamped into the style's colour extent",
        tr.source.mean,
        tr.style.mean,
        scene.len()
    );
    Ok(scene)
}
