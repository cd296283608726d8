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
//! [`lettering_scene`] (`make-sample --lettering`, the lettering case of the structure
//! benchmark `benches/quality/keep.toml`) builds, with the same disks, a closed card box
//! whose four sides carry a word each in dark 5x7 bitmap capitals on light card, letters
//! about 30 px high in 256 px views of the default orbit: a scene whose structure (printed
//! words) a stylization can be seen to keep or lose.
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
    /// Toward the light, and the baked shade `ambient + (1 - ambient) max(0, n.L)`.
    light: DVec3,
    ambient: f64,
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
        let l = self.light;
        let shade = self.ambient + (1.0 - self.ambient) * n.dot(l).max(0.0);
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
        light: light(),
        ambient: 0.35,
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

// ---------------------------------------------------------------------------------------
// The lettering scene.

/// Number of Gaussians in the lettering scene.
pub const LETTERING_GAUSSIANS: usize = 34_250;

/// The words on the lettering box's four sides, in the order an orbit meets them: the
/// -z face (orbit view 0), +x (view N/4), +z (view N/2), -x (view 3N/4).
pub const LETTERING_WORDS: [&str; 4] = ["STYLE", "KEEP", "SPLAT", "READ"];

/// The lettering box's size (x, height along -y, z).
const BOX: [f64; 3] = [1.0, 0.55, 0.75];
/// Spacing of the Gaussians on the faces; a font pixel is `INK_CELLS` x `INK_CELLS` of them.
const GRID: f64 = 0.01;
const INK_CELLS: usize = 3;
const CARD: [f64; 3] = [0.94, 0.91, 0.84];
const INK: [f64; 3] = [0.07, 0.07, 0.10];

/// A 5x7 bitmap font, A-Z: seven rows from the top, bit 4 the leftmost column.
const FONT: [[u8; 7]; 26] = [
    [
        0b01110, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001,
    ], // A
    [
        0b11110, 0b10001, 0b10001, 0b11110, 0b10001, 0b10001, 0b11110,
    ], // B
    [
        0b01110, 0b10001, 0b10000, 0b10000, 0b10000, 0b10001, 0b01110,
    ], // C
    [
        0b11100, 0b10010, 0b10001, 0b10001, 0b10001, 0b10010, 0b11100,
    ], // D
    [
        0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b11111,
    ], // E
    [
        0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b10000,
    ], // F
    [
        0b01110, 0b10001, 0b10000, 0b10111, 0b10001, 0b10001, 0b01111,
    ], // G
    [
        0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001,
    ], // H
    [
        0b01110, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110,
    ], // I
    [
        0b00111, 0b00010, 0b00010, 0b00010, 0b00010, 0b10010, 0b01100,
    ], // J
    [
        0b10001, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010, 0b10001,
    ], // K
    [
        0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b11111,
    ], // L
    [
        0b10001, 0b11011, 0b10101, 0b10101, 0b10001, 0b10001, 0b10001,
    ], // M
    [
        0b10001, 0b10001, 0b11001, 0b10101, 0b10011, 0b10001, 0b10001,
    ], // N
    [
        0b01110, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110,
    ], // O
    [
        0b11110, 0b10001, 0b10001, 0b11110, 0b10000, 0b10000, 0b10000,
    ], // P
    [
        0b01110, 0b10001, 0b10001, 0b10001, 0b10101, 0b10010, 0b01101,
    ], // Q
    [
        0b11110, 0b10001, 0b10001, 0b11110, 0b10100, 0b10010, 0b10001,
    ], // R
    [
        0b01111, 0b10000, 0b10000, 0b01110, 0b00001, 0b00001, 0b11110,
    ], // S
    [
        0b11111, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100,
    ], // T
    [
        0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110,
    ], // U
    [
        0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100,
    ], // V
    [
        0b10001, 0b10001, 0b10001, 0b10101, 0b10101, 0b10101, 0b01010,
    ], // W
    [
        0b10001, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b10001,
    ], // X
    [
        0b10001, 0b10001, 0b01010, 0b00100, 0b00100, 0b00100, 0b00100,
    ], // Y
    [
        0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b11111,
    ], // Z
];

/// Whether font pixel (`col`, `row`) of `word` set in the font (letters 6 columns apart,
/// rows from the top) is ink; anything but A-Z is a blank.
fn ink(word: &str, col: usize, row: usize) -> bool {
    let (letter, x) = (col / 6, col % 6);
    match word.as_bytes().get(letter) {
        Some(&c) if c.is_ascii_uppercase() && x < 5 && row < 7 => {
            (FONT[usize::from(c - b'A')][row] >> (4 - x)) & 1 == 1
        }
        _ => false,
    }
}

/// One face of the lettering box: centre, outward normal, the reading directions (right,
/// up: `right = up x normal`, so the word reads unmirrored from outside), size and word.
struct Face {
    centre: [f64; 3],
    normal: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    size: [f64; 2],
    word: &'static str,
}

/// The box's six faces: the four sides carry [`LETTERING_WORDS`], the top and the bottom
/// are plain card.
fn box_faces() -> [Face; 6] {
    let [w, h, d] = BOX;
    let cy = -0.5 * h;
    let up = [0.0, -1.0, 0.0];
    let side = |centre, normal, right, width, word| Face {
        centre,
        normal,
        right,
        up,
        size: [width, h],
        word,
    };
    let [front, right, back, left] = LETTERING_WORDS;
    [
        side(
            [0.0, cy, -0.5 * d],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            w,
            front,
        ),
        side(
            [0.5 * w, cy, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            d,
            right,
        ),
        side(
            [0.0, cy, 0.5 * d],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 0.0],
            w,
            back,
        ),
        side(
            [-0.5 * w, cy, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            d,
            left,
        ),
        Face {
            centre: [0.0, -h, 0.0],
            normal: up,
            right: [1.0, 0.0, 0.0],
            up: [0.0, 0.0, 1.0],
            size: [w, d],
            word: "",
        },
        Face {
            centre: [0.0, 0.0, 0.0],
            normal: [0.0, 1.0, 0.0],
            right: [-1.0, 0.0, 0.0],
            up: [0.0, 0.0, 1.0],
            size: [w, d],
            word: "",
        },
    ]
}

/// The lettering scene (deterministic): a closed card box, 1.0 x 0.55 x 0.75, standing
/// on the plane y = 0 (-y up), its four sides printed with a word each
/// ([`LETTERING_WORDS`]) in dark 5x7 bitmap capitals on light card. Every face is a grid of
/// surface-aligned flat Gaussians 0.01 apart (jittered by up to 0.1 of that), a font pixel
/// 3 x 3 of them (0.03), so a letter is 0.21 high: about 30 px in a 256 px view of the
/// default orbit (`orbit:N`, elevation 15 degrees, radius 2.2 x the box's width). Shading:
/// albedo x baked Lambert light (`0.55 + 0.45 max(0, n.L)`, the sample's light direction),
/// a faint degree-1 highlight; 34,250 Gaussians at SH degree 1.
pub fn lettering_scene(seed: u64) -> Scene {
    let mut b = Builder {
        s: Scene {
            sh_degree: 1,
            ..Scene::default()
        },
        rng: Rng::derive(seed, "lettering-scene"),
        light: light(),
        ambient: 0.55,
    };
    for f in box_faces() {
        b.lettered_face(&f);
    }
    b.s
}

impl Builder {
    /// A face of the box: a grid of Gaussians, the word centred on it.
    fn lettered_face(&mut self, f: &Face) {
        let (nu, nv) = (
            (f.size[0] / GRID).round() as usize,
            (f.size[1] / GRID).round() as usize,
        );
        let cols = (6 * f.word.len()).saturating_sub(1) * INK_CELLS;
        let (u0, v0) = (
            nu.saturating_sub(cols) / 2,
            nv.saturating_sub(7 * INK_CELLS) / 2,
        );
        for j in 0..nv {
            for i in 0..nu {
                let a =
                    -0.5 * f.size[0] + GRID * (i as f64 + 0.5 + 0.2 * (self.rng.uniform() - 0.5));
                let c =
                    0.5 * f.size[1] - GRID * (j as f64 + 0.5 + 0.2 * (self.rng.uniform() - 0.5));
                let p = [0, 1, 2].map(|k| f.centre[k] + a * f.right[k] + c * f.up[k]);
                let printed =
                    i >= u0 && j >= v0 && ink(f.word, (i - u0) / INK_CELLS, (j - v0) / INK_CELLS);
                let albedo = if printed { INK } else { CARD };
                self.disk(p, f.normal, 0.75 * GRID, albedo, 0.05);
            }
        }
    }
}

/// Write the lettering scene ([`lettering_scene`]) to `path` as an INRIA `.ply`
/// (atomically).
pub fn write_lettering(path: &std::path::Path, seed: u64) -> crate::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
    }
    crate::scene::ply::write_ply(path, &lettering_scene(seed))
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

    /// The DC colour's mean over the channels, per Gaussian.
    fn grey(s: &Scene) -> Vec<f32> {
        s.sh_dc
            .iter()
            .map(|c| c.iter().map(|v| SH_C0 * v + 0.5).sum::<f32>() / 3.0)
            .collect()
    }

    #[test]
    fn lettering_is_deterministic_and_carries_its_words() {
        let s = lettering_scene(0);
        assert_eq!((s.len(), s.sh_degree), (LETTERING_GAUSSIANS, 1));
        s.validate(std::path::Path::new("lettering")).unwrap();
        assert_ne!(s, lettering_scene(1));
        assert!(s.positions.iter().all(|p| p[1] <= 0.01)); // -y up, on the plane y = 0
        let d = tempfile::tempdir().unwrap();
        let (a, b) = (d.path().join("a.ply"), d.path().join("sub/b.ply"));
        write_lettering(&a, 0).unwrap();
        write_lettering(&b, 0).unwrap();
        let bytes = std::fs::read(&a).unwrap();
        assert!(
            bytes == std::fs::read(&b).unwrap(),
            "two calls, two byte strings"
        );
        assert_eq!(crate::scene::read_scene_file(&a).unwrap(), s);
        // Every ink pixel of the four words is 3 x 3 dark Gaussians; all others are card.
        let ink_pixels: usize = LETTERING_WORDS
            .iter()
            .map(|w| {
                (0..6 * w.len())
                    .flat_map(|c| (0..7).map(move |r| (c, r)))
                    .filter(|&(c, r)| ink(w, c, r))
                    .count()
            })
            .sum();
        let g = grey(&s);
        let dark = g.iter().filter(|&&v| v < 0.1).count();
        let light = g.iter().filter(|&&v| v > 0.45).count();
        assert_eq!(dark, ink_pixels * INK_CELLS * INK_CELLS);
        assert_eq!(dark + light, s.len());
        assert!(
            (0.05..0.2).contains(&(dark as f64 / s.len() as f64)),
            "{dark}"
        );
    }

    #[test]
    fn lettering_reads_at_256_px_from_the_default_orbit() {
        // View 0 of `orbit:16` (elevation 15 degrees) faces STYLE: ink covers a good share
        // of the box, in a band 20-40 px high (the letters' height).
        let s = lettering_scene(0);
        let cams = crate::camera::load_cameras("orbit:16", &s.bounds(), 256, 256).unwrap();
        let cache = crate::render::ViewCache::build(&s, &cams[0]).unwrap();
        let cover = cache.forward(&vec![[1.0; 3]; cache.gaussians().len()], [0.0; 3]);
        let g = grey(&s);
        let colours: Vec<[f32; 3]> = cache
            .gaussians()
            .iter()
            .map(|&i| [g[i as usize]; 3])
            .collect();
        let rgb = cache.forward(&colours, [0.0; 3]);
        let (mut object, mut rows) = (0usize, Vec::new());
        for p in 0..256 * 256 {
            if cover[3 * p] > 0.95 {
                object += 1;
                if rgb[3 * p] < 0.2 {
                    rows.push(p / 256);
                }
            }
        }
        let share = rows.len() as f64 / object as f64;
        let height = rows.iter().max().unwrap() - rows.iter().min().unwrap() + 1;
        assert!((0.05..0.4).contains(&share), "ink share {share}");
        assert!((20..=40).contains(&height), "ink band {height} px");
    }
}
