//! Style projection (not part of FantasyStyle): the style image texture-mapped onto the
//! object by triplanar projection, written into the Gaussians' DC colours. No network, no
//! optimisation: well under a second. A baseline (`stylize-baseline --method project`) and
//! a start for the distillation (`start = "projection"`, [`crate::ends`]).
//!
//! Why: a texture statistic inside the loop (NNFM, Gram; [`crate::terms::texture`]) and
//! the 2D stylizer both ask each view for motifs where that view's content puts them, and
//! views 22-45 degrees apart disagree, so bands and rings average into blobs of the style's
//! colours (docs/style-projection.md). A motif painted once on the surface is the
//! same motif from every view by construction; the loop then refines it.
//!
//! **Normals** ([`surface_normals`]). Each Gaussian takes the normal of the rendered
//! surface where it is seen: its centre is projected into every source view; where the
//! view's surface (expected depth over coverage) lies within [`SEEN_TOL`] of the centre's
//! depth, the surface normal there is the cross product of the back-projected depth map's
//! central differences (a view with a depth edge or a background pixel in the 3x3 is
//! skipped), turned toward the camera and into world space; the views' normals are
//! averaged, each weighted by how squarely it faces its camera. A Gaussian no view sees
//! (inside the object, or hidden by others) keeps the axis of its smallest scale
//! ([`normal`]): trained splats are flat (the plant's median ratio of largest to smallest
//! scale is 11), so that axis is the normal 2DGS and GaussianShader take. That axis alone
//! was the first version. On mesh-derived splats it is the surface's normal (mean |cos|
//! to the rendered surface's 1.00 on bob_100k, 0.96 on fish_10k), on a trained capture
//! it is not (0.63 on the plant; 0.5 for unrelated directions; on its pot only half of
//! the covered area has the axis within 37 degrees of the radial direction), and a
//! Gaussian whose axis picks the wrong plane takes an unrelated style sample: the pot's
//! bands blurred into one gradient (docs/style-projection.md "Normals from the rendered surface").
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
//! `texture.style_size`). The style image's centre sits at the object's centre (the
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
use crate::maths::warp::surface_depth;
use crate::render::sh::C0;
use crate::{Camera, Error, Result, Scene};
use glam::DVec3;

/// Exponent of the triplanar blend weights `|n_k|^SHARPNESS`.
pub const SHARPNESS: i32 = 8;

/// Bounds of the shading factor `l_i / mean(l)`.
pub const SHADING_RANGE: (f64, f64) = (0.3, 2.0);

/// Opacity above which a Gaussian counts for the object's centre.
const SOLID: f32 = 0.5;

/// A Gaussian is on a view's surface where its centre's depth is within this fraction of
/// the surface's depth there.
pub const SEEN_TOL: f64 = 0.02;

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

/// A source view for the surface normals: its camera and its surface depth
/// ([`crate::maths::warp::surface_depth`]: `depth / alpha` where the view covers the
/// object, NaN elsewhere), `[H, W]` at the camera's size.
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    pub camera: &'a Camera,
    pub surface: &'a [f32],
}

impl DepthView<'_> {
    /// The surface point of pixel `(x, y)` in camera coordinates: the pixel centre's ray
    /// at the surface depth; `None` off the object.
    fn point(&self, x: usize, y: usize) -> Option<DVec3> {
        let z = self.surface[y * self.camera.width as usize + x] as f64;
        let c = self.camera;
        z.is_finite().then(|| {
            DVec3::new(
                (x as f64 + 0.5 - c.cx as f64) * z / c.fx as f64,
                (y as f64 + 0.5 - c.cy as f64) * z / c.fy as f64,
                z,
            )
        })
    }

    /// The surface normal (world, unit, toward the camera) where world point `p` is seen,
    /// and the cosine between it and the viewing ray; `None` where `p` is outside the
    /// frame, not on the surface (hidden, or in front of it), or next to a depth edge.
    fn normal_at(&self, p: [f32; 3]) -> Option<(DVec3, f64)> {
        let c = self.camera;
        let ([u, v], z) = c.project(p);
        let (w, h) = (c.width as usize, c.height as usize);
        if !(z > 0.0 && u >= 1.0 && v >= 1.0 && u < (w - 1) as f32 && v < (h - 1) as f32) {
            return None;
        }
        let (x, y) = (u as usize, v as usize);
        let centre = self.point(x, y)?;
        if (centre.z - z as f64).abs() > SEEN_TOL * centre.z {
            return None;
        }
        let (n, cos) = self.pixel_normal(x, y)?;
        // Camera to world: the transpose of the world-to-camera rotation.
        Some((c.w2c().0.transpose() * n, cos))
    }

    /// The surface normal at pixel `(x, y)` (camera coordinates, unit, toward the camera)
    /// and the cosine between it and the pixel's viewing ray: the cross product of the
    /// back-projected depth map's central differences; `None` on the frame's border, off
    /// the surface, or where a neighbour's depth is more than [`SEEN_TOL`] from the
    /// centre's (a depth edge).
    pub fn pixel_normal(&self, x: usize, y: usize) -> Option<(DVec3, f64)> {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        if !(x >= 1 && y >= 1 && x + 1 < w && y + 1 < h) {
            return None;
        }
        let centre = self.point(x, y)?;
        let tol = SEEN_TOL * centre.z;
        let near = |q: DVec3| ((q.z - centre.z).abs() <= tol).then_some(q);
        let dx = near(self.point(x + 1, y)?)? - near(self.point(x - 1, y)?)?;
        let dy = near(self.point(x, y + 1)?)? - near(self.point(x, y - 1)?)?;
        let n = dx.cross(dy).try_normalize()?;
        let ray = centre.normalize();
        let n = if n.dot(ray) > 0.0 { -n } else { n };
        Some((n, -n.dot(ray)))
    }
}

/// Every Gaussian's normal, from [`surface_normals`].
#[derive(Debug, Clone)]
pub struct Normals {
    /// One unit normal per Gaussian.
    pub normals: Vec<DVec3>,
    /// How many took the rendered surface's normal (the rest kept their own axis).
    pub seen: usize,
    /// Mean `|cos|` between the surface normal and the Gaussian's own axis over the seen
    /// ones (1: the axes were the surface's already; 0.5: unrelated).
    pub axis_agreement: f64,
}

impl std::fmt::Display for Normals {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of {} Gaussians on the views' surface take its normal (mean |cos| to their own \
             axis {:.2})",
            self.seen,
            self.normals.len(),
            self.axis_agreement
        )
    }
}

/// Every Gaussian's normal: the rendered surface's where a view sees it (the views'
/// normals averaged, each weighted by its cosine to the viewing ray), the axis of its
/// smallest scale elsewhere ([`normal`]).
pub fn surface_normals(scene: &Scene, views: &[DepthView<'_>]) -> Normals {
    use rayon::prelude::*;
    let found: Vec<(DVec3, Option<f64>)> = (0..scene.len())
        .into_par_iter()
        .map(|i| {
            let p = scene.positions[i];
            let sum = views
                .iter()
                .filter_map(|v| v.normal_at(p))
                .fold(DVec3::ZERO, |acc, (n, w)| acc + w * n);
            let own = normal(scene, i);
            match sum.try_normalize() {
                Some(n) => (n, Some(n.dot(own).abs())),
                None => (own, None),
            }
        })
        .collect();
    let agree: Vec<f64> = found.iter().filter_map(|(_, c)| *c).collect();
    Normals {
        seen: agree.len(),
        axis_agreement: agree.iter().sum::<f64>() / agree.len().max(1) as f64,
        normals: found.into_iter().map(|(n, _)| n).collect(),
    }
}

/// [`surface_normals`] from `scene`'s own renders at `cameras` (for callers without the
/// source views at hand).
pub fn rendered_normals(scene: &Scene, cameras: &[Camera]) -> Result<Normals> {
    let surfaces: Vec<Vec<f32>> = crate::render::render_all(scene, cameras, [0.0; 3])?
        .iter()
        .map(|r| surface_depth(&r.depth, &r.alpha))
        .collect();
    Ok(surface_normals(scene, &depth_views(cameras, &surfaces)))
}

/// The [`DepthView`]s of `cameras` with their surface depths (one per camera).
pub fn depth_views<'a>(cameras: &'a [Camera], surfaces: &'a [Vec<f32>]) -> Vec<DepthView<'a>> {
    cameras
        .iter()
        .zip(surfaces)
        .map(|(camera, surface)| DepthView { camera, surface })
        .collect()
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

/// `scene` with its DC colours replaced by the style projected at `at` along `normals`
/// (one per Gaussian: [`surface_normals`]; shaded by each Gaussian's relative luminance)
/// and its higher-order SH coefficients zeroed; geometry and opacities unchanged.
pub fn project_style(scene: &Scene, style: &Image, at: &Placement, normals: &[DVec3]) -> Scene {
    assert_eq!(normals.len(), scene.len(), "one normal per Gaussian");
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
        let c = colour_at(style, at, p, normals[i]);
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

    /// Every Gaussian's own normal ([`normal`]): the axis of its smallest scale.
    fn axis_normals(scene: &Scene) -> Vec<DVec3> {
        (0..scene.len()).map(|i| normal(scene, i)).collect()
    }

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
        let out = project_style(&s, &style, &at, &axis_normals(&s));
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

    /// Normals from the rendered surface: a grid of Gaussians whose own axis of smallest
    /// scale lies in the plane (scales 0.02, 0.02, 0.015 with the thin axis along x: the
    /// wrong normal, and barely the smallest), in a plane tilted 30 degrees about y, seen
    /// by a camera looking along +z. The Gaussians the view sees get the plane's normal
    /// (at least 90% of them within 0.02 in cosine, all within 0.2); a smaller grid hidden 0.3 behind the first keeps its own
    /// axis (x).
    #[test]
    fn surface_normals_come_from_the_rendered_depth() {
        let tilt = DMat3::from_rotation_y(std::f64::consts::FRAC_PI_6);
        let mut pos = Vec::new();
        // The hidden grid is smaller (21 x 21), so that all of it is behind the first.
        for (layer, half) in [(0.0, 30), (0.3, 10)] {
            for y in -half..=half {
                for x in -half..=half {
                    let p = tilt * DVec3::new(x as f64 * 0.01, y as f64 * 0.01, layer);
                    pos.push(p.as_vec3().to_array());
                }
            }
        }
        // Local x (the thin axis) is world x before the tilt.
        let mut s = scene(&pos, tilt);
        s.log_scales = vec![[0.015f32.ln(), 0.02f32.ln(), 0.02f32.ln()]; pos.len()];
        let cam = camera(2.0, 100.0);
        let r = crate::render::render(&s, &cam, &Default::default()).unwrap();
        let surface = surface_depth(&r.depth, &r.alpha);
        let view = DepthView {
            camera: &cam,
            surface: &surface,
        };
        let Normals { normals, seen, .. } = surface_normals(&s, &[view]);
        let plane = tilt * DVec3::Z;
        let own = tilt * DVec3::X;
        let front = 61 * 61;
        assert!(seen > front / 2 && seen <= front, "{seen} of {front} seen");
        // |cos| to the plane's normal (the own axis would give 0): near 1 for most, the
        // rest at the grid's rim, where a 3x3 of depths includes partly covered pixels.
        let cos: Vec<f64> = normals[..front]
            .iter()
            .map(|n| n.dot(plane).abs())
            .collect();
        let close = cos.iter().filter(|&&c| c > 0.98).count();
        let worst = cos.iter().copied().fold(1.0, f64::min);
        assert!(
            close * 10 >= seen * 9 && worst > 0.8,
            "{close} of {seen} seen Gaussians within 0.02 of the plane's normal, worst {worst}"
        );
        for (i, n) in normals[front..].iter().enumerate() {
            assert!(n.dot(own).abs() > 0.999, "hidden Gaussian {i}: {n:?}");
        }
        // Seen Gaussians' normals face the camera (at -z).
        assert!(
            normals[..front]
                .iter()
                .filter(|n| n.dot(plane).abs() > 0.98)
                .all(|n| n.z < 0.0)
        );
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
        let out = project_style(&s, &style, &at, &axis_normals(&s));
        for (i, f) in [1.8f32, 0.9, 0.3].into_iter().enumerate() {
            let got = out.sh_dc[i].map(|d| 0.5 + C0 * d);
            for (k, base) in [0.4f32, 0.2, 0.1].into_iter().enumerate() {
                assert!((got[k] - base * f).abs() < 1e-5, "{i}: {got:?}, factor {f}");
            }
        }
    }
}
