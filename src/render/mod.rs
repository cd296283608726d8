//! CPU rasterizer for 3D Gaussian splats: EWA splatting as in 3DGS (Kerbl et al. 2023,
//! Sec. 4 and 6; Zwicker et al. 2001), with the colour backward pass and the
//! frozen-geometry contribution cache used by stylization.
//!
//! Pipeline of one view ([`render`]):
//! 1. [`project`](mod@project): cull, project means, EWA 2D covariance `J W Sigma W^T J^T + 0.3 I`,
//!    conic, 3-sigma radius; [`bin`]: 16x16 tile lists in a deterministic depth order;
//! 2. [`sh`]: colour per splat for the view direction, `max(0, SH(d) + 0.5)`;
//! 3. [`raster`]: per-tile front-to-back compositing (parallel over tile rows with
//!    rayon, bit-identical for any thread count); outputs RGB over the background,
//!    expected depth `sum_i w_i z_i` and alpha `1 - T_final`.
//!
//! Stylization keeps geometry frozen, so the blending weights `w_i = alpha_i T_i` of
//! each pixel never change: [`cache::ViewCache`] stores them once per view, and colour
//! forward/backward become a sparse product and its transpose ([`backward`]).
//!
//! Pixel coordinates: pixel `(i, j)` has its centre at `(i + 0.5, j + 0.5)` and the
//! principal point `(cx, cy)` is in the same continuous coordinates (COLMAP's
//! convention; gsplat's). INRIA's integer-centred pixels with `cx = W/2` are the same
//! image.

pub mod backward;
pub mod bin;
pub mod cache;
pub mod fill;
pub mod project;
pub mod raster;
pub mod sh;
pub mod shares;
pub mod source;

pub use cache::{CacheMode, ViewCache};
pub use project::Frame;

use crate::{Camera, Error, Result, Scene};
use raster::{Plane, Sink, TileState, composite_tile};
use rayon::prelude::*;

use project::TILE;

/// Project every Gaussian of `scene` for `camera` (validated by the caller) and bin the
/// survivors into tiles.
pub fn project(scene: &Scene, camera: &Camera) -> Frame {
    bin::bin(
        project::project_splats(scene, camera),
        camera.width as usize,
        camera.height as usize,
    )
}

/// Options for a render.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Background colour, linear RGB in [0, 1].
    pub background: [f32; 3],
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            background: [0.0; 3],
        }
    }
}

/// One rendered view, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    pub width: usize,
    pub height: usize,
    /// `[H, W, 3]`, composited over the background.
    pub rgb: Vec<f32>,
    /// `[H, W]`, expected depth sum_i w_i z_i (not normalised by alpha).
    pub depth: Vec<f32>,
    /// `[H, W]`, accumulated opacity 1 - T_final.
    pub alpha: Vec<f32>,
}

/// Largest image side accepted (pixels).
pub const MAX_SIDE: u32 = 1 << 15;

/// Check that a camera can be rendered: non-zero, bounded size, finite positive focal
/// lengths, finite principal point, rotation and translation.
pub fn validate_camera(camera: &Camera) -> Result<()> {
    let name = &camera.name;
    if camera.width == 0 || camera.height == 0 {
        return Err(Error::param(format!(
            "camera {name:?}: image size {}x{} is empty",
            camera.width, camera.height
        )));
    }
    if camera.width > MAX_SIDE || camera.height > MAX_SIDE {
        return Err(Error::param(format!(
            "camera {name:?}: image size {}x{} exceeds {MAX_SIDE} pixels per side",
            camera.width, camera.height
        )));
    }
    let f = [camera.fx, camera.fy, camera.cx, camera.cy];
    if !(f.iter().all(|v| v.is_finite()) && camera.fx > 0.0 && camera.fy > 0.0) {
        return Err(Error::param(format!(
            "camera {name:?}: intrinsics fx={} fy={} cx={} cy={} must be finite with fx, fy > 0",
            camera.fx, camera.fy, camera.cx, camera.cy
        )));
    }
    let finite = camera.rotation.iter().flatten().all(|v| v.is_finite())
        && camera.translation.iter().all(|v| v.is_finite());
    if !finite {
        return Err(Error::param(format!(
            "camera {name:?}: rotation or translation is not finite"
        )));
    }
    Ok(())
}

/// Check the scene's array lengths agree (so indexing cannot panic).
pub fn validate_scene(scene: &Scene) -> Result<()> {
    let n = scene.len();
    let k = scene.rest_per_channel();
    if scene.sh_degree > 3 {
        return Err(Error::param(format!(
            "scene: SH degree {} is above 3",
            scene.sh_degree
        )));
    }
    if scene.log_scales.len() != n
        || scene.rotations.len() != n
        || scene.opacity_logits.len() != n
        || scene.sh_dc.len() != n
        || scene.sh_rest.len() != n * k * 3
    {
        return Err(Error::param(format!(
            "scene: inconsistent array lengths for {n} Gaussians of SH degree {}",
            scene.sh_degree
        )));
    }
    Ok(())
}

/// Pre-clamp colours `SH(d) + 0.5` of scene Gaussians `ids` seen from `centre`.
/// A Gaussian exactly at the camera centre uses the degree-0 term only.
pub fn raw_colours(scene: &Scene, ids: &[u32], centre: [f32; 3]) -> Vec<[f32; 3]> {
    let k = scene.rest_per_channel();
    let deg = scene.sh_degree;
    if k == 0 {
        // Degree 0: the basis is `C0` alone, whatever the direction (not computed).
        let mut basis = [0.0f32; 16];
        sh::sh_basis(0, [0.0; 3], &mut basis);
        return ids
            .par_iter()
            .map(|&id| sh::raw_colour(&basis, scene.sh_dc[id as usize], &[], 0))
            .collect();
    }
    ids.par_iter()
        .map_init(
            || [0.0f32; 16],
            |basis, &id| {
                let i = id as usize;
                let d = sh::unit_dir(centre, scene.positions[i]);
                let kk = if d.is_some() { k } else { 0 };
                sh::sh_basis(deg, d.unwrap_or([0.0; 3]), basis);
                let rest = &scene.sh_rest[i * k * 3..(i + 1) * k * 3];
                sh::raw_colour(basis, scene.sh_dc[i], rest, kk)
            },
        )
        .collect()
}

/// `max(0, raw)` per channel.
pub fn clamp_colours(raw: &[[f32; 3]]) -> Vec<[f32; 3]> {
    raw.par_iter()
        .map(|c| [c[0].max(0.0), c[1].max(0.0), c[2].max(0.0)])
        .collect()
}

/// Render `scene` from `camera`.
pub fn render(scene: &Scene, camera: &Camera, opts: &RenderOptions) -> Result<RenderOutput> {
    validate_camera(camera)?;
    validate_scene(scene)?;
    if !opts.background.iter().all(|v| v.is_finite()) {
        return Err(Error::param("background colour is not finite"));
    }
    let frame = project(scene, camera);
    let colours = clamp_colours(&raw_colours(scene, &frame.splats.ids, camera.center()));
    Ok(composite(&frame, &colours, opts.background))
}

/// Render `scene` from every camera of `cameras` over `background`, in order (one view
/// after another, each on all cores).
pub fn render_all(
    scene: &Scene,
    cameras: &[Camera],
    background: [f32; 3],
) -> Result<Vec<RenderOutput>> {
    let opts = RenderOptions { background };
    cameras.iter().map(|c| render(scene, c, &opts)).collect()
}

struct ForwardSink<'a> {
    /// Colour and depth per splat.
    cz: &'a [[f32; 4]],
    /// Colour and depth of the current batch.
    batch: Vec<[f32; 4]>,
    /// Colour and depth of the current splat.
    cur: [f32; 4],
    acc: [Plane; 4],
}

impl Sink for ForwardSink<'_> {
    #[inline(always)]
    fn gather(&mut self, batch: &[u32]) {
        self.batch.clear();
        self.batch
            .extend(batch.iter().map(|&g| self.cz[g as usize]));
    }

    #[inline(always)]
    fn begin(&mut self, _local: u32, slot: usize) {
        self.cur = self.batch[slot];
    }

    #[inline(always)]
    fn half(&mut self, r: usize, h: usize, w: &[f32; raster::HALF]) {
        const H: usize = raster::HALF;
        let c = self.cur;
        for (a, cv) in self.acc.iter_mut().zip(c) {
            let a: &mut [f32; H] = (&mut a[r][h * H..(h + 1) * H])
                .try_into()
                .expect("half row");
            for x in 0..H {
                a[x] += w[x] * cv;
            }
        }
    }
}

/// Composite a projected frame with per-splat colours (indexed like `frame.splats`).
pub fn composite(frame: &Frame, colours: &[[f32; 3]], background: [f32; 3]) -> RenderOutput {
    let (w, h) = (frame.width, frame.height);
    let mut rgb = vec![0.0f32; w * h * 3];
    let mut depth = vec![0.0f32; w * h];
    let mut alpha = vec![0.0f32; w * h];
    let cz: Vec<[f32; 4]> = colours
        .par_iter()
        .zip(&frame.splats.depth)
        .map(|(c, &z)| [c[0], c[1], c[2], z])
        .collect();
    rgb.par_chunks_mut(TILE * w * 3)
        .zip(depth.par_chunks_mut(TILE * w))
        .zip(alpha.par_chunks_mut(TILE * w))
        .enumerate()
        .for_each(|(ty, ((rgb, depth), alpha))| {
            let mut st = TileState::new();
            let mut sink = ForwardSink {
                cz: &cz,
                batch: Vec::with_capacity(raster::BATCH),
                cur: [0.0; 4],
                acc: [[[0.0; TILE]; TILE]; 4],
            };
            for tx in 0..frame.tiles_x {
                sink.acc = [[[0.0; TILE]; TILE]; 4];
                composite_tile(frame, ty * frame.tiles_x + tx, &mut st, &mut sink);
                let x0 = tx * TILE;
                let cols = (w - x0).min(TILE);
                let rows = depth.len() / w;
                for r in 0..rows {
                    for c in 0..cols {
                        let o = r * w + x0 + c;
                        let t = st.transmittance(r, c);
                        rgb[o * 3] = sink.acc[0][r][c] + t * background[0];
                        rgb[o * 3 + 1] = sink.acc[1][r][c] + t * background[1];
                        rgb[o * 3 + 2] = sink.acc[2][r][c] + t * background[2];
                        depth[o] = sink.acc[3][r][c];
                        alpha[o] = 1.0 - t;
                    }
                }
            }
        });
    RenderOutput {
        width: w,
        height: h,
        rgb,
        depth,
        alpha,
    }
}

#[cfg(test)]
pub(crate) mod tests;
