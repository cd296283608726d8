//! Gaussian scenes as the 3DGS papers define them (Kerbl et al. 2023, Sec. 4).
//!
//! A [`Scene`] stores parameters exactly as the INRIA `.ply` does: log-scales, opacity
//! logits, unnormalised quaternions (w, x, y, z) and spherical-harmonic coefficients,
//! so that reading and writing a `.ply` round-trips every field bit-exactly.
//! Only colour (`sh_dc`, `sh_rest`) changes during stylization; geometry is frozen.
//!
//! Submodules: `ply` (INRIA binary/ascii PLY), `splat` (the 32-byte `.splat` layout),
//! `sample` (the deterministic sample scene in `data-sample/`).

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
    /// Axis-aligned bounds of the means: (min, max).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }
}
