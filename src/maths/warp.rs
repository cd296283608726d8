//! Depth reprojection: warp one rendered view into another with the rendered depth and
//! the known cameras, so view consistency needs no optical flow (FantasyStyle's
//! experiments measure short- and long-range consistency on warped view pairs).
//!
//! Depth convention: the `views` artifact's `depth.npy` is the *expected* depth
//! `sum_i w_i z_i` of the alpha-blended Gaussians, not normalised by the accumulated
//! alpha. The surface depth is `depth / alpha`, used only where `alpha > 0.5`
//! ([`ALPHA_MIN`]); elsewhere the pixel has no reliable surface and is masked.
//!
//! Backward warp of source view `s` into destination view `d`: for each destination pixel
//! with a surface, unproject its centre `(x + 0.5, y + 0.5)` (OpenCV pinhole, the
//! rasterizer's pixel-centre convention) to a world point, project it into `s`; it is
//! valid when it lands inside `s` (bilinear support), in front of the camera, on pixels
//! that all have a surface, and passes the occlusion test
//! `|z_s(point) - depth_s(u, v)| <= 3% z_s(point)` ([`DEPTH_REL_TOL`]) — a point hidden
//! behind something nearer in `s` fails it. Valid pixels take the bilinear sample of the
//! source image; invalid ones are masked out of every consistency measure.

use crate::Camera;
use crate::imageio::Image;

/// Pixels with accumulated alpha at or below this have no surface depth.
pub const ALPHA_MIN: f32 = 0.5;
/// Relative depth tolerance of the occlusion test.
pub const DEPTH_REL_TOL: f64 = 0.03;

/// Surface depth `depth / alpha` where `alpha > ALPHA_MIN`, NaN elsewhere.
pub fn surface_depth(depth: &[f32], alpha: &[f32]) -> Vec<f32> {
    depth
        .iter()
        .zip(alpha)
        .map(|(&d, &a)| {
            if a > ALPHA_MIN && d > 0.0 {
                d / a
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// A warped image in the destination frame and its validity mask (1 valid, 0 not).
#[derive(Debug, Clone)]
pub struct Warped {
    pub image: Image,
    pub mask: Vec<f32>,
    pub valid: usize,
}

impl Warped {
    pub fn valid_fraction(&self) -> f64 {
        self.valid as f64 / self.mask.len().max(1) as f64
    }
}

/// Warp `src_img` (view `src_cam`, surface depth `src_z`) into the frame of `dst_cam`
/// (surface depth `dst_z`). Depths are from [`surface_depth`]; images share one size.
pub fn warp_into(
    dst_cam: &Camera,
    dst_z: &[f32],
    src_cam: &Camera,
    src_z: &[f32],
    src_img: &Image,
) -> Warped {
    warp_with_tolerance(dst_cam, dst_z, src_cam, src_z, src_img, DEPTH_REL_TOL)
}

/// [`warp_into`] with a given relative depth tolerance (`f64::INFINITY` disables the
/// occlusion test; the tests use that to show it matters).
pub fn warp_with_tolerance(
    dst_cam: &Camera,
    dst_z: &[f32],
    src_cam: &Camera,
    src_z: &[f32],
    src_img: &Image,
    depth_rel_tol: f64,
) -> Warped {
    let (w, h) = (src_img.width, src_img.height);
    let (rs, ts) = src_cam.w2c();
    let unproject = dst_cam.unprojector();
    let (sfx, sfy, scx, scy) = (
        src_cam.fx as f64,
        src_cam.fy as f64,
        src_cam.cx as f64,
        src_cam.cy as f64,
    );
    let mut image = Image::filled(w, h, [0.0; 3]);
    let mut mask = vec![0.0f32; w * h];
    let mut valid = 0;
    for y in 0..h {
        for x in 0..w {
            let z = dst_z[y * w + x] as f64;
            if !z.is_finite() {
                continue;
            }
            // destination pixel centre -> world -> source camera
            let p = unproject(x as f64 + 0.5, y as f64 + 0.5, z);
            let q = rs * p + ts;
            if q.z <= 1e-9 {
                continue;
            }
            let u = sfx * q.x / q.z + scx - 0.5;
            let v = sfy * q.y / q.z + scy - 0.5;
            // Inside the bilinear support of the source pixel centres (a rounding-level
            // excess, as in a view warped into itself, is snapped back).
            const SNAP: f64 = 1e-3;
            let (wl, hl) = ((w - 1) as f64, (h - 1) as f64);
            if !(u >= -SNAP && v >= -SNAP && u <= wl + SNAP && v <= hl + SNAP) {
                continue;
            }
            let (uc, vc) = (u.clamp(0.0, (w - 1) as f64), v.clamp(0.0, (h - 1) as f64));
            let (x0, y0) = (uc.floor() as usize, vc.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = (uc - x0 as f64, vc - y0 as f64);
            // Bilinear source depth over the neighbours that carry weight; all of them
            // must have a surface.
            let nb = [
                (x0, y0, (1.0 - fx) * (1.0 - fy)),
                (x1, y0, fx * (1.0 - fy)),
                (x0, y1, (1.0 - fx) * fy),
                (x1, y1, fx * fy),
            ];
            let (mut zsum, mut wsum, mut ok) = (0.0, 0.0, true);
            for (nx, ny, wt) in nb {
                if wt <= 1e-6 {
                    continue;
                }
                let zn = src_z[ny * w + nx];
                if !zn.is_finite() {
                    ok = false;
                    break;
                }
                zsum += wt * zn as f64;
                wsum += wt;
            }
            if !ok || wsum <= 0.0 {
                continue;
            }
            let zsrc = zsum / wsum;
            if (q.z - zsrc).abs() > depth_rel_tol * q.z {
                continue;
            }
            let (u, v) = (uc, vc);
            let col = src_img.sample(u, v);
            let i = (y * w + x) * 3;
            image.data[i..i + 3].copy_from_slice(&col);
            mask[y * w + x] = 1.0;
            valid += 1;
        }
    }
    Warped { image, mask, valid }
}

/// A pinhole camera at `eye` looking at `target`, image-down as close to world `-z` as
/// possible (`-y` when looking nearly straight up or down;
/// [`crate::geometry::look_at_c2w`]), focal length `f` pixels, principal point
/// at the image centre. For synthetic cases.
pub fn look_at(
    name: &str,
    eye: [f64; 3],
    target: [f64; 3],
    width: u32,
    height: u32,
    f: f64,
) -> Camera {
    use crate::geometry::{DVec3, look_at_c2w, rows, unit};
    let (eye_v, target_v) = (DVec3::from_array(eye), DVec3::from_array(target));
    // Image-down along world -z, or -y when looking (nearly) straight up or down.
    let down = if unit(target_v - eye_v).z.abs() > 0.99 {
        -DVec3::Y
    } else {
        -DVec3::Z
    };
    let c2w = look_at_c2w(eye_v, target_v, down);
    Camera::from_c2w(
        name.into(),
        width,
        height,
        [f, f, 0.5 * width as f64, 0.5 * height as f64],
        rows(c2w),
        eye,
    )
}

/// Synthetic scenes rendered analytically (ray casting): a textured ground plane `z = 0`
/// and optionally a flat square occluder at height `occluder_z`. Returns (image, depth,
/// alpha) with the depth in the artifact convention (expected depth = surface depth x
/// alpha, alpha = 1 on hits). Used by the warp tests and by the evaluate tests.
pub mod synthetic {
    use super::*;

    /// Texture of the ground plane at world `(x, y)`.
    pub fn ground(x: f64, y: f64) -> [f32; 3] {
        [
            (0.5 + 0.35 * (0.9 * x).sin() * (0.6 * y).cos()) as f32,
            (0.5 + 0.35 * (0.7 * y + 0.4).sin()) as f32,
            (0.5 + 0.25 * (0.5 * (x + y)).cos()) as f32,
        ]
    }

    pub const OCCLUDER_RGB: [f32; 3] = [0.95, 0.1, 0.1];

    /// Ray-cast camera `cam`; the occluder is the square `|x|, |y| < half` at height `z`.
    pub fn render(cam: &Camera, occluder: Option<(f64, f64)>) -> (Image, Vec<f32>, Vec<f32>) {
        let (w, h) = (cam.width as usize, cam.height as usize);
        let unproject = cam.unprojector();
        let eye = unproject(cam.cx as f64, cam.cy as f64, 0.0);
        let mut img = Image::filled(w, h, [0.0; 3]);
        let mut depth = vec![0.0f32; w * h];
        let mut alpha = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                // world direction with unit camera-z: points are eye + s * d, camera depth s
                let d = unproject(x as f64 + 0.5, y as f64 + 0.5, 1.0) - eye;
                let hit = |zp: f64| {
                    let s = (zp - eye.z) / d.z;
                    (s > 1e-6).then_some((s, eye.x + s * d.x, eye.y + s * d.y))
                };
                let mut best: Option<(f64, [f32; 3])> =
                    hit(0.0).map(|(s, px, py)| (s, ground(px, py)));
                if let Some((zo, half)) = occluder
                    && let Some((s, px, py)) = hit(zo)
                    && px.abs() < half
                    && py.abs() < half
                    && best.is_none_or(|(b, _)| s < b)
                {
                    best = Some((s, OCCLUDER_RGB));
                }
                if let Some((s, col)) = best {
                    let i = y * w + x;
                    img.data[i * 3..i * 3 + 3].copy_from_slice(&col);
                    depth[i] = s as f32;
                    alpha[i] = 1.0;
                }
            }
        }
        (img, depth, alpha)
    }
}

#[cfg(test)]
mod tests {
    use super::synthetic::*;
    use super::*;

    fn max_err_where(a: &Image, b: &Image, mask: &[f32]) -> f32 {
        let mut e = 0.0f32;
        for (p, m) in mask.iter().enumerate() {
            if *m > 0.0 {
                for c in 0..3 {
                    e = e.max((a.data[p * 3 + c] - b.data[p * 3 + c]).abs());
                }
            }
        }
        e
    }

    #[test]
    fn surface_depth_divides_by_alpha_and_masks_low_alpha() {
        let z = surface_depth(&[2.0, 1.0, 0.3, 0.0], &[1.0, 0.5, 0.6, 1.0]);
        assert_eq!(z[0], 2.0);
        assert!(z[1].is_nan()); // alpha 0.5 is not > 0.5
        assert!((z[2] - 0.5).abs() < 1e-6);
        assert!(z[3].is_nan());
    }

    #[test]
    fn a_view_warped_into_itself_is_the_identity() {
        let cam = look_at("a", [1.0, -3.0, 2.5], [0.0, 0.0, 0.0], 64, 48, 50.0);
        let (img, depth, alpha) = render(&cam, Some((0.6, 0.4)));
        let z = surface_depth(&depth, &alpha);
        let wp = warp_into(&cam, &z, &cam, &z, &img);
        let hits = alpha.iter().filter(|a| **a > 0.5).count();
        assert_eq!(wp.valid, hits, "every surface pixel maps onto itself");
        let e = max_err_where(&wp.image, &img, &wp.mask);
        eprintln!(
            "identity warp: max error {e:.2e}, {} of {hits} surface pixels valid",
            wp.valid
        );
        assert!(e < 1e-4, "identity warp error {e}");
    }

    #[test]
    fn two_views_of_a_textured_plane_agree_where_both_see_it() {
        let a = look_at("a", [0.5, -2.5, 3.0], [0.0, 0.0, 0.0], 80, 60, 60.0);
        let b = look_at("b", [-0.8, -2.2, 3.3], [0.1, 0.2, 0.0], 80, 60, 60.0);
        let (ia, da, aa) = render(&a, None);
        let (ib, db, ab) = render(&b, None);
        let (za, zb) = (surface_depth(&da, &aa), surface_depth(&db, &ab));
        let wp = warp_into(&a, &za, &b, &zb, &ib);
        assert!(wp.valid_fraction() > 0.5, "overlap {}", wp.valid_fraction());
        let e = max_err_where(&wp.image, &ia, &wp.mask);
        // Residual = bilinear interpolation of a smooth texture sampled at pixel centres.
        eprintln!(
            "plane warp: max error {e:.2e}, overlap {:.3}",
            wp.valid_fraction()
        );
        assert!(e < 5e-3, "plane warp error {e}");
        // A camera that looks elsewhere gives no overlap.
        let c = look_at("c", [0.0, 30.0, 2.0], [0.0, 60.0, 0.0], 80, 60, 60.0);
        let (ic, dc, ac) = render(&c, None);
        let wc = warp_into(&a, &za, &c, &surface_depth(&dc, &ac), &ic);
        assert_eq!(wc.valid, 0);
    }

    #[test]
    fn occluded_points_are_masked_by_the_depth_test() {
        // a looks from above, b from low at the side: the occluder hides ground from b
        // that a sees.
        let a = look_at("a", [0.0, -0.5, 4.0], [0.0, 0.0, 0.0], 80, 60, 55.0);
        let b = look_at("b", [3.0, -0.3, 1.2], [0.0, 0.0, 0.2], 80, 60, 55.0);
        let occ = Some((0.8, 0.35));
        let (ia, da, aa) = render(&a, occ);
        let (ib, db, ab) = render(&b, occ);
        let (za, zb) = (surface_depth(&da, &aa), surface_depth(&db, &ab));
        let wp = warp_into(&a, &za, &b, &zb, &ib);
        assert!(wp.valid > 500);
        let e = max_err_where(&wp.image, &ia, &wp.mask);
        eprintln!("occluder warp: max error on valid pixels {e:.2e}");
        assert!(
            e < 2e-2,
            "max error on valid pixels {e} (an occlusion leak would be ~1)"
        );
        // Without the depth test, ground pixels of `a` hidden in `b` take the occluder's red.
        let leaky = warp_with_tolerance(&a, &za, &b, &zb, &ib, f64::INFINITY);
        let leaks = (0..leaky.mask.len())
            .filter(|&p| {
                leaky.mask[p] > 0.0
                    && (0..3)
                        .any(|c| (leaky.image.data[p * 3 + c] - ia.data[p * 3 + c]).abs() > 0.3)
            })
            .count();
        assert!(
            leaks > 20,
            "the configuration must have occluded pixels: {leaks}"
        );
        assert!(leaky.valid > wp.valid + leaks / 2);
    }
}
