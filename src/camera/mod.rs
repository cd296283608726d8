//! Pinhole cameras in the OpenCV / COLMAP convention (x right, y down, z forward;
//! world-to-camera rotation and translation), as the 3DGS rasterizer uses them.
//!
//! Sources ([`load_cameras`] picks one from the spec):
//! * [`inria`]: the INRIA 3DGS `cameras.json` (reader and the writer used for the
//!   `cameras.json` of views/targets artifacts);
//! * [`colmap`]: COLMAP sparse models, text (`cameras.txt`, `images.txt`) and binary
//!   (`cameras.bin`, `images.bin`);
//! * [`nerfstudio`]: nerfstudio / instant-ngp `transforms.json` (OpenGL camera-to-world);
//! * an artifact holding a `cameras.json` (views, targets, latents);
//! * [`orbit`]: generated orbits `orbit:N[,elev=DEG][,radius=R][,fov=DEG]` around the
//!   centre of given [`Bounds`] (a scene's, but cameras know nothing of scenes).
//!
//! Pose arithmetic (quaternions, look-at frames, matrix products) is [`crate::geometry`].
//!
//! Every camera is checked by [`Camera::validate`]: the rotation must be orthonormal
//! with determinant +1 within [`ROTATION_TOL`], focal lengths positive and finite, the
//! principal point and translation finite, width and height positive.

pub mod colmap;
pub mod inria;
pub mod nerfstudio;
pub mod orbit;
pub mod path;

use crate::geometry::{Bounds, DMat3, DVec3, mat3, rows};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Largest accepted deviation of a rotation from orthonormality, max |R R^T - I| and
/// |det R - 1| (f32 storage of f64 file values gives about 1e-7).
pub const ROTATION_TOL: f32 = 1e-3;

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

    /// Pixel coordinates (u, v) of a world point and its depth.
    pub fn project(&self, p: [f32; 3]) -> ([f32; 2], f32) {
        let c = self.to_camera(p);
        (
            [
                self.fx * c[0] / c[2] + self.cx,
                self.fy * c[1] / c[2] + self.cy,
            ],
            c[2],
        )
    }

    /// The world-to-camera rotation and translation in f64 (`p_cam = R p + t`).
    pub fn w2c(&self) -> (DMat3, DVec3) {
        (
            mat3(self.rotation.map(|r| r.map(f64::from))),
            DVec3::from_array(self.translation.map(f64::from)),
        )
    }

    /// The world point seen at pixel position `(u, v)` (pixel centres at `x + 0.5`) at
    /// camera depth `z`: `R^T (K^-1 (u, v, 1) z - t)`, in f64.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> DVec3 {
        self.unprojector()(u, v, z)
    }

    /// [`Self::unproject`] with the pose and intrinsics converted once, for many pixels.
    pub fn unprojector(&self) -> impl Fn(f64, f64, f64) -> DVec3 + use<> {
        let (r, t) = self.w2c();
        let to_world = r.transpose();
        let [fx, fy, cx, cy] = [self.fx, self.fy, self.cx, self.cy].map(f64::from);
        move |u, v, z| to_world * (DVec3::new((u - cx) / fx * z, (v - cy) / fy * z, z) - t)
    }

    /// A camera from a world-to-camera rotation and translation in f64.
    pub fn from_w2c(
        name: String,
        width: u32,
        height: u32,
        [fx, fy, cx, cy]: [f64; 4],
        r: [[f64; 3]; 3],
        t: [f64; 3],
    ) -> Camera {
        Camera {
            name,
            width,
            height,
            fx: fx as f32,
            fy: fy as f32,
            cx: cx as f32,
            cy: cy as f32,
            rotation: r.map(|row| row.map(|v| v as f32)),
            translation: t.map(|v| v as f32),
        }
    }

    /// A camera from a camera-to-world rotation (columns = camera axes in world) and the
    /// camera centre, in f64: R = C^T, t = -R c.
    pub fn from_c2w(
        name: String,
        width: u32,
        height: u32,
        intr: [f64; 4],
        c2w: [[f64; 3]; 3],
        center: [f64; 3],
    ) -> Camera {
        let r = mat3(c2w).transpose();
        let t = -(r * DVec3::from_array(center));
        Camera::from_w2c(name, width, height, intr, rows(r), t.to_array())
    }

    /// Check the camera; `path` names the source file in errors.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |r: String| Err(Error::input(path, format!("camera `{}`: {r}", self.name)));
        if self.width == 0 || self.height == 0 {
            return bad(format!(
                "image size {}x{} must be positive",
                self.width, self.height
            ));
        }
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx > 0.0 && self.fy > 0.0) {
            return bad(format!(
                "focal lengths fx={} fy={} must be positive and finite",
                self.fx, self.fy
            ));
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return bad(format!(
                "principal point ({}, {}) is not finite",
                self.cx, self.cy
            ));
        }
        if self.translation.iter().any(|v| !v.is_finite()) {
            return bad(format!("translation {:?} is not finite", self.translation));
        }
        let r = mat3(self.rotation.map(|row| row.map(|v| v as f64)));
        if !r.is_finite() {
            return bad(format!("rotation {:?} is not finite", self.rotation));
        }
        let dev = (r * r.transpose() - crate::geometry::DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, d| m.max(d.abs()));
        if dev > ROTATION_TOL as f64 {
            return bad(format!(
                "rotation is not orthonormal (max |R R^T - I| = {dev:.3e}, tolerance {ROTATION_TOL:e})"
            ));
        }
        let det = r.determinant();
        if (det - 1.0).abs() > ROTATION_TOL as f64 {
            return bad(format!(
                "rotation has determinant {det:.4} (a reflection; must be +1)"
            ));
        }
        Ok(())
    }

    /// The same camera for an image of `width` x `height`: focal lengths and principal
    /// point scale with the image (per axis).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        if width == self.width && height == self.height {
            return self.clone();
        }
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: (self.fx as f64 * sx) as f32,
            fy: (self.fy as f64 * sy) as f32,
            cx: (self.cx as f64 * sx) as f32,
            cy: (self.cy as f64 * sy) as f32,
            ..self.clone()
        }
    }
}

/// Load the cameras named by `spec` for images of `width` x `height`:
/// `orbit:...` (generated around `bounds`, e.g. [`crate::Scene::bounds`]), an INRIA
/// `cameras.json`, a nerfstudio `transforms.json`, or a COLMAP sparse model directory
/// (`sparse/0`, or a directory holding one). Cameras read from files keep their poses;
/// their intrinsics are rescaled from the file's image size to `width` x `height`
/// ([`fit_cameras`]); so are those of an artifact directory holding a `cameras.json`
/// (a views artifact: the cameras a scene was rendered from).
pub fn load_cameras(spec: &str, bounds: &Bounds, width: u32, height: u32) -> Result<Vec<Camera>> {
    check_size(width, height)?;
    if let Some(rest) = spec.strip_prefix("orbit:") {
        let o = orbit::OrbitSpec::parse(rest)?;
        let cams = orbit::orbit(&o, bounds, width, height)?;
        for c in &cams {
            c.validate(Path::new(spec))?;
        }
        return Ok(cams);
    }
    let (cams, src) = load_camera_file(Path::new(spec))?;
    fit_cameras(cams, &src, width, height)
}

/// How many cameras `spec` (as for [`load_cameras`]) names, without a scene: the `N` of
/// `orbit:N`, or the cameras a file, directory or artifact holds.
pub fn count_cameras(spec: &str) -> Result<usize> {
    match spec.strip_prefix("orbit:") {
        Some(rest) => Ok(orbit::OrbitSpec::parse(rest)?.n),
        None => Ok(load_camera_file(Path::new(spec))?.0.len()),
    }
}

/// The `cameras.json` of an artifact that has one (views, targets, latents), its
/// manifest and hashes checked, at the artifact's image size; also returns the file.
fn read_artifact_cameras(dir: &Path) -> Result<(Vec<Camera>, std::path::PathBuf)> {
    let a = fantasystyle_schemas::Artifact::open_any(dir)?;
    let p = a.path("cameras.json");
    if !p.is_file() {
        return Err(Error::input(
            dir,
            format!(
                "artifact of kind `{}` holds no cameras.json",
                a.manifest.kind
            ),
        ));
    }
    Ok((inria::read_inria(&p)?, p))
}

/// Error unless `width` and `height` are positive.
pub fn check_size(width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::param(format!(
            "image size {width}x{height}: width and height must be positive"
        )));
    }
    Ok(())
}

/// Cameras read from `src` (at their own image size) for images of `width` x `height`:
/// intrinsics rescaled per axis (a warning if that changes the aspect ratio), each
/// validated; an empty list is an error naming `src`.
pub fn fit_cameras(cams: Vec<Camera>, src: &Path, width: u32, height: u32) -> Result<Vec<Camera>> {
    for c in cams.iter().take(1) {
        let (a, b) = (
            c.width as f64 / c.height as f64,
            width as f64 / height as f64,
        );
        if (a / b - 1.0).abs() > 0.01 {
            tracing::warn!(
                "{}: cameras are {}x{}, rendering at {width}x{height} changes the aspect \
                 ratio (intrinsics are scaled per axis)",
                src.display(),
                c.width,
                c.height
            );
        }
    }
    let cams: Vec<Camera> = cams.iter().map(|c| c.resized(width, height)).collect();
    if cams.is_empty() {
        return Err(Error::input(src, "no cameras in the file"));
    }
    for c in &cams {
        c.validate(src)?;
    }
    Ok(cams)
}

/// Read cameras (at their own image sizes) from a file, a directory, or an artifact
/// holding a `cameras.json` (views, targets, latents); also returns the file they came
/// from (for messages).
pub fn load_camera_file(path: &Path) -> Result<(Vec<Camera>, std::path::PathBuf)> {
    if path.join(fantasystyle_schemas::MANIFEST_FILE).is_file() {
        return read_artifact_cameras(path);
    }
    if path.is_dir() {
        for (name, is_colmap) in [
            ("cameras.json", false),
            ("transforms.json", false),
            ("cameras.bin", true),
            ("cameras.txt", true),
            ("sparse/0/cameras.bin", true),
            ("sparse/0/cameras.txt", true),
        ] {
            let p = path.join(name);
            if p.is_file() {
                if is_colmap {
                    let dir = p.parent().unwrap_or(path);
                    return Ok((colmap::read_colmap(dir)?, dir.to_path_buf()));
                }
                return load_camera_file(&p);
            }
        }
        return Err(Error::input(
            path,
            "directory holds no cameras (expected cameras.json, transforms.json or a \
             COLMAP sparse model; stages also take an artifact with cameras.json)",
        ));
    }
    if !path.is_file() {
        return Err(Error::input(
            path,
            "camera file does not exist (and the spec is not `orbit:N`)",
        ));
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::input(path, format!("invalid JSON: {e}")))?;
    let cams = if v.is_array() {
        inria::parse_inria(path, v)?
    } else if v.get("frames").is_some() {
        nerfstudio::parse_transforms(path, &v)?
    } else {
        return Err(Error::input(
            path,
            "unknown camera JSON (expected an INRIA cameras.json array or a \
             transforms.json object with `frames`)",
        ));
    };
    Ok((cams, path.to_path_buf()))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A camera at `eye` looking at `target` with world -y up (OpenCV axes).
    pub(crate) fn look_at(eye: [f64; 3], target: [f64; 3]) -> Camera {
        let c2w = crate::geometry::look_at_c2w(eye.into(), target.into(), DVec3::Y);
        Camera::from_c2w("t".into(), 64, 48, [50.0, 50.0, 32.0, 24.0], rows(c2w), eye)
    }

    #[test]
    fn unproject_inverts_project() {
        let c = look_at([1.0, -2.0, -3.0], [0.2, 0.1, 0.0]);
        for p in [[0.0f32, 0.0, 0.0], [0.3, -0.2, 0.5], [-0.4, 0.25, -0.1]] {
            let ([u, v], z) = c.project(p);
            let q = c.unproject(u as f64, v as f64, z as f64);
            let err = (q - DVec3::from_array(p.map(f64::from)))
                .abs()
                .max_element();
            // f32 projection of a point about 3.7 units away: a few ulps of the depth.
            assert!(err < 1e-5, "{p:?} -> {q} (err {err:e})");
        }
        let (r, t) = c.w2c();
        let centre = DVec3::from_array(c.center().map(f64::from));
        assert!((r * centre + t).length() < 1e-5);
    }

    #[test]
    fn validate_names_the_problem() {
        let p = Path::new("c.json");
        let c = look_at([0.0, 0.0, -3.0], [0.0; 3]);
        c.validate(p).unwrap();
        let mut b = c.clone();
        b.rotation[0][0] *= 1.1;
        let e = b.validate(p).unwrap_err().to_string();
        assert!(
            e.contains("c.json") && e.contains("`t`") && e.contains("orthonormal"),
            "{e}"
        );
        let mut b = c.clone();
        b.rotation[2] = b.rotation[2].map(|v| -v);
        assert!(
            b.validate(p)
                .unwrap_err()
                .to_string()
                .contains("determinant")
        );
        let mut b = c.clone();
        b.fx = 0.0;
        assert!(b.validate(p).unwrap_err().to_string().contains("focal"));
        let mut b = c;
        b.width = 0;
        assert!(
            b.validate(p)
                .unwrap_err()
                .to_string()
                .contains("image size")
        );
    }

    #[test]
    fn look_at_projects_target_to_principal_point() {
        let c = look_at([1.0, -2.0, -3.0], [0.2, 0.1, 0.3]);
        let (uv, z) = c.project([0.2, 0.1, 0.3]);
        assert!((uv[0] - 32.0).abs() < 1e-4 && (uv[1] - 24.0).abs() < 1e-4 && z > 0.0);
        let ce = c.center();
        assert!((ce[0] - 1.0).abs() < 1e-5 && (ce[1] + 2.0).abs() < 1e-5);
        let r = c.resized(128, 96);
        assert_eq!((r.fx, r.cx, r.cy), (100.0, 64.0, 48.0));
    }
}
