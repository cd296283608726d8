//! Writing the INRIA layout: every property `float`, normals written as 0, `f_rest`
//! channel-major, binary little-endian (blocks of Gaussians in parallel, each written
//! into its place) or ASCII (shortest round-trip float text).

use super::ROWS;
use crate::Result;
use crate::scene::{Scene, sh_coeffs};
use rayon::prelude::*;
use std::path::Path;

/// The INRIA property names, in the INRIA order, for `degree`.
pub(super) fn property_names(degree: usize) -> Vec<String> {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for j in 0..3 * (sh_coeffs(degree) - 1) {
        names.push(format!("f_rest_{j}"));
    }
    names.push("opacity".into());
    for j in 0..3 {
        names.push(format!("scale_{j}"));
    }
    for j in 0..4 {
        names.push(format!("rot_{j}"));
    }
    names
}

/// One Gaussian's values in INRIA property order.
pub(super) fn record(s: &Scene, i: usize, out: &mut Vec<f32>) {
    let r = s.rest_per_channel();
    out.extend_from_slice(&s.positions[i]);
    out.extend_from_slice(&[0.0; 3]);
    out.extend_from_slice(&s.sh_dc[i]);
    for c in 0..3 {
        for k in 0..r {
            out.push(s.sh_rest[(i * r + k) * 3 + c]);
        }
    }
    out.push(s.opacity_logits[i]);
    out.extend_from_slice(&s.log_scales[i]);
    out.extend_from_slice(&s.rotations[i]);
}

pub(super) fn header_text(s: &Scene, format: &str) -> String {
    let mut h = format!(
        "ply\nformat {format} 1.0\ncomment written by fantasystyle {}\nelement vertex {}\n",
        crate::VERSION,
        s.len()
    );
    for n in property_names(s.sh_degree) {
        h.push_str(&format!("property float {n}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// Encode `s` as an INRIA binary little-endian PLY (blocks of Gaussians in parallel,
/// each written into its place).
pub fn encode_ply(s: &Scene) -> Vec<u8> {
    let mut out = header_text(s, "binary_little_endian").into_bytes();
    let head = out.len();
    let stride = property_names(s.sh_degree).len() * 4;
    out.resize(head + s.len() * stride, 0);
    out[head..]
        .par_chunks_mut(ROWS * stride)
        .enumerate()
        .for_each(|(b, block)| {
            let mut rec = Vec::with_capacity(stride / 4);
            for (j, dst) in block.chunks_exact_mut(stride).enumerate() {
                rec.clear();
                record(s, b * ROWS + j, &mut rec);
                for (d, v) in dst.chunks_exact_mut(4).zip(&rec) {
                    d.copy_from_slice(&v.to_le_bytes());
                }
            }
        });
    out
}

/// Encode `s` as an ASCII PLY (shortest round-trip float text: reading it back is exact).
pub fn encode_ply_ascii(s: &Scene) -> Vec<u8> {
    let mut out = header_text(s, "ascii");
    let mut rec = Vec::new();
    for i in 0..s.len() {
        rec.clear();
        record(s, i, &mut rec);
        let line: Vec<String> = rec.iter().map(|v| format!("{v:?}")).collect();
        out.push_str(&line.join(" "));
        out.push('\n');
    }
    out.into_bytes()
}

/// Validate `s` and write it to `path` as an INRIA binary PLY, atomically.
pub fn write_ply(path: &Path, s: &Scene) -> Result<()> {
    s.validate(path)?;
    fantasystyle_schemas::atomic_write(path, &encode_ply(s))?;
    Ok(())
}
