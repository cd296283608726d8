//! Style projection (not part of FantasyStyle): the style image texture-mapped onto the
//! object by triplanar projection, written into the Gaussians' DC colours. No network, no
//! optimisation: well under a second. A baseline (`stylize-baseline --method project`) and
//! a start for the distillation (`distill --project-style`).
//!
//! Why: a texture statistic inside the loop (NNFM, Gram; [`crate::distill::texture`]) and
//! the 2D stylizer both ask each view for motifs where that view's content puts them, and
//! views 22-45 degrees apart disagree, so bands and rings average into blobs of the style's
//! colours (BENCHMARKS.md "Style projection"). A motif painted once on the surface is the
//! same motif from every view by construction; the loop then refines it.
//!
//! **Normals.** A trained splat's Gaussians are flat (the plant's median ratio of largest
//! to smallest scale is 11): the axis of the smallest scale is the surface normal, as 2DGS
//! and GaussianShader take it. It is the rotation matrix's column of that axis. Where the
//! two smallest scales are close (a needle, or a round blob: 19% of the plant's Gaussians
//! have them within 1.5x) the normal is ill-defined and the plane it picks is arbitrary;
//! no neighbourhood estimate is made.
//!
//! **Triplanar mapping** (the terrain-texturing technique of GPU Gems 3, ch. 1): the
//! Gaussian's mean is projected on the three axis planes; each projection samples the
//! style image (bilinear, mirrored repeat so that a band continues across a tile edge),
//! and the three colours are blended with weights `|n_k|^SHARPNESS / sum`, so a surface
//! facing an axis takes that plane's texture undistorted and the seams between planes are
//! narrow. Plane coordinates: `(z, y)` for the x axis, `(x, z)` for y, `(x, y)` for z,
//! image rows along +y (the captures here have -y up, as COLMAP's cameras do, so motifs
//! stand upright on the side planes; a z-up scene gets them turned, nothing worse).
//!
//! **Scale and origin.** One style pixel spans the world length of one render pixel at the
//! object: `d / f`, with `d` the depth of the object's centre in a camera and `f` its focal
//! length in pixels, the median over the cameras. So the motif size on screen is the one
//! the texture term matches (the caller passes the style at the texture term's size,
//! `--texture-style-size`). The style image's centre sits at the object's centre (the
//! per-axis median of the means of Gaussians with opacity >= 0.5), so an object smaller
//! than the style sees one copy of it.
//!
//! **Shading.** The style's colours alone would erase the object's shading (a capture bakes
//! its light into the colours). Each projected colour is multiplied by the Gaussian's
//! relative luminance `l_i / mean(l)` (its own DC colour's, the mean weighted by opacity),
//! clamped to [`SHADING_RANGE`] (and the result to [0, 1]): shadows stay darker, highlights
//! lighter. The higher-order
//! SH coefficients are set to zero (their view-dependent tint belongs to the old colours).

use crate::geometry::quat_to_mat;
use crate::imageio::Image;
use crate::render::sh::C0;
use crate::{Camera, Error, Result, Scene};
use glam::DVec3;

/// Exponent of the triplanar blend weights `|n_k|^SHARPNESS`.
pub const SHARPNESS: i32 = 8;

/// Bounds of the shading factor `l_i / mean(l)`.
pub const SHADING_RANGE: (f64, f64) = (0.3, 2.0);

/// Opacity above which a Gaussian counts for the object's centre.
const SOLID: f32 = 0.5;

/// Where the style sits on the object: its centre in world coordinates and the world
/// length of one style pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub centre: [f64; 3],
    pub world_per_pixel: f64,
}

impl Placement {
    /// The object's centre (per-axis median of the solid Gaussians' means; all of them if
    /// none is solid) and the median over `cameras` of `depth(centre) / fx`. Errors when
    /// the scene is empty or no camera has the centre in front of it.
    pub fn of(scene: &Scene, cameras: &[Camera]) -> Result<Placement> {
        if scene.is_empty() {
            return Err(Error::param("style projection: the scene has no Gaussians"));
        }
        let solid: Vec<usize> = (0..scene.len())
            .filter(|&i| scene.opacity(i) >= SOLID)
            .collect();
        let ids: Vec<usize> = if solid.is_empty() {
            (0..scene.len()).collect()
        } else {
            solid
        };
        let centre = [0, 1, 2].map(|k| median(ids.iter().map(|&i| scene.positions[i][k] as f64)));
        let c32 = centre.map(|v| v as f32);
        let per_px = median(cameras.iter().filter_map(|cam| {
            let z = cam.to_camera(c32)[2] as f64;
            (z > 0.0 && cam.fx > 0.0).then(|| z / cam.fx as f64)
        }));
        if !(per_px.is_finite() && per_px > 0.0) {
            return Err(Error::param(
                "style projection: no camera has the object's centre in front of it",
            ));
        }
        Ok(Placement {
            centre,
            world_per_pixel: per_px,
        })
    }
}

/// Median of `v` (NaN when empty; the mean of the two middle values for an even count).
fn median(v: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = v.collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// The unit normal of Gaussian `i`: its rotation's axis of the smallest scale (+z for a
/// degenerate rotation, which `Scene::validate` refuses anyway).
pub fn normal(scene: &Scene, i: usize) -> DVec3 {
    let s = scene.log_scales[i];
    let k = (0..3).min_by(|&a, &b| s[a].total_cmp(&s[b])).unwrap_or(2);
    match quat_to_mat(scene.rotations[i].map(|v| v as f64)) {
        Some(r) => r.col(k).normalize_or(DVec3::Z),
        None => DVec3::Z,
    }
}

/// Mirrored repeat of a continuous pixel coordinate onto `[0, n - 1]` (period `2 (n - 1)`,
/// continuous across the edges).
pub fn mirror(u: f64, n: usize) -> f64 {
    let last = (n.max(2) - 1) as f64;
    let p = u.rem_euclid(2.0 * last);
    if p > last { 2.0 * last - p } else { p }
}

/// Triplanar blend weights of a normal, summing to 1.
pub fn weights(n: DVec3) -> [f64; 3] {
    let w = n.abs().to_array().map(|v| v.powi(SHARPNESS));
    let s: f64 = w.iter().sum();
    if s > 0.0 {
        w.map(|v| v / s)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The projected style colour at world point `p` with normal `n` (before shading).
pub fn colour_at(style: &Image, at: &Placement, p: [f64; 3], n: DVec3) -> [f32; 3] {
    let q = [0, 1, 2].map(|k| (p[k] - at.centre[k]) / at.world_per_pixel);
    let (cu, cv) = (
        (style.width as f64 - 1.0) / 2.0,
        (style.height as f64 - 1.0) / 2.0,
    );
    let sample =
        |u: f64, v: f64| style.sample(mirror(u + cu, style.width), mirror(v + cv, style.height));
    // Plane of each axis: (u, v) = (z, y), (x, z), (x, y).
    let planes = [(q[2], q[1]), (q[0], q[2]), (q[0], q[1])];
    let mut c = [0.0f32; 3];
    for (w, (u, v)) in weights(n).into_iter().zip(planes) {
        if w > 0.0 {
            let s = sample(u, v);
            for k in 0..3 {
                c[k] += w as f32 * s[k];
            }
        }
    }
    c
}

/// Rec. 601 luminance.
fn luminance(c: [f64; 3]) -> f64 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// `scene` with its DC colours replaced by the style projected at `at` (shaded by each
/// Gaussian's relative luminance) and its higher-order SH coefficients zeroed; geometry
/// and opacities unchanged.
pub fn project_style(scene: &Scene, style: &Image, at: &Placement) -> Scene {
    let lum: Vec<f64> = scene
        .sh_dc
        .iter()
        .map(|dc| luminance(dc.map(|d| (0.5 + C0 * d).max(0.0) as f64)))
        .collect();
    let (num, den) = (0..scene.len()).fold((0.0, 0.0), |(a, b), i| {
        let o = scene.opacity(i) as f64;
        (a + o * lum[i], b + o)
    });
    let mean = if den > 0.0 { num / den } else { 0.0 };
    let mut out = scene.clone();
    for i in 0..scene.len() {
        let p = scene.positions[i].map(|v| v as f64);
        let c = colour_at(style, at, p, normal(scene, i));
        let shade = if mean > 1e-6 {
            (lum[i] / mean).clamp(SHADING_RANGE.0, SHADING_RANGE.1)
        } else {
            1.0
        };
        out.sh_dc[i] = c.map(|v| (((v as f64 * shade).clamp(0.0, 1.0) - 0.5) / C0 as f64) as f32);
    }
    out.sh_rest.iter_mut().for_each(|v| *v = 0.0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mat_to_quat;
    use glam::DMat3;

    /// A camera at `(0, 0, -d)` looking along +z at the origin.
    fn camera(d: f32, fx: f32) -> Camera {
        Camera {
            name: "c".into(),
            width: 64,
            height: 64,
            fx,
            fy: fx,
            cx: 32.0,
            cy: 32.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0, 0.0, d],
        }
    }

    /// Gaussians at `pos`, flat along `rot`'s third axis (scales 0.01, 0.01, 0.001),
    /// opaque, grey.
    fn scene(pos: &[[f32; 3]], rot: DMat3) -> Scene {
        let q = mat_to_quat(rot).map(|v| v as f32);
        let n = pos.len();
        Scene {
            positions: pos.to_vec(),
            log_scales: vec![[0.01f32.ln(), 0.01f32.ln(), 0.001f32.ln()]; n],
            rotations: vec![q; n],
            opacity_logits: vec![5.0; n],
            sh_degree: 1,
            sh_dc: vec![[0.0; 3]; n],
            sh_rest: vec![0.3; n * 9],
        }
    }

    fn ramp() -> Image {
        Image::from_fn(9, 7, |x, y| [x as f32 / 8.0, y as f32 / 6.0, 0.5])
    }

    #[test]
    fn mirror_is_continuous_and_in_range() {
        for (u, want) in [
            (0.0, 0.0),
            (3.5, 3.5),
            (8.0, 8.0),
            (9.0, 7.0),
            (-1.0, 1.0),
            (17.0, 1.0),
        ] {
            assert!(
                (mirror(u, 9) - want).abs() < 1e-12,
                "mirror({u}) = {}",
                mirror(u, 9)
            );
        }
        for k in 0..400 {
            let u = -50.0 + k as f64 * 0.37;
            let (a, b) = (mirror(u, 9), mirror(u + 1e-6, 9));
            assert!((0.0..=8.0).contains(&a) && (a - b).abs() < 1e-5);
        }
    }

    #[test]
    fn normal_is_the_axis_of_the_smallest_scale() {
        // Rotated 90 degrees about y: local z (the thin axis) goes to world -x or +x.
        let r = DMat3::from_rotation_y(std::f64::consts::FRAC_PI_2);
        let s = scene(&[[0.0; 3]], r);
        let n = normal(&s, 0);
        assert!((n.x.abs() - 1.0).abs() < 1e-6 && n.y.abs() < 1e-6, "{n:?}");
        let w = weights(n);
        assert!((w[0] - 1.0).abs() < 1e-9, "{w:?}");
        // 45 degrees between x and z: both planes, equally.
        let w = weights(DVec3::new(1.0, 0.0, 1.0).normalize());
        assert!((w[0] - 0.5).abs() < 1e-12 && w[1] == 0.0 && (w[2] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn placement_scale_is_depth_over_focal_length() {
        let pos = [[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.2, 0.0]];
        let s = scene(&pos, DMat3::IDENTITY);
        let at = Placement::of(
            &s,
            &[camera(2.0, 100.0), camera(4.0, 100.0), camera(3.0, 50.0)],
        )
        .unwrap();
        assert_eq!(at.centre, [0.0, 0.0, 0.0]);
        // depth / fx: 0.02, 0.04, 0.06 -> median 0.04.
        assert!((at.world_per_pixel - 0.04).abs() < 1e-7, "{at:?}");
        // Behind every camera: refused.
        let err = Placement::of(&s, &[camera(-2.0, 100.0)]).unwrap_err();
        assert!(err.to_string().contains("in front"), "{err}");
    }

    /// A plane facing the camera (normals +z) gets the style image itself, pixel for
    /// pixel at one style pixel per `world_per_pixel`, its centre at the object's centre;
    /// beyond the image the mirrored copy.
    #[test]
    fn a_plane_facing_z_takes_the_style_pixel_for_pixel() {
        let style = ramp();
        let at = Placement {
            centre: [0.0; 3],
            world_per_pixel: 0.1,
        };
        let mut pos = Vec::new();
        for y in -3..=3 {
            for x in -6..=6 {
                pos.push([x as f32 * 0.1, y as f32 * 0.1, 0.0]);
            }
        }
        let s = scene(&pos, DMat3::IDENTITY);
        let out = project_style(&s, &style, &at);
        for (i, p) in pos.iter().enumerate() {
            // Style pixel (x + 4, y + 3), mirrored past column 8.
            let px = (p[0] / 0.1).round() as i64 + 4;
            let py = (p[1] / 0.1).round() as i64 + 3;
            let mx = if px > 8 { 16 - px } else { px.abs() } as usize;
            let want = style.px(mx, py as usize);
            let got = out.sh_dc[i].map(|d| 0.5 + C0 * d);
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-5,
                    "at {p:?}: {got:?} vs {want:?}"
                );
            }
        }
        assert!(out.sh_rest.iter().all(|&v| v == 0.0));
        assert_eq!(out.positions, s.positions);
        assert_eq!(out.log_scales, s.log_scales);
    }

    /// Shading: a Gaussian twice as bright as the mean gets twice the style's colour
    /// (within the clamp), one at a third of the mean is clamped to 0.3.
    #[test]
    fn shading_follows_the_relative_luminance() {
        let style = Image::filled(8, 8, [0.4, 0.2, 0.1]);
        let at = Placement {
            centre: [0.0; 3],
            world_per_pixel: 1.0,
        };
        let mut s = scene(&[[0.0; 3]; 3], DMat3::IDENTITY);
        // Grey levels 0.6, 0.3, 0.1 (mean 1/3): factors 1.8, 0.9, 0.3.
        for (i, g) in [0.6f32, 0.3, 0.1].into_iter().enumerate() {
            s.sh_dc[i] = [(g - 0.5) / C0; 3];
        }
        let out = project_style(&s, &style, &at);
        for (i, f) in [1.8f32, 0.9, 0.3].into_iter().enumerate() {
            let got = out.sh_dc[i].map(|d| 0.5 + C0 * d);
            for (k, base) in [0.4f32, 0.2, 0.1].into_iter().enumerate() {
                assert!((got[k] - base * f).abs() < 1e-5, "{i}: {got:?}, factor {f}");
            }
        }
    }
}
