//! The deterministic sample of `data-sample/` (the `make-sample` stage's work): the scene,
//! its orbit cameras and its style image. It sits beside the stages, above both
//! [`crate::scene`] and [`crate::camera`], which know nothing of each other.
//!
//! [`sample_scene`] builds a small still life from surface-aligned flat Gaussians
//! (one thin disk per surface sample, its normal along the Gaussian's third axis):
//! a checkered ground disk, a red/white banded sphere, a blue cube and a yellow cone,
//! 18,000 Gaussians at SH degree 1 (a 1.9 MB INRIA `.ply`). Colours are albedo x baked
//! Lambert light (`0.35 + 0.65 max(0, n.L)`) in `f_dc`; the degree-1 coefficients carry a
//! view-dependent highlight, linear in the view direction `d` (camera to Gaussian):
//! `k * (r . -d)` with `r` the light's mirror direction about the normal, which the
//! degree-1 basis (`-C1 y, C1 z, -C1 x`, INRIA order) represents exactly. So every view
//! sees the highlights at different places. Convention: **-y is up** (like the shared
//! scenes); the ground is the plane y = 0 and objects stand at y < 0.
//!
//! [`style_image`] paints a 256x256 style image: a swirling two-colour gradient under a
//! few hundred soft brush strokes in a bold palette that follow a smooth flow field.
//!
//! Everything is drawn from [`crate::rng::Rng`] with a fixed seed and plain IEEE
//! arithmetic, so the generated files are byte-identical from run to run.

use crate::geometry::{DMat3, DVec3, mat_to_quat, normalize};
use crate::rng::Rng;
use crate::scene::{SH_C0, Scene};

/// Degree-1 SH constant sqrt(3) / (2 sqrt(pi)).
const SH_C1: f64 = 0.488_602_511_902_919_9;

/// Number of Gaussians in the sample scene.
pub const SAMPLE_GAUSSIANS: usize = 18_000;

/// The orbit spec of the sample's `cameras.json`.
pub const SAMPLE_ORBIT: &str = "orbit:8,elev=30,radius=2.4,fov=50";
/// Image size of the sample's cameras.
pub const SAMPLE_SIZE: u32 = 256;

/// Light direction (toward the light): above (-y), front-left.
fn light() -> DVec3 {
    norm(DVec3::new(0.4, -1.0, -0.5))
}

fn norm(v: DVec3) -> DVec3 {
    normalize(v).unwrap_or(DVec3::Z)
}

struct Builder {
    s: Scene,
    rng: Rng,
}

impl Builder {
    /// Add a flat Gaussian at `p` with normal `n`, in-plane size `size`, albedo `albedo`
    /// and highlight strength `k`.
    fn disk(&mut self, p: [f64; 3], n: [f64; 3], size: f64, albedo: [f64; 3], k: f64) {
        let n = norm(DVec3::from_array(n));
        let helper = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let t1 = norm(helper.cross(n));
        let t2 = n.cross(t1);
        let q = mat_to_quat(DMat3::from_cols(t1, t2, n));
        let jitter = 1.0 + 0.15 * (self.rng.uniform() - 0.5);
        let s = size * jitter;
        let l = light();
        let shade = 0.35 + 0.65 * n.dot(l).max(0.0);
        let c = albedo.map(|a| a * shade);
        // Mirror direction of the light about the normal.
        let nl = n.dot(l);
        let r = [0, 1, 2].map(|i| 2.0 * nl * n[i] - l[i]);
        let a = [k * r[1], -k * r[2], k * r[0]].map(|v| v / SH_C1);
        self.s.positions.push(p.map(|v| v as f32));
        self.s
            .log_scales
            .push([s.ln(), s.ln(), (0.15 * s).ln()].map(|v| v as f32));
        self.s.rotations.push(q.map(|v| v as f32));
        let o = 0.92 + 0.05 * self.rng.uniform();
        self.s.opacity_logits.push((o / (1.0 - o)).ln() as f32);
        self.s
            .sh_dc
            .push(c.map(|v| ((v - 0.5) / SH_C0 as f64) as f32));
        // Scene layout [k][c]: the same (white) highlight in every channel.
        for ak in a {
            for _ in 0..3 {
                self.s.sh_rest.push(ak as f32);
            }
        }
    }
}

const GOLDEN_ANGLE: f64 = 2.399_963_229_728_653;

/// The sample scene (deterministic).
pub fn sample_scene(seed: u64) -> Scene {
    build(seed).0
}

/// The sample scene's parts in the scene's order: `("ground" | "sphere" | "cube" |
/// "cone", the indices of its Gaussians)` (for ground-truth selections).
pub fn sample_parts(seed: u64) -> Vec<(&'static str, std::ops::Range<usize>)> {
    build(seed).1
}

fn build(seed: u64) -> (Scene, Vec<(&'static str, std::ops::Range<usize>)>) {
    let mut b = Builder {
        s: Scene {
            sh_degree: 1,
            ..Scene::default()
        },
        rng: Rng::derive(seed, "sample-scene"),
    };
    let mut parts = Vec::with_capacity(4);
    type Add = fn(&mut Builder);
    let steps: [(&'static str, Add); 4] = [
        ("ground", Builder::ground),
        ("sphere", Builder::sphere),
        ("cube", Builder::cube),
        ("cone", Builder::cone),
    ];
    for (name, add) in steps {
        let start = b.s.len();
        add(&mut b);
        parts.push((name, start..b.s.len()));
    }
    (b.s, parts)
}

/// The side of a square cell when `m` points share `area`.
fn spacing(area: f64, m: usize) -> f64 {
    (area / m as f64).sqrt()
}

impl Builder {
    /// Checkered ground disk, radius 1, in the plane y = 0 (normal toward -y, up).
    fn ground(&mut self) {
        let (m, rad) = (7000, 1.0);
        let sz = 0.75 * spacing(std::f64::consts::PI * rad * rad, m);
        for i in 0..m {
            let r = rad * ((i as f64 + 0.5) / m as f64).sqrt();
            let th = i as f64 * GOLDEN_ANGLE;
            let (x, z) = (r * th.cos(), r * th.sin());
            let cell = ((x / 0.25).floor() + (z / 0.25).floor()) as i64;
            let albedo = if cell.rem_euclid(2) == 0 {
                [0.92, 0.86, 0.70]
            } else {
                [0.12, 0.36, 0.42]
            };
            self.disk([x, 0.0, z], [0.0, -1.0, 0.0], sz, albedo, 0.05);
        }
    }

    /// Red/white banded sphere.
    fn sphere(&mut self) {
        let (m, c, rad) = (4500, [-0.42, -0.29, 0.12], 0.28);
        let sz = 0.75 * spacing(4.0 * std::f64::consts::PI * rad * rad, m);
        for i in 0..m {
            let yy = 1.0 - 2.0 * (i as f64 + 0.5) / m as f64;
            let rr = (1.0 - yy * yy).max(0.0).sqrt();
            let th = i as f64 * GOLDEN_ANGLE;
            let n = [rr * th.cos(), yy, rr * th.sin()];
            let band = ((yy + 1.0) * 4.0).floor() as i64;
            let albedo = if band.rem_euclid(2) == 0 {
                [0.88, 0.08, 0.08]
            } else {
                [0.95, 0.95, 0.93]
            };
            let p = [0, 1, 2].map(|k| c[k] + rad * n[k]);
            self.disk(p, n, sz, albedo, 0.3);
        }
    }

    /// Blue cube, half-size 0.2, standing on the ground, turned 30 degrees about y.
    fn cube(&mut self) {
        let (per_face, c, h) = (600usize, [0.45, -0.2, 0.18], 0.2);
        let (sa, ca) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
        let turn = |v: [f64; 3]| [ca * v[0] + sa * v[2], v[1], -sa * v[0] + ca * v[2]];
        let g = (per_face as f64).sqrt().round() as usize; // 24 x 24 grid + jitter
        let sz = 0.75 * (2.0 * h) / g as f64;
        for face in 0..6 {
            let axis = face / 2;
            let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
            let mut n = [0.0; 3];
            n[axis] = sign;
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..g {
                for j in 0..g {
                    let mut p = [0.0; 3];
                    p[axis] = sign * h;
                    p[u] = h
                        * (2.0 * (i as f64 + 0.5 + 0.3 * (self.rng.uniform() - 0.5)) / g as f64
                            - 1.0);
                    p[v] = h
                        * (2.0 * (j as f64 + 0.5 + 0.3 * (self.rng.uniform() - 0.5)) / g as f64
                            - 1.0);
                    let p = turn(p);
                    let p = [p[0] + c[0], p[1] + c[1], p[2] + c[2]];
                    self.disk(p, turn(n), sz, [0.12, 0.28, 0.88], 0.15);
                }
            }
        }
    }

    /// Yellow cone: base circle radius 0.22 on the ground, apex 0.55 above (toward -y).
    fn cone(&mut self) {
        let m = SAMPLE_GAUSSIANS - self.s.len();
        let (c, rad, ht): ([f64; 3], f64, f64) = ([0.02, 0.0, -0.45], 0.22, 0.55);
        let slant = (rad * rad + ht * ht).sqrt();
        let sz = 0.75 * spacing(std::f64::consts::PI * rad * slant, m);
        for i in 0..m {
            // Area-uniform along the slant: distance from apex ~ sqrt(u).
            let f = ((i as f64 + 0.5) / m as f64).sqrt();
            let th = i as f64 * GOLDEN_ANGLE;
            let (cr, sr) = (th.cos(), th.sin());
            let p = [
                c[0] + f * rad * cr,
                c[1] - ht * (1.0 - f),
                c[2] + f * rad * sr,
            ];
            let n = [ht * cr, -rad, ht * sr];
            self.disk(p, n, sz, [0.97, 0.80, 0.10], 0.2);
        }
    }
}

/// Ground-truth masks of the Gaussians `part` of `scene` as seen (occlusion included)
/// from each camera: 1 where they make up more than half of the pixel's colour (the
/// full scene rendered with colour 1 on `part`, 0 elsewhere, over black), else 0;
/// `[H, W]` per camera.
pub fn part_masks(
    scene: &Scene,
    part: std::ops::Range<usize>,
    cameras: &[crate::Camera],
) -> crate::Result<Vec<Vec<f32>>> {
    cameras
        .iter()
        .map(|cam| {
            let cache = crate::render::ViewCache::build(scene, cam)?;
            let colours: Vec<[f32; 3]> = cache
                .gaussians()
                .iter()
                .map(|&g| {
                    [if part.contains(&(g as usize)) {
                        1.0
                    } else {
                        0.0
                    }; 3]
                })
                .collect();
            let rgb = cache.forward(&colours, [0.0; 3]);
            Ok(rgb
                .chunks_exact(3)
                .map(|c| if c[0] > 0.5 { 1.0 } else { 0.0 })
                .collect())
        })
        .collect()
}

/// A 256x256 painterly style image, `[H, W, 3]` in [0, 1] (deterministic).
pub fn style_image(seed: u64) -> (usize, usize, Vec<f32>) {
    const W: usize = 256;
    const H: usize = 256;
    let palette: [[f64; 3]; 7] = [
        [0.08, 0.12, 0.45],
        [0.15, 0.38, 0.85],
        [0.98, 0.80, 0.12],
        [0.96, 0.45, 0.08],
        [0.80, 0.08, 0.22],
        [0.08, 0.60, 0.55],
        [0.97, 0.93, 0.80],
    ];
    let mut rng = Rng::derive(seed, "style-image");
    let flow = |x: f64, y: f64| (x * 0.031).sin() * 2.1 + (y * 0.027).cos() * 1.9 + (x + y) * 0.004;
    let mut img = vec![0.0f64; W * H * 3];
    for y in 0..H {
        for x in 0..W {
            let t = 0.5 + 0.5 * (flow(x as f64, y as f64) * 0.8).sin();
            for k in 0..3 {
                img[(y * W + x) * 3 + k] = palette[0][k] * (1.0 - t) + palette[5][k] * t;
            }
        }
    }
    for _ in 0..700 {
        let mut px = rng.uniform() * W as f64;
        let mut py = rng.uniform() * H as f64;
        let len = 12.0 + rng.uniform() * 30.0;
        let rad = 2.0 + rng.uniform() * 4.5;
        let base = palette[(rng.uniform() * palette.len() as f64) as usize % palette.len()];
        let jit = 0.12 * (rng.uniform() - 0.5);
        let col = base.map(|v| (v + jit).clamp(0.0, 1.0));
        let bristle = 1.2 + rng.uniform() * 1.5;
        let mut step = 0.0;
        while step < len {
            let a = flow(px, py);
            let (dx, dy) = (a.cos(), a.sin());
            let (x0, x1) = ((px - rad).floor() as i64, (px + rad).ceil() as i64);
            let (y0, y1) = ((py - rad).floor() as i64, (py + rad).ceil() as i64);
            for yy in y0.max(0)..=y1.min(H as i64 - 1) {
                for xx in x0.max(0)..=x1.min(W as i64 - 1) {
                    let (ox, oy) = (xx as f64 - px, yy as f64 - py);
                    let d = (ox * ox + oy * oy).sqrt() / rad;
                    if d >= 1.0 {
                        continue;
                    }
                    // Bristle texture across the stroke.
                    let across = -ox * dy + oy * dx;
                    let tex = 0.75 + 0.25 * (across * bristle).sin();
                    let al = 0.35 * (1.0 - d).sqrt() * tex;
                    let o = (yy as usize * W + xx as usize) * 3;
                    for k in 0..3 {
                        img[o + k] = img[o + k] * (1.0 - al) + col[k] * al;
                    }
                }
            }
            px += dx;
            py += dy;
            step += 1.0;
        }
    }
    (W, H, img.into_iter().map(|v| v as f32).collect())
}

/// Write `scene.ply`, `cameras.json` and `style.png` of the sample into `dir`
/// (created if missing), each atomically.
pub fn write_sample(dir: &std::path::Path, seed: u64) -> crate::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
    let scene = sample_scene(seed);
    crate::scene::ply::write_ply(&dir.join("scene.ply"), &scene)?;
    let cams =
        crate::camera::load_cameras(SAMPLE_ORBIT, &scene.bounds(), SAMPLE_SIZE, SAMPLE_SIZE)?;
    crate::camera::inria::write_inria(&dir.join("cameras.json"), &cams)?;
    let (w, h, img) = style_image(seed);
    crate::imageio::write_png_rgb(&dir.join("style.png"), &img, w, h)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_is_valid_and_deterministic() {
        let s = sample_scene(0);
        assert_eq!(s.len(), SAMPLE_GAUSSIANS);
        assert_eq!(s.sh_degree, 1);
        s.validate(std::path::Path::new("sample")).unwrap();
        assert_eq!(s, sample_scene(0));
        assert_ne!(s, sample_scene(1));
        // -y up: everything at or above the ground plane y = 0.
        assert!(s.positions.iter().all(|p| p[1] <= 0.01));
        // View dependence present.
        assert!(s.sh_rest.iter().any(|v| v.abs() > 0.1));
        // Colours of the DC term stay inside [0, 1].
        for c in &s.sh_dc {
            for v in c {
                let x = SH_C0 * v + 0.5;
                assert!((0.0..=1.0).contains(&x), "{x}");
            }
        }
        let parts = sample_parts(0);
        let names: Vec<&str> = parts.iter().map(|p| p.0).collect();
        assert_eq!(names, ["ground", "sphere", "cube", "cone"]);
        assert_eq!(parts[0].1.start, 0);
        assert_eq!(parts[3].1.end, SAMPLE_GAUSSIANS);
        assert!(parts.windows(2).all(|w| w[0].1.end == w[1].1.start));
        // The sphere's centres lie on the sphere (centre (-0.42, -0.29, 0.12), r 0.28).
        for i in parts[1].1.clone() {
            let p = s.positions[i];
            let d = ((p[0] + 0.42).powi(2) + (p[1] + 0.29).powi(2) + (p[2] - 0.12).powi(2)).sqrt();
            assert!((d - 0.28).abs() < 1e-4, "{i}: {d}");
        }
        let (w, h, img) = style_image(0);
        assert_eq!(img.len(), w * h * 3);
        assert!(img.iter().all(|v| (0.0..=1.0).contains(v)));
    }
}
