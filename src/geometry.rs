//! 3-D geometry on [`glam`]: unit vectors, rotations as matrices and quaternions, look-at
//! frames and axis-aligned bounds. The one place for this arithmetic: cameras, scenes, the
//! rasterizer, the metrics' warps and the sample generator all use it.
//!
//! Conventions: double precision ([`DVec3`], [`DMat3`]) for poses; quaternions are
//! `[w, x, y, z]` (Hamilton, as COLMAP and the INRIA `.ply` store them); matrices stored
//! elsewhere as row-major `[[f64; 3]; 3]` convert with [`mat3`] and [`rows`].
//!
//! glam's own `normalize` multiplies by the reciprocal length and its quaternion-to-matrix
//! conversion orders the products differently; [`unit()`] divides and [`quat_to_mat`] keeps
//! COLMAP's `qvec2rotmat` formula, so poses, renders and files stay bit-identical to the
//! values these functions have always produced.

pub use glam::{DMat3, DVec3, Vec3};
use std::ops::{Add, Mul, Sub};

/// `v / |v|` (division, not multiplication by the reciprocal); not checked.
#[inline]
pub fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}

/// `v / |v|`, or `None` when `|v|` is below 1e-12 or not finite.
#[inline]
pub fn normalize(v: DVec3) -> Option<DVec3> {
    let n = v.length();
    (n > 1e-12 && n.is_finite()).then(|| v / n)
}

/// A matrix from row-major rows.
#[inline]
pub fn mat3(rows: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols_array_2d(&rows).transpose()
}

/// The row-major rows of a matrix.
#[inline]
pub fn rows(m: DMat3) -> [[f64; 3]; 3] {
    m.transpose().to_cols_array_2d()
}

/// Rotation matrix of a unit quaternion `[w, x, y, z]` (Hamilton convention, as COLMAP's
/// `qvec2rotmat`). The quaternion is normalised first; `None` when it is zero or not finite.
pub fn quat_to_mat(q: [f64; 4]) -> Option<DMat3> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !n.is_finite() || n < 1e-12 {
        return None;
    }
    let [w, x, y, z] = q.map(|v| v / n);
    Some(mat3(unit_quat_rows(w, x, y, z)))
}

/// The rows of the rotation matrix of the unit quaternion `(w, x, y, z)` (already
/// normalised), in f32 (the projection's lanes) or f64.
#[inline(always)]
pub fn unit_quat_rows<T>(w: T, x: T, y: T, z: T) -> [[T; 3]; 3]
where
    T: Copy + From<f32> + Add<Output = T> + Sub<Output = T> + Mul<Output = T>,
{
    let (one, two) = (T::from(1.0), T::from(2.0));
    [
        [
            one - two * (y * y + z * z),
            two * (x * y - w * z),
            two * (x * z + w * y),
        ],
        [
            two * (x * y + w * z),
            one - two * (x * x + z * z),
            two * (y * z - w * x),
        ],
        [
            two * (x * z - w * y),
            two * (y * z + w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

/// Unit quaternion `[w, x, y, z]`, `w >= 0`, of a rotation matrix (Shepperd's method).
pub fn mat_to_quat(m: DMat3) -> [f64; 4] {
    let r = rows(m);
    let tr = r[0][0] + r[1][1] + r[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
        ]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [
            (r[2][1] - r[1][2]) / s,
            0.25 * s,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            0.25 * s,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            0.25 * s,
        ]
    };
    if q[0] < 0.0 { q.map(|v| -v) } else { q }
}

/// Camera-to-world rotation (columns: camera x right, y down, z forward, OpenCV axes) of a
/// camera at `eye` looking at `target`, with image-down as close to `down` as possible.
pub fn look_at_c2w(eye: DVec3, target: DVec3, down: DVec3) -> DMat3 {
    let z = normalize(target - eye).unwrap_or(DVec3::Z);
    let proj = |d: DVec3| normalize(d - d.dot(z) * z);
    let y = proj(down).or_else(|| proj(DVec3::Z)).unwrap_or(DVec3::Y);
    let x = y.cross(z);
    DMat3::from_cols(x, y, z)
}

/// Axis-aligned bounds `[min, max]` of a point set; empty when `min > max` on an axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    pub min: Vec3,
    pub max: Vec3,
}

impl Bounds {
    /// The bounds of no points (`min = +inf`, `max = -inf`).
    pub const EMPTY: Bounds = Bounds {
        min: Vec3::INFINITY,
        max: Vec3::NEG_INFINITY,
    };

    /// The bounds of `points`.
    pub fn of_points<'a>(points: impl IntoIterator<Item = &'a [f32; 3]>) -> Bounds {
        let mut b = Bounds::EMPTY;
        for p in points {
            for k in 0..3 {
                b.min[k] = b.min[k].min(p[k]);
                b.max[k] = b.max[k].max(p[k]);
            }
        }
        b
    }

    /// True when no point was added.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|k| self.min[k] > self.max[k])
    }

    /// Centre `(min + max) / 2`, in f64.
    pub fn center(&self) -> DVec3 {
        DVec3::from_array([0, 1, 2].map(|i| 0.5 * (self.min[i] as f64 + self.max[i] as f64)))
    }

    /// The largest extent `max - min` over the axes, in f64 (0 for a single point).
    pub fn largest_extent(&self) -> f64 {
        (0..3)
            .map(|i| self.max[i] as f64 - self.min[i] as f64)
            .fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_matrix_is_a_rotation_and_round_trips() {
        let r = quat_to_mat([0.3, -0.2, 0.9, 0.1]).unwrap();
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        // 90 degrees about z: x -> y.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let r = quat_to_mat([h, 0.0, 0.0, h]).unwrap();
        let v = r * DVec3::X;
        assert!((v.y - 1.0).abs() < 1e-12 && v.x.abs() < 1e-12);
        assert!(quat_to_mat([0.0; 4]).is_none());
        assert!(quat_to_mat([f64::NAN, 0.0, 0.0, 1.0]).is_none());
        for q in [
            [0.9, 0.1, -0.3, 0.2],
            [0.1, 0.9, 0.2, -0.3],
            [0.1, 0.2, 0.9, 0.3],
            [0.1, -0.2, 0.3, 0.9],
        ] {
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let back = mat_to_quat(quat_to_mat(q).unwrap());
            for k in 0..4 {
                assert!((back[k] - q[k] / n).abs() < 1e-12, "{q:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn quaternion_round_trip_colmap_cases() {
        for q in [
            [1.0, 0.0, 0.0, 0.0],
            [0.1, 0.9, -0.3, 0.2],
            [0.0, 0.0, 1.0, 0.0],
            [0.2, 0.1, 0.1, -0.95],
        ] {
            let n = (q.iter().map(|v: &f64| v * v).sum::<f64>()).sqrt();
            let q = q.map(|v| v / n);
            let back = mat_to_quat(quat_to_mat(q).unwrap());
            let s = if back[0] * q[0] + back[1] * q[1] + back[2] * q[2] + back[3] * q[3] < 0.0 {
                -1.0
            } else {
                1.0
            };
            for k in 0..4 {
                assert!((back[k] * s - q[k]).abs() < 1e-12, "{q:?} {back:?}");
            }
        }
    }

    #[test]
    fn row_major_conversion_and_hand_formulas() {
        let m = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]];
        assert_eq!(rows(mat3(m)), m);
        // mat3 * v is row . v
        let v = mat3(m) * DVec3::new(1.0, 0.0, -1.0);
        assert_eq!(v, DVec3::new(-2.0, -2.0, -2.0));
        let a = DVec3::new(0.3, -1.7, 2.9);
        let b = DVec3::new(-4.1, 0.2, 1.3);
        // The hand-written formulas these replace, bit for bit.
        let cross = [
            a.y * b.z - a.z * b.y,
            a.z * b.x - a.x * b.z,
            a.x * b.y - a.y * b.x,
        ];
        assert_eq!(a.cross(b).to_array(), cross);
        assert_eq!(a.dot(b), a.x * b.x + a.y * b.y + a.z * b.z);
        let n = (a.x * a.x + a.y * a.y + a.z * a.z).sqrt();
        assert_eq!(unit(a).to_array(), [a.x / n, a.y / n, a.z / n]);
        assert_eq!(normalize(a), Some(unit(a)));
        assert_eq!(normalize(DVec3::ZERO), None);
    }

    #[test]
    fn look_at_frame_is_a_rotation_looking_at_the_target() {
        let eye = DVec3::new(1.0, -2.0, -3.0);
        let target = DVec3::new(0.2, 0.1, 0.3);
        let m = look_at_c2w(eye, target, DVec3::Y);
        assert!((m.determinant() - 1.0).abs() < 1e-12);
        let fwd = m.z_axis;
        assert!((fwd - unit(target - eye)).length() < 1e-12);
        // image down (camera +y) leans toward world +y
        assert!(m.y_axis.y > 0.0);
    }

    #[test]
    fn bounds_of_points() {
        let b = Bounds::of_points(&[[-1.0, -0.5, 0.0], [1.0, 0.5, 0.4]]);
        assert_eq!(b.center(), DVec3::new(0.0, 0.0, 0.5 * (0.4f32 as f64)));
        assert_eq!(b.largest_extent(), 2.0);
        assert!(!b.is_empty());
        assert!(Bounds::of_points(&[]).is_empty());
    }
}
