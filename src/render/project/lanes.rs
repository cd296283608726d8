//! The f32 lane path: eight Gaussians at a time, branch-free per lane so that the loops
//! vectorise, with the lanes the f32 arithmetic cannot represent handed to the f64 path.

use super::camera::{Cam, CamF};
use super::fastmath::{exp_f32, ln_f32};
use super::reference::project_one_f64;
use super::screen::{Screen, finish};
use super::{ALPHA_MIN, BoxMargin, DILATION, NEAR, One};
use crate::Scene;

/// Gaussians per lane block.
const LANES: usize = 8;

/// Per-lane results of the vectorised part.
#[derive(Default)]
struct LaneOut {
    /// 0: culled for good; 1: projected in f32; 2: redo in f64.
    state: [u8; LANES],
    mean: [[f32; LANES]; 2],
    conic: [[f32; LANES]; 3],
    cov: [[f32; LANES]; 2],
    radius: [f32; LANES],
    level: [f32; LANES],
    cond: [f32; LANES],
    opacity: [f32; LANES],
    depth: [f32; LANES],
}

/// The lane inputs of Gaussians `lo..lo + LANES`, one array per component: positions,
/// rotations, log-scales, opacity logits.
#[inline(always)]
#[allow(clippy::type_complexity)]
fn gather_lanes(
    scene: &Scene,
    lo: usize,
) -> (
    [[f32; LANES]; 3],
    [[f32; LANES]; 4],
    [[f32; LANES]; 3],
    [f32; LANES],
) {
    let mut p = [[0.0f32; LANES]; 3];
    let mut q = [[0.0f32; LANES]; 4];
    let mut ls = [[0.0f32; LANES]; 3];
    let mut logit = [0.0f32; LANES];
    for l in 0..LANES {
        let i = lo + l;
        let (pp, qq, ll) = (scene.positions[i], scene.rotations[i], scene.log_scales[i]);
        for k in 0..3 {
            p[k][l] = pp[k];
            ls[k][l] = ll[k];
        }
        for k in 0..4 {
            q[k][l] = qq[k];
        }
        logit[l] = scene.opacity_logits[i];
    }
    (p, q, ls, logit)
}

/// `U = J W R S` (2x3) from the Jacobian's non-zero entries `[j00, j02, j11, j12]`, the
/// camera rotation `r`, the Gaussian's rotation `rq` and scales `s`.
#[inline(always)]
fn jwrs_f32(r: &[[f32; 3]; 3], j: [f32; 4], rq: &[[f32; 3]; 3], s: [f32; 3]) -> [[f32; 3]; 2] {
    let [j00, j02, j11, j12] = j;
    let mut tw = [[0.0f32; 3]; 2];
    for b in 0..3 {
        tw[0][b] = j00 * r[0][b] + j02 * r[2][b];
        tw[1][b] = j11 * r[1][b] + j12 * r[2][b];
    }
    let mut u = [[0.0f32; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            u[a][b] = (tw[a][0] * rq[0][b] + tw[a][1] * rq[1][b] + tw[a][2] * rq[2][b]) * s[b];
        }
    }
    u
}

/// The screen-space covariance `[a, b, c]` of `U U^T` dilated by `dil`, and its
/// determinant (Lagrange's identity: the cross product of U's rows, free of the
/// cancellation in `a c - b^2`).
#[inline(always)]
fn cov2d_f32(u: &[[f32; 3]; 2], dil: f32) -> [f32; 4] {
    let n0 = u[0][0] * u[0][0] + u[0][1] * u[0][1] + u[0][2] * u[0][2];
    let n1 = u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2];
    let cb = u[0][0] * u[1][0] + u[0][1] * u[1][1] + u[0][2] * u[1][2];
    let cross = [
        u[0][1] * u[1][2] - u[0][2] * u[1][1],
        u[0][2] * u[1][0] - u[0][0] * u[1][2],
        u[0][0] * u[1][1] - u[0][1] * u[1][0],
    ];
    let ca = n0 + dil;
    let cc = n1 + dil;
    let det = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
        + dil * (n0 + n1)
        + dil * dil;
    [ca, cb, cc, det]
}

/// The f32 arithmetic of `LANES` Gaussians `lo..lo + LANES` (all present). Branch-free
/// per lane so that the loops vectorise.
#[inline(always)]
fn lanes(scene: &Scene, cam: &CamF, lo: usize, out: &mut LaneOut) {
    let (p, q, ls, logit) = gather_lanes(scene, lo);
    let r = &cam.r;
    let near = NEAR as f32;
    let dil = DILATION as f32;
    for l in 0..LANES {
        let (px, py, pz) = (p[0][l], p[1][l], p[2][l]);
        let tx = r[0][0] * px + r[0][1] * py + r[0][2] * pz + cam.t[0];
        let ty = r[1][0] * px + r[1][1] * py + r[1][2] * pz + cam.t[1];
        let tz = r[2][0] * px + r[2][1] * py + r[2][2] * pz + cam.t[2];
        let t_ok = tx.is_finite() & ty.is_finite() & tz.is_finite();
        let front = tz >= near;
        let opacity = 1.0 / (1.0 + exp_f32(-logit[l]));
        let visible = opacity >= ALPHA_MIN;
        // Rotation from the normalised quaternion (w, x, y, z).
        let (qw, qx, qy, qz) = (q[0][l], q[1][l], q[2][l], q[3][l]);
        let qn = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
        let q_finite = qn.is_finite();
        let q_ok = qn >= 1e-12;
        let inv = 1.0 / qn;
        let (w, x, y, z) = (qw * inv, qx * inv, qy * inv, qz * inv);
        let rq = crate::geometry::unit_quat_rows(w, x, y, z);
        let s = [exp_f32(ls[0][l]), exp_f32(ls[1][l]), exp_f32(ls[2][l])];
        // The polynomial exp clamps at 88; a larger log-scale is left to the f64 path.
        let s_ok = (ls[0][l] < 88.0) & (ls[1][l] < 88.0) & (ls[2][l] < 88.0);
        // Jacobian with the guard-band clamp; z is at least NEAR where it matters.
        let zc = tz.max(near);
        let txc = zc * (tx / zc).clamp(-cam.lim_x_neg, cam.lim_x_pos);
        let tyc = zc * (ty / zc).clamp(-cam.lim_y_neg, cam.lim_y_pos);
        let j00 = cam.fx / zc;
        let j02 = -cam.fx * txc / (zc * zc);
        let j11 = cam.fy / zc;
        let j12 = -cam.fy * tyc / (zc * zc);
        // T = J W (2x3), then U = T R S (2x3).
        let u = jwrs_f32(r, [j00, j02, j11, j12], &rq, s);
        let [ca, cb, cc, det] = cov2d_f32(&u, dil);
        let conic = [cc / det, -cb / det, ca / det];
        let mx = cam.fx * tx / zc + cam.cx;
        let my = cam.fy * ty / zc + cam.cy;
        let mid = 0.5 * (ca + cc);
        let half_diff = 0.5 * (ca - cc);
        let lambda = mid + (half_diff * half_diff + cb * cb).max(0.1).sqrt();
        let radius = (3.0 * lambda.sqrt()).ceil();
        let level = ln_f32((opacity / ALPHA_MIN).max(1.0)).max(0.0);
        let geo_ok = (det > 0.0)
            & det.is_finite()
            & conic[0].is_finite()
            & conic[1].is_finite()
            & conic[2].is_finite()
            & mx.is_finite()
            & my.is_finite()
            & radius.is_finite()
            & (ca * cc).is_finite()
            & (2.0 * (level + 1e-3) * ca).is_finite()
            & (2.0 * (level + 1e-3) * cc).is_finite();
        // Clean culls first (behind the camera, transparent, zero quaternion); then
        // anything the f32 arithmetic could not represent goes to the f64 path.
        let culled = t_ok & (!front | (front & !visible) | (front & visible & q_finite & !q_ok));
        let projected = t_ok & front & visible & q_finite & q_ok & s_ok & geo_ok;
        out.state[l] = if culled {
            0
        } else if projected {
            1
        } else {
            2
        };
        out.mean[0][l] = mx;
        out.mean[1][l] = my;
        out.conic[0][l] = conic[0];
        out.conic[1][l] = conic[1];
        out.conic[2][l] = conic[2];
        out.cov[0][l] = ca;
        out.cov[1][l] = cc;
        out.radius[l] = radius;
        out.level[l] = level;
        out.cond[l] = ca * cc / det;
        out.opacity[l] = opacity;
        out.depth[l] = tz;
    }
}

/// Project Gaussians `lo..hi`, keeping the survivors in order.
///
/// On x86-64 CPUs with AVX2 and FMA this runs a copy compiled with those features (8
/// lanes per instruction; `floor`/`ceil` become single instructions). Rust never fuses
/// `a * b + c`, so both copies give identical bits.
pub(super) fn project_range(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        return unsafe { project_range_avx2(scene, cam, camf, m, lo, hi) };
    }
    project_range_impl(scene, cam, camf, m, lo, hi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_range_avx2(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    project_range_impl(scene, cam, camf, m, lo, hi)
}

#[inline(always)]
fn project_range_impl(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    let mut out = Vec::with_capacity(hi - lo);
    let mut lane = LaneOut::default();
    let mut i = lo;
    while i + LANES <= hi {
        lanes(scene, camf, i, &mut lane);
        for l in 0..LANES {
            let id = i + l;
            let o = match lane.state[l] {
                0 => None,
                1 => finish(
                    m,
                    id as u32,
                    &Screen {
                        mean: [lane.mean[0][l], lane.mean[1][l]],
                        cov_a: lane.cov[0][l],
                        cov_c: lane.cov[1][l],
                        radius: lane.radius[l],
                        level: lane.level[l],
                        cond: lane.cond[l],
                    },
                    [lane.conic[0][l], lane.conic[1][l], lane.conic[2][l]],
                    lane.opacity[l],
                    lane.depth[l],
                    cam.width,
                    cam.height,
                ),
                _ => project_one_f64(scene, cam, m, id),
            };
            out.extend(o);
        }
        i += LANES;
    }
    // The last few Gaussians of the scene: f64.
    for id in i..hi {
        out.extend(project_one_f64(scene, cam, m, id));
    }
    out
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::project::BOX_MARGIN;
    use crate::render::tests::{front_camera, random_scene};

    /// The f32 lanes against the f64 path on random scenes and cameras: the same
    /// Gaussians survive (up to threshold cases), means within 1e-4 px, conics and
    /// opacities within 1e-5 relative, identical or neighbouring tiles.
    #[test]
    fn f32_lanes_agree_with_f64() {
        let mut checked = 0;
        for seed in 0..6 {
            let scene = random_scene(4000, 1, 100 + seed);
            let cam_c = front_camera(160, 120, 140.0, 2.0 + seed as f32 * 0.3);
            let cam = Cam::new(&cam_c);
            let camf = CamF::new(&cam);
            let fast = project_range_impl(&scene, &cam, &camf, BOX_MARGIN, 0, scene.len());
            let slow: Vec<One> = (0..scene.len())
                .filter_map(|i| project_one_f64(&scene, &cam, BOX_MARGIN, i))
                .collect();
            let diff = fast.len().abs_diff(slow.len());
            assert!(diff <= 2, "{} vs {} survivors", fast.len(), slow.len());
            let mut j = 0;
            for a in &fast {
                while j < slow.len() && slow[j].id < a.id {
                    j += 1;
                }
                let Some(b) = slow.get(j).filter(|b| b.id == a.id) else {
                    continue;
                };
                for k in 0..2 {
                    assert!((a.rec.mean[k] - b.rec.mean[k]).abs() < 1e-4, "{a:?} {b:?}");
                }
                for k in 0..3 {
                    let tol = 1e-5 * (b.rec.conic[0].abs() + b.rec.conic[2].abs());
                    assert!(
                        (a.rec.conic[k] - b.rec.conic[k]).abs() <= tol,
                        "{a:?} {b:?}"
                    );
                }
                assert!((a.rec.opacity - b.rec.opacity).abs() <= 1e-6);
                assert!((a.rec.power_floor - b.rec.power_floor).abs() <= 1e-5);
                for k in 0..4 {
                    assert!(a.tiles[k].abs_diff(b.tiles[k]) <= 1, "{a:?} {b:?}");
                }
                assert!((a.depth - b.depth).abs() <= 1e-6 * b.depth);
                checked += 1;
            }
        }
        assert!(checked > 10_000, "{checked}");
    }

    /// Lanes that overflow in f32 are projected by the f64 path: a Gaussian of scale
    /// e^40 covers the whole image instead of being culled.
    #[test]
    fn overflowing_lanes_fall_back_to_f64() {
        let mut scene = random_scene(16, 0, 7);
        scene.log_scales[3] = [40.0, 40.0, 40.0];
        scene.opacity_logits[3] = 5.0;
        let c = front_camera(64, 48, 60.0, 3.0);
        let cam = Cam::new(&c);
        let fast = project_range_impl(&scene, &cam, &CamF::new(&cam), BOX_MARGIN, 0, 16);
        let big = fast.iter().find(|o| o.id == 3).expect("huge Gaussian kept");
        assert_eq!(big.tiles, [0, 0, 4, 3]);
        assert_eq!(Some(*big), project_one_f64(&scene, &cam, BOX_MARGIN, 3));
    }
}
