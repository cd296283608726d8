//! CPU rasterizer for 3D Gaussian splats (EWA splatting as in 3DGS, Kerbl et al. 2023).
//!
//! (forward, colour backward and the frozen-geometry contribution cache to be written)

use crate::{Camera, Result, Scene};

/// Options for a render.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Background colour, linear RGB in [0, 1].
    pub background: [f32; 3],
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            background: [0.0; 3],
        }
    }
}

/// One rendered view, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    pub width: usize,
    pub height: usize,
    /// `[H, W, 3]`, composited over the background.
    pub rgb: Vec<f32>,
    /// `[H, W]`, expected depth sum_i w_i z_i (not normalised by alpha).
    pub depth: Vec<f32>,
    /// `[H, W]`, accumulated opacity 1 - T_final.
    pub alpha: Vec<f32>,
}

/// Render `scene` from `camera`.
pub fn render(scene: &Scene, camera: &Camera, opts: &RenderOptions) -> Result<RenderOutput> {
    let _ = (scene, camera, opts);
    Err(crate::Error::Other("render: not implemented yet".into()))
}
