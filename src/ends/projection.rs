//! `projection`, a start (ARF's recipe, not FantasyStyle): the style image, at the texture
//! terms' size (`texture.style_size`: one style pixel per render pixel at the object),
//! texture-mapped onto the object by triplanar projection along each Gaussian's normal
//! (the normals from the source views' depth), shaded by each Gaussian's relative
//! brightness ([`crate::transfer::projection`]).

use super::{EndInputs, Role};
use crate::transfer::projection::{Placement, depth_views, project_style, surface_normals};
use crate::{Error, Result, Scene};

/// The style image texture-mapped onto `scene` ([`super::ENDS`]' `projection`).
pub fn run(_: Role, scene: &Scene, inputs: &EndInputs<'_>) -> Result<Scene> {
    use crate::maths::warp::surface_depth;
    let _ph = crate::timing::span("style projection");
    // The cameras are the source views': a placement error is about them.
    let at = Placement::of(scene, inputs.cameras)
        .map_err(|e| Error::input(inputs.cameras_from, e.to_string()))?;
    let texture: crate::terms::texture::TextureParams = inputs.section("texture")?;
    let size = texture.style_size;
    let img = crate::vgg::prepare_style(inputs.style, size, inputs.style_path)?;
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
