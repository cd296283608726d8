//! `colour`, a start and a finish (ARF's colour transfer, not FantasyStyle): the object's
//! colour mean and covariance moved onto the style image's, each Gaussian then clamped
//! into the style's colour extent ([`crate::transfer::colour::move_palette`]). As a start
//! the statistics are the source views' (ARF's colour pre-transfer); as a finish they are
//! the result's own renders from the same cameras (ARF's transfer after the optimisation:
//! the loop's palette drift taken back, the texture's arrangement kept).

use super::{EndInputs, Role};
use crate::{Result, Scene};

/// `scene` with its palette moved onto the style's ([`super::ENDS`]' `colour`).
pub fn run(role: Role, scene: &Scene, inputs: &EndInputs<'_>) -> Result<Scene> {
    let s = inputs.source;
    match role {
        Role::Start => {
            let views: Vec<(&[f32], &[f32])> = (0..s.rgb.len())
                .map(|v| (&s.rgb[v][..], &s.alpha[v][..]))
                .collect();
            move_palette("colour start", scene, &views, s.background, inputs)
        }
        Role::Finish => {
            let _ph = crate::timing::span("colour finish");
            let renders = crate::render::render_all(scene, inputs.cameras, s.background)?;
            let views: Vec<(&[f32], &[f32])> =
                renders.iter().map(|r| (&r.rgb[..], &r.alpha[..])).collect();
            move_palette("colour finish", scene, &views, s.background, inputs)
        }
    }
}

/// [`crate::transfer::colour::move_palette`] over `views` (rgb, alpha), logged as `what`.
fn move_palette(
    what: &str,
    scene: &Scene,
    views: &[(&[f32], &[f32])],
    background: [f32; 3],
    inputs: &EndInputs<'_>,
) -> Result<Scene> {
    let (scene, tr, clamped) =
        crate::transfer::colour::move_palette(scene, views, background, inputs.style)?;
    tracing::info!(
        "{what}: object mean {:.3?} -> style mean {:.3?}; {clamped} of {} Gaussians \
         clamped into the style's colour extent",
        tr.source.mean,
        tr.style.mean,
        scene.len()
    );
    Ok(scene)
}
