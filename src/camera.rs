//! Pinhole cameras in the OpenCV / COLMAP convention (x right, y down, z forward;
//! world-to-camera rotation and translation), as the 3DGS rasterizer uses them.
//!
//! Readers for INRIA `cameras.json`, COLMAP sparse models (text and binary), nerfstudio
//! `transforms.json`, and generated orbits (`orbit:N[,elev=DEG][,radius=R]`).

use serde::{Deserialize, Serialize};

/// A pinhole camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// A name (image name in the source file, or `orbit_000`).
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Focal lengths and principal point, pixels.
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// World-to-camera rotation, row-major (must be orthonormal, det +1).
    pub rotation: [[f32; 3]; 3],
    /// World-to-camera translation.
    pub translation: [f32; 3],
}

impl Camera {
    /// Camera centre in world coordinates: -R^T t.
    pub fn center(&self) -> [f32; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        let mut c = [0.0; 3];
        for j in 0..3 {
            c[j] = -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]);
        }
        c
    }

    /// A world point in camera coordinates.
    pub fn to_camera(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2],
        ]
    }
}
