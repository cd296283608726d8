//! Gaussian scenes as the 3DGS papers define them (Kerbl et al. 2023, Sec. 4).
//!
//! A [`Scene`] stores parameters exactly as the INRIA `.ply` does: log-scales, opacity
//! logits, unnormalised quaternions (w, x, y, z) and spherical-harmonic coefficients,
//! so that reading and writing a `.ply` round-trips every field bit-exactly.
//! Only colour (`sh_dc`, `sh_rest`) changes during stylization's iterations; geometry is
//! frozen (the `split` stage may subdivide it once, before the first: [`crate::ends::split`]).
//!
//! Submodules: [`ply`] (INRIA binary/ascii PLY), [`splat`] (the 32-byte `.splat` layout),
//! [`spz`] (Niantic's compressed `.spz`, versions 2 and 3); [`colour`] (the base colour's
//! range every format holds, and the choice of the view-dependent bands).
//! [`read_scene_file`] picks the reader from the path (stages read their `--scene`
//! through [`crate::artifacts::load_scene`], which also takes scene artifacts); every reader ends with
//! [`Scene::validate`]. Scenes know nothing of cameras: [`Scene::bounds`] is what a
//! generated orbit needs ([`crate::camera::orbit`]). [`encode_files`] gives the files a
//! scene is written as (`scene.ply`, and on request `scene.splat` and `scene.spz`).

pub mod colour;
pub mod ply;
pub mod splat;
pub mod spz;

use crate::geometry::Bounds;
use crate::{Error, Result};
use rayon::prelude::*;
use std::path::Path;

/// Largest accepted natural-log scale: exp(20) is about 5e8 scene units, far beyond any
/// real scene; larger values mean a corrupt or non-log file.
pub const MAX_LOG_SCALE: f32 = 20.0;

/// The degree-0 real spherical-harmonic constant, 1 / (2 sqrt(pi)).
pub const SH_C0: f32 = 0.282_094_8;

/// Number of SH coefficients per channel for `degree` (1, 4, 9, 16).
pub const fn sh_coeffs(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// A 3D Gaussian scene in the INRIA parameterisation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    /// Means (x, y, z).
    pub positions: Vec<[f32; 3]>,
    /// Natural-log scales per axis (`scale_0..2` in the PLY).
    pub log_scales: Vec<[f32; 3]>,
    /// Rotation quaternions (w, x, y, z) as stored; normalised when used.
    pub rotations: Vec<[f32; 4]>,
    /// Opacity logits (`opacity` in the PLY); opacity = sigmoid(logit).
    pub opacity_logits: Vec<f32>,
    /// SH degree, 0..=3.
    pub sh_degree: usize,
    /// Degree-0 SH coefficient per channel (`f_dc_0..2`).
    pub sh_dc: Vec<[f32; 3]>,
    /// Higher-order SH coefficients, `len == n * (sh_coeffs(deg) - 1) * 3`, laid out
    /// per Gaussian as `[coeff k = 1..K][channel]` (the PLY stores them channel-major;
    /// the reader and writer transpose).
    pub sh_rest: Vec<f32>,
}

impl Scene {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
    /// Higher-order coefficients per Gaussian per channel.
    pub fn rest_per_channel(&self) -> usize {
        sh_coeffs(self.sh_degree) - 1
    }
    /// Opacity in (0, 1).
    pub fn opacity(&self, i: usize) -> f32 {
        1.0 / (1.0 + (-self.opacity_logits[i]).exp())
    }
    /// Linear scales.
    pub fn scale(&self, i: usize) -> [f32; 3] {
        let s = self.log_scales[i];
        [s[0].exp(), s[1].exp(), s[2].exp()]
    }
    /// Axis-aligned bounds of the means (empty for an empty scene).
    pub fn bounds(&self) -> Bounds {
        Bounds::of_points(&self.positions)
    }

    /// Check the invariants every renderer relies on; `path` names the file in errors.
    ///
    /// Refused: inconsistent array lengths, SH degree > 3, NaN/infinite positions,
    /// opacities or SH coefficients, zero or non-finite quaternions, NaN or non-finite
    /// log-scales and log-scales above [`MAX_LOG_SCALE`]. An empty scene is allowed
    /// here (a reader may refuse it).
    pub fn validate(&self, path: &Path) -> Result<()> {
        let n = self.len();
        let bad = |reason: String| Err(Error::input(path, reason));
        if self.sh_degree > 3 {
            return bad(format!(
                "SH degree {} (at most 3 supported)",
                self.sh_degree
            ));
        }
        let lens = [
            ("log_scales", self.log_scales.len()),
            ("rotations", self.rotations.len()),
            ("opacity_logits", self.opacity_logits.len()),
            ("sh_dc", self.sh_dc.len()),
        ];
        for (name, l) in lens {
            if l != n {
                return bad(format!("{name} has {l} entries for {n} Gaussians"));
            }
        }
        let rest = n * self.rest_per_channel() * 3;
        if self.sh_rest.len() != rest {
            return bad(format!(
                "sh_rest has {} values, SH degree {} with {n} Gaussians needs {rest}",
                self.sh_rest.len(),
                self.sh_degree
            ));
        }
        // In parallel; the first bad Gaussian (by index) is the one reported.
        if let Some(msg) = (0..n)
            .into_par_iter()
            .map(|i| self.check_gaussian(i))
            .find_first(Option::is_some)
            .flatten()
        {
            return bad(msg);
        }
        if let Some(j) = self.sh_rest.par_iter().position_first(|v| !v.is_finite()) {
            let per = (self.rest_per_channel() * 3).max(1);
            return bad(format!(
                "Gaussian {}: f_rest coefficient {} is not finite",
                j / per,
                self.sh_rest[j]
            ));
        }
        Ok(())
    }

    /// What is wrong with Gaussian `i`, if anything (see [`Self::validate`]).
    fn check_gaussian(&self, i: usize) -> Option<String> {
        let p = self.positions[i];
        if p.iter().any(|v| !v.is_finite()) {
            return Some(format!("Gaussian {i}: position {p:?} is not finite"));
        }
        let q = self.rotations[i];
        if q.iter().any(|v| !v.is_finite()) {
            return Some(format!(
                "Gaussian {i}: rotation quaternion {q:?} is not finite"
            ));
        }
        let qn = q.iter().map(|v| (*v as f64) * (*v as f64)).sum::<f64>();
        if qn < 1e-20 {
            return Some(format!(
                "Gaussian {i}: rotation quaternion {q:?} is zero (no rotation can be derived)"
            ));
        }
        let s = self.log_scales[i];
        if s.iter().any(|v| !v.is_finite()) {
            return Some(format!("Gaussian {i}: log-scale {s:?} is not finite"));
        }
        if s.iter().any(|v| *v > MAX_LOG_SCALE) {
            return Some(format!(
                "Gaussian {i}: log-scale {s:?} is absurdly large (> {MAX_LOG_SCALE}, \
                 scale > {:.3e}); is this a linear scale or a corrupt file?",
                MAX_LOG_SCALE.exp()
            ));
        }
        let o = self.opacity_logits[i];
        if !o.is_finite() {
            return Some(format!("Gaussian {i}: opacity logit {o} is not finite"));
        }
        let c = self.sh_dc[i];
        if c.iter().any(|v| !v.is_finite()) {
            return Some(format!("Gaussian {i}: f_dc {c:?} is not finite"));
        }
        None
    }
}

/// Load a scene from `path`: a `.ply` (INRIA), a `.splat`, a `.spz`, or a plain directory
/// holding a `scene.ply`.
pub fn read_scene_file(path: &Path) -> Result<Scene> {
    if path.is_dir() {
        let p = path.join("scene.ply");
        if p.is_file() {
            return ply::read_ply(&p);
        }
        return Err(Error::input(
            path,
            "directory holds neither a scene artifact (manifest.json) nor scene.ply",
        ));
    }
    if !path.exists() {
        return Err(Error::input(path, "scene file does not exist"));
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "ply" => ply::read_ply(path),
        "splat" => splat::read_splat(path),
        "spz" => spz::read_spz(path),
        _ => Err(Error::input(
            path,
            "unknown scene format (expected a .ply, a .splat, a .spz or a scene artifact \
             directory)",
        )),
    }
}

/// Which files [`encode_files`] writes besides `scene.ply` (always written: it keeps
/// every coefficient and is what the stages read back).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExtraFormats {
    /// `scene.splat` (32 bytes per Gaussian, base colours only; [`splat`]).
    pub splat: bool,
    /// `scene.spz` (Niantic's compressed format, version 3; [`spz`]).
    pub spz: bool,
}

/// The files a scene is written as, `(file name, bytes)`: `scene.ply`, then
/// `scene.splat` and `scene.spz` as `extra` asks. `path` names the scene in errors (a
/// scene `.spz` cannot hold: coordinates beyond its 24-bit range).
pub fn encode_files(
    path: &Path,
    scene: &Scene,
    extra: ExtraFormats,
) -> Result<Vec<(&'static str, Vec<u8>)>> {
    let mut files = vec![("scene.ply", ply::encode_ply(scene))];
    if extra.splat {
        files.push(("scene.splat", splat::encode_splat(scene)));
    }
    if extra.spz {
        files.push((
            "scene.spz",
            spz::encode_spz(&path.join("scene.spz"), scene)?,
        ));
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn tiny(n: usize, degree: usize) -> Scene {
        let r = sh_coeffs(degree) - 1;
        Scene {
            positions: (0..n).map(|i| [i as f32, 0.5, -1.0]).collect(),
            log_scales: vec![[-2.0, -3.0, -4.0]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![0.5; n],
            sh_degree: degree,
            sh_dc: vec![[0.1, 0.2, 0.3]; n],
            sh_rest: (0..n * r * 3).map(|j| j as f32 * 0.01).collect(),
        }
    }

    #[test]
    fn validate_accepts_good_and_names_problems() {
        let p = Path::new("x.ply");
        tiny(3, 2).validate(p).unwrap();
        let mut s = tiny(3, 1);
        s.positions[1][2] = f32::NAN;
        let e = s.validate(p).unwrap_err().to_string();
        assert!(
            e.contains("x.ply") && e.contains("Gaussian 1") && e.contains("position"),
            "{e}"
        );
        let mut s = tiny(3, 1);
        s.rotations[2] = [0.0; 4];
        let e = s.validate(p).unwrap_err().to_string();
        assert!(e.contains("quaternion") && e.contains("zero"), "{e}");
        let mut s = tiny(3, 1);
        s.log_scales[0][1] = 25.0;
        let e = s.validate(p).unwrap_err().to_string();
        assert!(e.contains("absurdly large"), "{e}");
        let mut s = tiny(3, 1);
        s.sh_rest.pop();
        assert!(s.validate(p).is_err());
    }
}
