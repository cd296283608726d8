//! Per-Gaussian weights rendered like colours: for weights `w_r` (one per Gaussian and
//! per set `r`), each pixel's `sum_i w_ri alpha_i T_i`, the share of its light that comes
//! from the weighted Gaussians (the rasteriser's own blending weights, three sets per
//! composite, one in each colour channel). The regions of a run use it to say who owns a
//! pixel ([`crate::ends::patches::regions`]) and the report to draw them.

use super::{composite, project, validate_camera};
use crate::{Camera, Result, Scene};

/// Each set of `weights`' share of every pixel of `camera`'s view (`[set][H W]`); a
/// set's weights are in the scene's order.
pub fn shares(scene: &Scene, camera: &Camera, weights: &[&[f32]]) -> Result<Vec<Vec<f32>>> {
    validate_camera(camera)?;
    let frame = project(scene, camera);
    let mut out = Vec::with_capacity(weights.len());
    for first in (0..weights.len()).step_by(3) {
        let w = |r: usize, g: u32| weights.get(r).map_or(0.0, |w| w[g as usize]);
        let colours: Vec<[f32; 3]> = frame
            .splats
            .ids
            .iter()
            .map(|&g| [0, 1, 2].map(|c| w(first + c, g)))
            .collect();
        let rgb = composite(&frame, &colours, [0.0; 3]).rgb;
        for c in 0..3.min(weights.len() - first) {
            out.push(rgb.iter().skip(c).step_by(3).copied().collect());
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_of_a_split_add_up_to_the_coverage() {
        // The sample's Gaussians split in two by their index: the two sets' shares add up
        // to the render's coverage, and each set has pixels of its own.
        let scene = crate::sample::sample_scene(1);
        let cams = crate::camera::load_cameras("orbit:2", &scene.bounds(), 24, 24).unwrap();
        let a: Vec<f32> = (0..scene.len()).map(|i| (i % 2) as f32).collect();
        let b: Vec<f32> = a.iter().map(|w| 1.0 - w).collect();
        let alpha = crate::render::render_all(&scene, &cams, [0.0; 3]).unwrap();
        for (v, cam) in cams.iter().enumerate() {
            let s = shares(&scene, cam, &[&a, &b]).unwrap();
            for (i, &al) in alpha[v].alpha.iter().enumerate() {
                let sum = s[0][i] + s[1][i];
                assert!((sum - al).abs() < 1e-4, "view {v} pixel {i}: {sum} vs {al}");
            }
            assert!(s[0].iter().any(|&x| x > 0.1) && s[1].iter().any(|&x| x > 0.1));
        }
    }
}
