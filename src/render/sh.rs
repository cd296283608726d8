//! Real spherical harmonics up to degree 3, with the constants and sign conventions of
//! the INRIA 3DGS code (`computeColorFromSH`; Kerbl et al. 2023, Sec. 4: "colors
//! represented by spherical harmonics"). Colour = max(0, sum_k Y_k(d) c_k + 0.5) with d
//! the unit direction from the camera centre to the Gaussian's mean.
//!
//! Colour is linear in the coefficients, so everything here is expressed through the
//! basis vector `Y(d)` ([`sh_basis`]): forward is a dot product, the backward pass
//! multiplies the colour gradient by the same basis (zero where the clamp is active).

/// 1 / (2 sqrt(pi)).
pub const C0: f32 = 0.282_094_8;
/// sqrt(3) / (2 sqrt(pi)).
pub const C1: f32 = 0.488_602_5;
/// Degree-2 constants.
pub const C2: [f32; 5] = [
    1.092_548_4,
    -1.092_548_4,
    0.315_391_57,
    -1.092_548_4,
    0.546_274_2,
];
/// Degree-3 constants.
pub const C3: [f32; 7] = [
    -0.590_043_6,
    2.890_611_4,
    -0.457_045_8,
    0.373_176_33,
    -0.457_045_8,
    1.445_305_7,
    -0.590_043_6,
];

/// The SH basis `Y_0..Y_{K-1}` for unit direction `d` and `degree` (K = (degree+1)^2),
/// written into `out[..K]`; entries beyond K are untouched.
#[inline]
pub fn sh_basis(degree: usize, d: [f32; 3], out: &mut [f32; 16]) {
    let [x, y, z] = d;
    out[0] = C0;
    if degree == 0 {
        return;
    }
    out[1] = -C1 * y;
    out[2] = C1 * z;
    out[3] = -C1 * x;
    if degree == 1 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    out[4] = C2[0] * xy;
    out[5] = C2[1] * yz;
    out[6] = C2[2] * (2.0 * zz - xx - yy);
    out[7] = C2[3] * xz;
    out[8] = C2[4] * (xx - yy);
    if degree == 2 {
        return;
    }
    out[9] = C3[0] * y * (3.0 * xx - yy);
    out[10] = C3[1] * xy * z;
    out[11] = C3[2] * y * (4.0 * zz - xx - yy);
    out[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = C3[4] * x * (4.0 * zz - xx - yy);
    out[14] = C3[5] * z * (xx - yy);
    out[15] = C3[6] * x * (xx - 3.0 * yy);
}

/// Unit direction from `from` to `to`; `None` when they coincide or are not finite.
#[inline]
pub fn unit_dir(from: [f32; 3], to: [f32; 3]) -> Option<[f32; 3]> {
    let d = [to[0] - from[0], to[1] - from[1], to[2] - from[2]];
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if n > 0.0 && n.is_finite() {
        Some([d[0] / n, d[1] / n, d[2] / n])
    } else {
        None
    }
}

/// Pre-clamp colour `sum_k Y_k c_k + 0.5` per channel of Gaussian `g` of a scene with
/// `dc` and `rest` (layout of [`crate::Scene::sh_rest`]), `k_rest = K - 1`.
#[inline]
pub fn raw_colour(basis: &[f32; 16], dc: [f32; 3], rest: &[f32], k_rest: usize) -> [f32; 3] {
    let mut c = [
        basis[0] * dc[0] + 0.5,
        basis[0] * dc[1] + 0.5,
        basis[0] * dc[2] + 0.5,
    ];
    // Same association as the INRIA code: the degree-0 term first, then +=.
    for k in 0..k_rest {
        let b = basis[k + 1];
        for ch in 0..3 {
            c[ch] += b * rest[k * 3 + ch];
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real SH basis is orthonormal on the sphere: a Monte-Carlo-free check via a
    /// Fibonacci-sphere quadrature of the Gram matrix (4 pi / n sum Y_i Y_j ≈ delta_ij).
    #[test]
    fn basis_is_orthonormal() {
        let n = 20000;
        let mut gram = [[0.0f64; 16]; 16];
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut b = [0.0f32; 16];
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let th = golden * i as f64;
            let d = [(r * th.cos()) as f32, (r * th.sin()) as f32, z as f32];
            sh_basis(3, d, &mut b);
            for p in 0..16 {
                for q in 0..16 {
                    gram[p][q] += b[p] as f64 * b[q] as f64;
                }
            }
        }
        let w = 4.0 * std::f64::consts::PI / n as f64;
        for p in 0..16 {
            for q in 0..16 {
                let want = if p == q { 1.0 } else { 0.0 };
                assert!(
                    (gram[p][q] * w - want).abs() < 2e-3,
                    "gram[{p}][{q}] = {}",
                    gram[p][q] * w
                );
            }
        }
    }
}
