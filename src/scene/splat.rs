//! The `.splat` layout used by web viewers (antimatter15/splat and its descendants).
//!
//! 32 bytes per Gaussian, little-endian, no header:
//! position `f32 x3` | linear scale `f32 x3` | colour RGBA `u8 x4` (A = opacity) |
//! rotation `u8 x4`, the quaternion (w, x, y, z) mapped from [-1, 1] as `q = (b - 128) / 128`.
//! There are no higher-order SH coefficients (degree 0).
//!
//! Reading ([`read_splat`]), conversion to the INRIA parameterisation ([`Scene`]):
//! `log_scale = ln(s)`; `opacity_logit = logit(clamp(a / 255, 0.5/255, 1 - 0.5/255))` (so
//! A = 0 and A = 255 stay finite; A = 0 maps below the rasterizer's 1/255 cut);
//! `f_dc = (c / 255 - 0.5) / SH_C0` (the inverse of the renderer's
//! `colour = SH_C0 * f_dc + 0.5`).
//!
//! Writing ([`encode_splat`], [`write_splat`]) is the inverse, in the scene's order:
//! `s = exp(log_scale)`; `c = round(255 clamp(SH_C0 f_dc + 0.5, 0, 1))`;
//! `a = round(255 sigmoid(logit))`; the quaternion is normalised and stored as
//! `round(128 q + 128)` clamped to [0, 255] (as antimatter15's converter does, with
//! rounding instead of truncation). What is lost, per Gaussian:
//! - positions and scales: nothing (f32; log-scales come back within an ulp or two);
//! - colour: at most 0.5/255 per channel for base colours in [0, 1]; brighter or
//!   negative base colours are clamped; and **the higher-order SH coefficients are
//!   dropped** (the format has none), so view-dependent colour is lost: the DC term is
//!   the best constant colour over the sphere (the other SH functions average to zero);
//! - opacity: at most 0.5/255 (opacities above 1 - 0.5/255 read back as 1 - 0.5/255);
//! - rotation: each normalised quaternion component moves by at most 1/256 (1/128 for
//!   a component of exactly +1, stored as 255).

use super::{SH_C0, Scene};
use crate::{Error, Result};
use rayon::prelude::*;
use std::path::Path;

/// Bytes per Gaussian.
pub const RECORD: usize = 32;

/// The render tolerance of a written `.splat` against its degree-0 scene with base
/// colours in [0, 1] (RGB in [0, 1], per channel, max over pixels): colour and opacity
/// quantisation give up to 1/255 where one splat dominates a pixel, and the
/// quaternion's 1/256 steps move the edges of elongated splats by a fraction of a
/// pixel. Measured on the sample scene (orbit:4 at 128x128): max 0.0038, mean 7e-5.
pub const SPLAT_RENDER_MAX: f32 = 0.01;
/// Mean absolute difference bound of the same comparison.
pub const SPLAT_RENDER_MEAN: f64 = 5e-4;

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
    // The first bad record (by index) is the one reported.
    let bad = bytes
        .par_chunks_exact(RECORD)
        .enumerate()
        .map(|(i, r)| {
            let p = [f32_at(r, 0), f32_at(r, 4), f32_at(r, 8)];
            let sc = [f32_at(r, 12), f32_at(r, 16), f32_at(r, 20)];
            if p.iter().any(|v| !v.is_finite()) {
                Some(format!("Gaussian {i}: position {p:?} is not finite"))
            } else if sc.iter().any(|v| !v.is_finite() || *v <= 0.0) {
                Some(format!(
                    "Gaussian {i}: scale {sc:?} must be positive and finite"
                ))
            } else {
                None
            }
        })
        .find_first(Option::is_some)
        .flatten();
    if let Some(msg) = bad {
        return Err(Error::input(path, msg));
    }
    let mut s = Scene {
        positions: vec![[0.0; 3]; n],
        log_scales: vec![[0.0; 3]; n],
        rotations: vec![[0.0; 4]; n],
        opacity_logits: vec![0.0; n],
        sh_degree: 0,
        sh_dc: vec![[0.0; 3]; n],
        sh_rest: Vec::new(),
    };
    const ROWS: usize = 8192;
    s.positions
        .par_chunks_mut(ROWS)
        .zip(s.log_scales.par_chunks_mut(ROWS))
        .zip(s.rotations.par_chunks_mut(ROWS))
        .zip(s.opacity_logits.par_chunks_mut(ROWS))
        .zip(s.sh_dc.par_chunks_mut(ROWS))
        .zip(bytes.par_chunks(ROWS * RECORD))
        .for_each(|(((((pos, ls), rot), op), dc), recs)| {
            for (j, r) in recs.chunks_exact(RECORD).enumerate() {
                pos[j] = [f32_at(r, 0), f32_at(r, 4), f32_at(r, 8)];
                ls[j] = [f32_at(r, 12), f32_at(r, 16), f32_at(r, 20)].map(f32::ln);
                dc[j] = [r[24], r[25], r[26]].map(|c| (c as f32 / 255.0 - 0.5) / SH_C0);
                op[j] = opacity_logit_u8(r[27]);
                rot[j] = [r[28], r[29], r[30], r[31]].map(|b| (b as f32 - 128.0) / 128.0);
            }
        });
    s.validate(path)?;
    Ok(s)
}

/// One value in [0, 1] as a byte, `round(255 v)` (clamped; NaN is 0).
fn unit_u8(v: f32) -> u8 {
    if v.is_nan() {
        0
    } else {
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

/// Encode `s` as `.splat` bytes (see the module docs for what is kept and what is not).
/// The scene must be valid ([`Scene::validate`]); scales that overflow f32 are stored
/// as the largest f32.
pub fn encode_splat(s: &Scene) -> Vec<u8> {
    let mut out = vec![0u8; s.len() * RECORD];
    out.par_chunks_mut(RECORD).enumerate().for_each(|(i, rec)| {
        let mut o = 0;
        let mut put = |b: &[u8]| {
            rec[o..o + b.len()].copy_from_slice(b);
            o += b.len();
        };
        for v in s.positions[i] {
            put(&v.to_le_bytes());
        }
        for ls in s.log_scales[i] {
            put(&ls.exp().min(f32::MAX).to_le_bytes());
        }
        put(&s.sh_dc[i].map(|d| unit_u8(SH_C0 * d + 0.5)));
        let logit = s.opacity_logits[i] as f64;
        put(&[unit_u8((1.0 / (1.0 + (-logit).exp())) as f32)]);
        let q = s.rotations[i].map(f64::from);
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        put(&q.map(|v| (v / n * 128.0 + 128.0).round().clamp(0.0, 255.0) as u8));
    });
    out
}

/// Largest absolute higher-order SH coefficient of `s` (what a `.splat` drops; 0 for a
/// degree-0 scene).
pub fn dropped_sh(s: &Scene) -> f32 {
    s.sh_rest.iter().fold(0.0f32, |m, v| m.max(v.abs()))
}

/// Validate `s` and write it to `path` as `.splat`, atomically. A scene with non-zero
/// higher-order SH coefficients is written with a warning (their view-dependent colour
/// is not representable).
pub fn write_splat(path: &Path, s: &Scene) -> Result<()> {
    s.validate(path)?;
    if s.is_empty() {
        return Err(Error::input(path, "cannot write an empty scene as .splat"));
    }
    let dropped = dropped_sh(s);
    if dropped > 0.0 {
        tracing::warn!(
            "{}: .splat keeps base colours only; SH degree {} coefficients (largest |f_rest| \
             {dropped:.3}) are dropped",
            path.display(),
            s.sh_degree
        );
    }
    fantasystyle_schemas::atomic_write(path, &encode_splat(s))?;
    Ok(())
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

    #[test]
    fn round_trip_within_the_stated_bounds() {
        let mut rng = crate::rng::Rng::new(11);
        let n = 2000;
        let mut s = Scene {
            sh_degree: 0,
            ..Scene::default()
        };
        for _ in 0..n {
            let mut u = || rng.uniform() as f32;
            s.positions.push([u() * 4.0 - 2.0, u() - 0.5, u() * 3.0]);
            s.log_scales
                .push([u() * 4.0 - 5.0, u() * 4.0 - 5.0, u() - 3.0]);
            s.rotations
                .push([u() - 0.5, u() - 0.5, u() - 0.5, u() - 0.5]);
            s.opacity_logits.push(u() * 12.0 - 6.0);
            // Base colours in [0, 1].
            s.sh_dc.push([u(), u(), u()].map(|c| (c - 0.5) / SH_C0));
        }
        let b = encode_splat(&s);
        assert_eq!(b.len(), n * RECORD);
        let r = parse_splat(Path::new("t.splat"), &b).unwrap();
        let sig = |x: f32| 1.0 / (1.0 + (-x as f64).exp());
        for i in 0..n {
            assert_eq!(r.positions[i], s.positions[i]);
            for k in 0..3 {
                assert!((r.log_scales[i][k] - s.log_scales[i][k]).abs() < 1e-6);
                let (c0, c1) = (SH_C0 * s.sh_dc[i][k] + 0.5, SH_C0 * r.sh_dc[i][k] + 0.5);
                assert!((c0 - c1).abs() <= 0.5 / 255.0 + 1e-6, "{c0} {c1}");
            }
            let (o0, o1) = (sig(s.opacity_logits[i]), sig(r.opacity_logits[i]));
            assert!((o0 - o1).abs() <= 0.5 / 255.0 + 1e-6, "{o0} {o1}");
            let q = s.rotations[i];
            let qn = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            for k in 0..4 {
                let want = q[k] / qn;
                let tol = if want > 0.99 {
                    1.0 / 128.0
                } else {
                    1.0 / 256.0
                };
                assert!((r.rotations[i][k] - want).abs() <= tol + 1e-6);
            }
        }
        // A .splat read back and written again keeps every byte, except rotation bytes,
        // which move by at most one step (the stored quaternion is re-normalised).
        for (k, (x, y)) in encode_splat(&r).iter().zip(&b).enumerate() {
            if k % RECORD >= 28 {
                assert!(x.abs_diff(*y) <= 1, "byte {k}: {x} vs {y}");
            } else {
                assert_eq!(x, y, "byte {k}");
            }
        }
    }
}
