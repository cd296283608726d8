//! The f64 path: the fallback for Gaussians whose f32 evaluation overflows or meets a
//! non-finite value, and the reference the f32 lanes are tested against.

use super::camera::Cam;
use super::screen::{Screen, finish};
use super::{ALPHA_MIN, BoxMargin, DILATION, NEAR, One};
use crate::Scene;

/// The screen-space covariance `[a, b, c]` (dilated) of Gaussian `i` at camera-space
/// position `t`, in f64: `J W R S (J W R S)^T`; `None` for a degenerate rotation.
fn cov2d_f64(scene: &Scene, cam: &Cam, i: usize, t: [f64; 3]) -> Option<[f64; 3]> {
    let r = &cam.r;
    let rq = crate::geometry::rows(crate::geometry::quat_to_mat(
        scene.rotations[i].map(f64::from),
    )?);
    let ls = scene.log_scales[i];
    let s = [
        (ls[0] as f64).exp(),
        (ls[1] as f64).exp(),
        (ls[2] as f64).exp(),
    ];
    let mut m = [[0.0f64; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            m[a][b] = rq[a][b] * s[b];
        }
    }
    let z = t[2];
    let tx = z * (t[0] / z).clamp(-cam.lim_x_neg, cam.lim_x_pos);
    let ty = z * (t[1] / z).clamp(-cam.lim_y_neg, cam.lim_y_pos);
    let j = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    let mut tw = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            tw[a][b] = j[a][0] * r[0][b] + j[a][1] * r[1][b] + j[a][2] * r[2][b];
        }
    }
    let mut u = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            u[a][b] = tw[a][0] * m[0][b] + tw[a][1] * m[1][b] + tw[a][2] * m[2][b];
        }
    }
    let ca = u[0][0] * u[0][0] + u[0][1] * u[0][1] + u[0][2] * u[0][2] + DILATION;
    let cb = u[0][0] * u[1][0] + u[0][1] * u[1][1] + u[0][2] * u[1][2];
    let cc = u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2] + DILATION;
    Some([ca, cb, cc])
}

/// Project Gaussian `i` in f64; `None` when culled. The slow path: used where the f32
/// lanes overflow, and as the reference in tests.
pub(super) fn project_one_f64(
    scene: &Scene,
    cam: &Cam,
    margin: BoxMargin,
    i: usize,
) -> Option<One> {
    let p = scene.positions[i];
    let p = [p[0] as f64, p[1] as f64, p[2] as f64];
    let r = &cam.r;
    let t = [
        r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + cam.t[0],
        r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + cam.t[1],
        r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + cam.t[2],
    ];
    // Written so that NaN is rejected too.
    let in_front = t[2] >= NEAR && t.iter().all(|v| v.is_finite());
    if !in_front {
        return None;
    }
    let opacity = 1.0 / (1.0 + (-(scene.opacity_logits[i] as f64)).exp());
    if opacity.is_nan() || opacity < ALPHA_MIN as f64 {
        return None;
    }
    let [ca, cb, cc] = cov2d_f64(scene, cam, i, t)?;
    let z = t[2];
    let det = ca * cc - cb * cb;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let conic = [cc / det, -cb / det, ca / det];
    let mx = cam.fx * t[0] / z + cam.cx;
    let my = cam.fy * t[1] / z + cam.cy;
    if !mx.is_finite() || !my.is_finite() {
        return None;
    }
    let mid = 0.5 * (ca + cc);
    let lambda = mid + (mid * mid - det).max(0.1).sqrt();
    let radius = (3.0 * lambda.sqrt()).ceil();
    let level = (opacity / ALPHA_MIN as f64).ln().max(0.0);
    let screen = Screen {
        mean: [mx as f32, my as f32],
        cov_a: ca as f32,
        cov_c: cc as f32,
        radius: radius as f32,
        level: level as f32,
        cond: (ca * cc / det) as f32,
    };
    // Values beyond f32 (a Gaussian larger than any image by far) are clamped so that
    // the tail still sees a huge, finite splat.
    let big = |v: f32| if v.is_finite() { v } else { f32::MAX };
    let screen = Screen {
        cov_a: big(screen.cov_a),
        cov_c: big(screen.cov_c),
        radius: big(screen.radius),
        cond: big(screen.cond),
        ..screen
    };
    finish(
        margin,
        i as u32,
        &screen,
        conic.map(|v| v as f32),
        opacity as f32,
        z as f32,
        cam.width,
        cam.height,
    )
}
