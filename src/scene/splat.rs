//! The `.splat` layout used by web viewers (antimatter15/splat and its descendants).
//!
//! 32 bytes per Gaussian, little-endian, no header:
//! position `f32 x3` | linear scale `f32 x3` | colour RGBA `u8 x4` (A = opacity) |
//! rotation `u8 x4`, the quaternion (w, x, y, z) mapped from [-1, 1] as `q = (b - 128) / 128`.
//! There are no higher-order SH coefficients (degree 0).
//!
//! Conversion to the INRIA parameterisation ([`Scene`]): `log_scale = ln(s)`;
//! `opacity_logit = logit(clamp(a / 255, 0.5/255, 1 - 0.5/255))` (so A = 0 and A = 255
//! stay finite; A = 0 maps below the rasterizer's 1/255 cut); `f_dc = (c / 255 - 0.5) / SH_C0`
//! (the inverse of the renderer's `colour = SH_C0 * f_dc + 0.5`).

use super::{SH_C0, Scene};
use crate::{Error, Result};
use std::path::Path;

/// Bytes per Gaussian.
pub const RECORD: usize = 32;

/// Read a `.splat` file.
pub fn read_splat(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_splat(path, &bytes)
}

fn f32_at(b: &[u8], o: usize) -> f32 {
    f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

/// Logit of an 8-bit opacity, clamped half a step inside (0, 1).
pub fn opacity_logit_u8(a: u8) -> f32 {
    let p = (a as f64 / 255.0).clamp(0.5 / 255.0, 1.0 - 0.5 / 255.0);
    (p / (1.0 - p)).ln() as f32
}

/// Parse `.splat` bytes; `path` is used in error messages only.
pub fn parse_splat(path: &Path, bytes: &[u8]) -> Result<Scene> {
    if bytes.is_empty() {
        return Err(Error::input(path, "empty .splat file (no Gaussians)"));
    }
    if !bytes.len().is_multiple_of(RECORD) {
        return Err(Error::input(
            path,
            format!(
                "{} bytes is not a multiple of the 32-byte .splat record \
                 (truncated or not a .splat file)",
                bytes.len()
            ),
        ));
    }
    let n = bytes.len() / RECORD;
    let mut s = Scene {
        sh_degree: 0,
        ..Scene::default()
    };
    s.positions.reserve(n);
    s.log_scales.reserve(n);
    s.rotations.reserve(n);
    s.opacity_logits.reserve(n);
    s.sh_dc.reserve(n);
    for (i, r) in bytes.chunks_exact(RECORD).enumerate() {
        let p = [f32_at(r, 0), f32_at(r, 4), f32_at(r, 8)];
        if p.iter().any(|v| !v.is_finite()) {
            return Err(Error::input(
                path,
                format!("Gaussian {i}: position {p:?} is not finite"),
            ));
        }
        let sc = [f32_at(r, 12), f32_at(r, 16), f32_at(r, 20)];
        if sc.iter().any(|v| !v.is_finite() || *v <= 0.0) {
            return Err(Error::input(
                path,
                format!("Gaussian {i}: scale {sc:?} must be positive and finite"),
            ));
        }
        let q = [r[28], r[29], r[30], r[31]].map(|b| (b as f32 - 128.0) / 128.0);
        s.positions.push(p);
        s.log_scales.push(sc.map(f32::ln));
        s.sh_dc
            .push([r[24], r[25], r[26]].map(|c| (c as f32 / 255.0 - 0.5) / SH_C0));
        s.opacity_logits.push(opacity_logit_u8(r[27]));
        s.rotations.push(q);
    }
    s.validate(path)?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(p: [f32; 3], s: [f32; 3], rgba: [u8; 4], q: [u8; 4]) -> Vec<u8> {
        let mut b = Vec::new();
        for v in p.iter().chain(&s) {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&rgba);
        b.extend_from_slice(&q);
        b
    }

    #[test]
    fn converts_to_inria_parameters() {
        let b = rec(
            [1.0, 2.0, 3.0],
            [0.5, 1.0, 2.0],
            [255, 0, 128, 255],
            [255, 128, 128, 0],
        );
        let s = parse_splat(Path::new("a.splat"), &b).unwrap();
        assert_eq!(s.positions[0], [1.0, 2.0, 3.0]);
        assert!((s.scale(0)[0] - 0.5).abs() < 1e-6 && (s.scale(0)[2] - 2.0).abs() < 1e-6);
        // colour = SH_C0 * dc + 0.5 recovers c / 255.
        let c: Vec<f32> = s.sh_dc[0].iter().map(|d| SH_C0 * d + 0.5).collect();
        assert!((c[0] - 1.0).abs() < 1e-6 && c[1].abs() < 1e-6);
        assert!((c[2] - 128.0 / 255.0).abs() < 1e-6);
        assert!(s.opacity(0) > 0.99 && s.opacity_logits[0].is_finite());
        assert!((s.rotations[0][0] - 127.0 / 128.0).abs() < 1e-7);
        assert_eq!(s.rotations[0][3], -1.0);
        assert!(opacity_logit_u8(0).is_finite() && opacity_logit_u8(0) < -6.0);
    }

    #[test]
    fn refuses_bad_records() {
        let p = Path::new("bad.splat");
        let good = rec([0.0; 3], [1.0; 3], [1; 4], [255, 128, 128, 128]);
        let e = parse_splat(p, &good[..31]).unwrap_err().to_string();
        assert!(
            e.contains("bad.splat") && e.contains("multiple of the 32-byte"),
            "{e}"
        );
        assert!(
            parse_splat(p, &[])
                .unwrap_err()
                .to_string()
                .contains("empty")
        );
        let nan = rec([f32::NAN, 0.0, 0.0], [1.0; 3], [1; 4], [255, 128, 128, 128]);
        assert!(
            parse_splat(p, &nan)
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
        let neg = rec([0.0; 3], [1.0, -1.0, 1.0], [1; 4], [255, 128, 128, 128]);
        assert!(
            parse_splat(p, &neg)
                .unwrap_err()
                .to_string()
                .contains("positive")
        );
        let zq = rec([0.0; 3], [1.0; 3], [1; 4], [128; 4]);
        assert!(
            parse_splat(p, &zq)
                .unwrap_err()
                .to_string()
                .contains("zero")
        );
    }
}
